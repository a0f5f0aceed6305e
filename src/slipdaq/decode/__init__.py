"""Pure decoders: raw CAN frames -> wheel samples (DBC), raw NMEA lines -> GPS fixes."""
