"""The MCAP layer: topics, JSON schemas and the writer sink. Everything raw and derived, one topic each.

Foxglove opens the file and plots every numeric field. The config (TOML) and DBC text are stored in the
`slipdaq` metadata record, so a log replays with no other input.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any, BinaryIO

from mcap.writer import CompressionType, Writer

import slipdaq
from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.records import CanFrame, Estimate, GpsFix, NmeaLine, RawRecord, WheelSample

PROFILE = "slipdaq"
METADATA_NAME = "slipdaq"

TOPIC_CAN = "/can/raw"
TOPIC_NMEA = "/nmea/raw"
TOPIC_WPT = "/wpt/count"
TOPIC_GPS = "/gps/fix"
TOPIC_ESTIMATE = "/estimate"
TOPIC_DIAGNOSTICS = "/diagnostics"
RAW_TOPICS = (TOPIC_CAN, TOPIC_NMEA)

_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_INT = {"type": "integer"}
_INT_OR_NULL = {"type": ["integer", "null"]}


def _obj(title: str, props: dict[str, Any]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": props}


def _estimate_props() -> dict[str, Any]:
    text = {"type": "string"}
    props: dict[str, Any] = {
        "time_s": _NUM, "speed_mps": _NUM, "accel_mps2": _NUM_OR_NULL, "force_n": _NUM_OR_NULL, "window_s": _NUM,
        "phase": {"type": "string", "enum": ["standstill", "accelerate", "cruise", "brake"]},
        "source": text, "gps_latency_s": _NUM, "latency_source": text,
    }
    for w in WHEELS:
        props |= {
            f"slip_{w}": _NUM_OR_NULL, f"re_{w}_m": _NUM_OR_NULL, f"r0_{w}_m": _NUM, f"cx_{w}_n": _NUM_OR_NULL,
            f"force_{w}_n": _NUM_OR_NULL, f"wheel_speed_{w}_mps": _NUM_OR_NULL, f"r0_source_{w}": text,
            f"slip_nd_{w}": _NUM_OR_NULL, f"cx_fit_{w}_n": _NUM_OR_NULL, f"cx_fit_{w}_conf": _NUM_OR_NULL,
        }
    return props


def _per_wheel(title: str) -> dict[str, Any]:
    return _obj(title, {w: _INT for w in WHEELS})


SCHEMAS: dict[str, dict[str, Any]] = {
    TOPIC_CAN: _obj("slipdaq.CanFrame", {
        "timestamp_s": _NUM, "id": _INT, "extended": {"type": "boolean"}, "error": {"type": "boolean"},
        "dlc": _INT, "data": {"type": "string", "description": "payload bytes as hex"},
    }),
    TOPIC_NMEA: _obj("slipdaq.NmeaLine", {"timestamp_s": _NUM, "line": {"type": "string"}}),
    TOPIC_WPT: _obj("slipdaq.WheelSample", {
        "timestamp_s": _NUM, "wheel": {"type": "string"}, "revolutions": _NUM, "count": _INT_OR_NULL, "raw": _NUM,
        "seq": _INT_OR_NULL, "lost_frames": _INT,
    }),
    TOPIC_GPS: _obj("slipdaq.GpsFix", {
        "timestamp_s": _NUM, "speed_mps": _NUM, "fix_time_utc_s": _NUM_OR_NULL, "valid": {"type": "boolean"},
        "course_deg": _NUM_OR_NULL, "latitude_deg": _NUM_OR_NULL, "longitude_deg": _NUM_OR_NULL,
        "altitude_m": _NUM_OR_NULL, "fix_quality": _INT_OR_NULL, "satellites": _INT_OR_NULL,
        "sentence": {"type": "string"},
    }),
    TOPIC_ESTIMATE: _obj("slipdaq.Estimate", _estimate_props()),
    TOPIC_DIAGNOSTICS: _obj("slipdaq.Diagnostics", {
        "time_s": _NUM, "can_frames": _INT, "wpt_frames": _per_wheel("frames"), "lost_frames": _per_wheel("lost"),
        "count_wraps": _per_wheel("wraps"),
        "counter_resets": _per_wheel("resets"), "unknown_frames": _INT, "error_frames": _INT, "bad_frames": _INT,
        "nmea_lines": _INT, "bad_sentences": _INT, "gps_fixes": _INT, "estimates": _INT,
        "estimator": _obj("estimator", {
            "gps_latency_s": _NUM, "latency_source": {"type": "string"}, "gps_latency_utc_s": _NUM_OR_NULL,
            "gps_latency_wheels_s": _NUM_OR_NULL, "gps_latency_wheels_sigma_s": _NUM_OR_NULL,
            "r0_m": _obj("r0", {w: _NUM for w in WHEELS}), "r0_se_m": _obj("r0_se", {w: _NUM_OR_NULL for w in WHEELS}),
            "cx_fit_n": _obj("cx_fit", {w: _NUM_OR_NULL for w in WHEELS}),
            "cx_fit_conf": _obj("cx_fit_conf", {w: _NUM for w in WHEELS}), "rejected_fixes": _INT,
        }),
    }),
}


def can_frame_to_dict(f: CanFrame) -> dict[str, Any]:
    return {"timestamp_s": f.timestamp_s, "id": f.arbitration_id, "extended": f.is_extended_id,
            "error": f.is_error_frame, "dlc": len(f.data), "data": f.data.hex()}


def can_frame_from_dict(d: dict[str, Any]) -> CanFrame:
    return CanFrame(d["timestamp_s"], d["id"], bytes.fromhex(d["data"]), d["extended"], d["error"])


def estimate_to_dict(e: Estimate) -> dict[str, Any]:
    d: dict[str, Any] = e.as_row()
    d["window_s"] = e.window_s
    for w, we in e.wheels.items():
        d[f"force_{w}_n"] = we.force_n
        d[f"wheel_speed_{w}_mps"] = we.speed_mps
    return d


def _ns(t_s: float) -> int:
    return max(int(round(t_s * 1e9)), 0)


class McapLogSink:
    """Writes every record and result to one MCAP file (zstd chunks). Call close() to finish the file."""

    def __init__(
        self,
        path: str | Path,
        config: Config,
        mode: str,
        metadata: dict[str, str] | None = None,
        flush_every_s: float | None = None,
    ) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: BinaryIO = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=config.log.chunk_size_bytes, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"slipdaq {slipdaq.__version__}")
        self._channels: dict[str, int] = {}
        for topic, schema in SCHEMAS.items():
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        meta = {
            "version": slipdaq.__version__,
            "mode": mode,
            "created_utc": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
            "config_path": str(config.source_path or ""),
            "config_toml": config.to_toml(),
            "config_source_toml": config.source_text,
            "dbc": config.load_dbc_text(),
        }
        self._writer.add_metadata(METADATA_NAME, meta | (metadata or {}))
        self._seq = 0
        self._flush_every_s = flush_every_s
        self._last_flush_s: float | None = None
        self.messages = 0
        self.closed = False

    def _write(self, topic: str, log_time_s: float, payload: dict[str, Any]) -> None:
        self._seq += 1
        ns = _ns(log_time_s)
        self._writer.add_message(
            self._channels[topic], log_time=ns, publish_time=ns, sequence=self._seq & 0xFFFFFFFF,
            data=json.dumps(payload, separators=(",", ":")).encode(),
        )
        self.messages += 1

    def on_raw(self, record: RawRecord) -> None:
        if isinstance(record, CanFrame):
            self._write(TOPIC_CAN, record.timestamp_s, can_frame_to_dict(record))
        else:
            self._write(TOPIC_NMEA, record.timestamp_s, {"timestamp_s": record.timestamp_s, "line": record.line})

    def on_wheel(self, sample: WheelSample) -> None:
        self._write(TOPIC_WPT, sample.timestamp_s, {
            "timestamp_s": sample.timestamp_s, "wheel": sample.wheel, "revolutions": sample.revolutions,
            "count": sample.count, "raw": sample.raw, "seq": sample.seq, "lost_frames": sample.lost_frames,
        })

    def on_fix(self, fix: GpsFix) -> None:
        self._write(TOPIC_GPS, fix.timestamp_s, {k: getattr(fix, k) for k in fix.__slots__})

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self._write(TOPIC_ESTIMATE, log_time_s, estimate_to_dict(estimate))

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self._write(TOPIC_DIAGNOSTICS, log_time_s, diagnostics)
        if self._flush_every_s is not None:
            if self._last_flush_s is None or log_time_s - self._last_flush_s >= self._flush_every_s:
                self._writer.flush()
                self._last_flush_s = log_time_s

    @property
    def size_bytes(self) -> int:
        return self._file.tell()

    def close(self) -> None:
        """Finish the file (summary and footer). Safe to call twice."""
        if not self.closed:
            self.closed = True
            self._writer.finish()
            self._file.close()
