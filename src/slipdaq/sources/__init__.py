"""Sources: where raw records come from (CAN bus, serial GPS, MCAP logs, log files)."""
