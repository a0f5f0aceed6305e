"""The log's topics: one per record stream, raw and derived, and the metadata record that makes a log replayable
(the config's TOML and the DBC's text, in the `slipdaq` metadata record)."""

from __future__ import annotations

PROFILE = "slipdaq"
METADATA_NAME = "slipdaq"

TOPIC_CAN = "/can/raw"
TOPIC_NMEA = "/nmea/raw"
TOPIC_UBX = "/gps/ubx/raw"
TOPIC_RTCM = "/gps/rtcm/raw"
TOPIC_IMU_RAW = "/imu/raw"
TOPIC_WPT = "/wpt/count"
TOPIC_GPS = "/gps/fix"
TOPIC_GPS_LOCATION = "/gps/location"
"""The fixes with a position as foxglove.LocationFix (JSON), for Foxglove's Map panel."""
TOPIC_ESTIMATE = "/estimate"
TOPIC_FAST_SLIP = "/slip/fast"
TOPIC_FAST_SLIP_ROW = "/slip/fast/row"
"""The high-rate slip, one row per message with its instant as header.stamp: Foxglove's Plot panel (timestamp
"header stamp") draws each row at its own time, live and in the log (/slip/fast holds the same rows as columns)."""
TOPIC_SENSORS = "/can/sensors"
TOPIC_MANEUVER = "/maneuver"
TOPIC_TEST_SET = "/test_set"
"""A procedure's set of runs ([[test.procedure]]) after each of its maneuvers (maneuver.test_set)."""
TOPIC_DIAGNOSTICS = "/diagnostics"
TOPIC_EVENTS = "/diagnostics/events"
RAW_TOPICS = (TOPIC_CAN, TOPIC_NMEA, TOPIC_UBX, TOPIC_IMU_RAW, TOPIC_RTCM)

MAX_BATCH_FRAMES = 512
MAX_BATCH_SPAN_S = 0.05
"""/can/raw and /wpt/count: one message per batch of at most this many frames (samples) or this much log time."""


def log_time_ns(t_s: float) -> int:
    """A record's log time: nanoseconds since the Unix epoch (never negative), as MCAP stores it."""
    ns = int(round(t_s * 1e9))
    return ns if ns > 0 else 0
