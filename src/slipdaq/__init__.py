"""slipdaq: live wheel-slip acquisition from WPT pulse counts on CAN and NMEA GPS."""

__version__ = "0.1.0"

WHEELS: tuple[str, ...] = ("FL", "FR", "RL", "RR")
"""Wheel names in the order used everywhere (config, DBC messages WPT_<W>, CSV columns)."""
