"""Typed records that flow between modules: sources -> decode -> estimator -> sinks.

Times are seconds in the log's clock (host wall clock for live runs, the files' clock for imports).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, slots=True)
class CanFrame:
    """One raw CAN frame as received, with its receive timestamp."""

    timestamp_s: float
    arbitration_id: int
    data: bytes
    is_extended_id: bool = False
    is_error_frame: bool = False


@dataclass(frozen=True, slots=True)
class NmeaLine:
    """One raw line from the GPS serial port (without line ending), with its host receive timestamp."""

    timestamp_s: float
    line: str


@dataclass(frozen=True, slots=True)
class UbxFrame:
    """One raw u-blox UBX frame (sync bytes to checksum) from the GPS serial port, with its host receive time."""

    timestamp_s: float
    data: bytes


RawRecord = CanFrame | NmeaLine | UbxFrame

FLAG_EXTENDED = 1
FLAG_ERROR = 2


@dataclass(frozen=True, slots=True, eq=False)
class CanFrameBatch:
    """Consecutive raw CAN frames in arrival order, as numpy columns (one row per frame)."""

    timestamp_s: np.ndarray
    """float64 receive timestamps."""
    arbitration_id: np.ndarray
    """uint32."""
    flags: np.ndarray
    """uint8: FLAG_EXTENDED | FLAG_ERROR."""
    dlc: np.ndarray
    """uint8: payload length in bytes."""
    data: np.ndarray
    """uint8 [n, width]: frame i's payload in data[i, :dlc[i]], zero-padded; width >= 8 (64 for CAN FD)."""

    def __len__(self) -> int:
        return len(self.timestamp_s)

    @classmethod
    def from_columns(cls, timestamp_s: Sequence[float], arbitration_id: Sequence[int], flags: Sequence[int],
                     payloads: Sequence[bytes]) -> "CanFrameBatch":
        n = len(payloads)
        dlc = np.fromiter(map(len, payloads), dtype=np.uint8, count=n)
        width = max(8, int(dlc.max())) if n else 8
        if n and width == 8 and bool((dlc == 8).all()):
            data = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(n, 8)
        else:
            data = np.frombuffer(b"".join(p.ljust(width, b"\0") for p in payloads), dtype=np.uint8).reshape(n, width)
        return cls(np.asarray(timestamp_s, dtype=np.float64), np.asarray(arbitration_id, dtype=np.uint32),
                   np.asarray(flags, dtype=np.uint8), dlc, data)

    @classmethod
    def from_frames(cls, frames: Sequence[CanFrame]) -> "CanFrameBatch":
        return cls.from_columns([f.timestamp_s for f in frames], [f.arbitration_id for f in frames],
                                [f.is_extended_id | (f.is_error_frame << 1) for f in frames], [f.data for f in frames])

    def payload(self, i: int) -> bytes:
        return self.data[i, : self.dlc[i]].tobytes()

    def frames(self) -> Iterator[CanFrame]:
        """The frames one by one (the general path)."""
        rows = self.data.tolist()
        for t, fid, fl, n, row in zip(self.timestamp_s.tolist(), self.arbitration_id.tolist(), self.flags.tolist(),
                                      self.dlc.tolist(), rows):
            yield CanFrame(t, fid, bytes(row[:n]), bool(fl & FLAG_EXTENDED), bool(fl & FLAG_ERROR))

    def slice(self, start: int, stop: int) -> "CanFrameBatch":
        return CanFrameBatch(self.timestamp_s[start:stop], self.arbitration_id[start:stop], self.flags[start:stop],
                             self.dlc[start:stop], self.data[start:stop])

    @classmethod
    def concat(cls, parts: Sequence["CanFrameBatch"]) -> "CanFrameBatch":
        """The batches' frames in order, as one batch (payloads zero-padded to the widest)."""
        width = max(p.data.shape[1] for p in parts)
        data = [p.data if p.data.shape[1] == width else np.pad(p.data, ((0, 0), (0, width - p.data.shape[1])))
                for p in parts]
        return cls(np.concatenate([p.timestamp_s for p in parts]), np.concatenate([p.arbitration_id for p in parts]),
                   np.concatenate([p.flags for p in parts]), np.concatenate([p.dlc for p in parts]),
                   np.concatenate(data))


@dataclass(frozen=True, slots=True, eq=False)
class WheelSampleBatch:
    """Decoded wheel samples in record order, as numpy columns: what many WheelSamples carry."""

    frame: np.ndarray
    """int64: index of the frame each sample came from, within its CanFrameBatch."""
    wheel: np.ndarray
    """uint8: index in WHEELS."""
    timestamp_s: np.ndarray
    revolutions: np.ndarray
    count: np.ndarray
    """int64 (0 where has_count is false)."""
    raw: np.ndarray
    """float64: the signal as sent."""
    seq: np.ndarray
    """int64 (0 where has_seq is false)."""
    lost_frames: np.ndarray
    """int64."""
    flags: np.ndarray
    """uint8: SAMPLE_HAS_COUNT | SAMPLE_HAS_SEQ."""

    def __len__(self) -> int:
        return len(self.timestamp_s)

    def slice(self, start: int, stop: int, frame_offset: int = 0) -> "WheelSampleBatch":
        """Samples start..stop, their frame indices moved by frame_offset."""
        return WheelSampleBatch(self.frame[start:stop] + frame_offset, self.wheel[start:stop],
                                self.timestamp_s[start:stop], self.revolutions[start:stop], self.count[start:stop],
                                self.raw[start:stop], self.seq[start:stop], self.lost_frames[start:stop],
                                self.flags[start:stop])

    def samples(self, wheels: Sequence[str]) -> Iterator["WheelSample"]:
        for w, t, rev, c, raw, q, lost, fl in zip(
            self.wheel.tolist(), self.timestamp_s.tolist(), self.revolutions.tolist(), self.count.tolist(),
            self.raw.tolist(), self.seq.tolist(), self.lost_frames.tolist(), self.flags.tolist(),
        ):
            yield WheelSample(t, wheels[w], rev, c if fl & SAMPLE_HAS_COUNT else None, raw,
                              q if fl & SAMPLE_HAS_SEQ else None, lost)


SAMPLE_HAS_COUNT = 1
SAMPLE_HAS_SEQ = 2


@dataclass(frozen=True, slots=True)
class WheelSample:
    """One wheel's decoded sample: its cumulative revolutions since its first sample."""

    timestamp_s: float
    wheel: str
    revolutions: float
    """Cumulative wheel revolutions: counts / pulses_per_rev (unwrapped), or the integral of a wheel-speed signal."""
    count: int | None
    """Count sources: cumulative pulses since the first frame, unwrapped across the counter's wrap."""
    raw: float
    """The signal as sent: the raw count, or the speed in the signal's unit."""
    seq: int | None
    lost_frames: int
    """Frames missing before this one, from the gap in the sequence counter."""


@dataclass(frozen=True, slots=True)
class GpsFix:
    """One GPS velocity epoch decoded from NMEA."""

    timestamp_s: float
    """Host receive time of the sentence that completed the epoch."""
    speed_mps: float
    fix_time_utc_s: float | None = None
    """The fix's own UTC time (seconds since the epoch), when the sentence carries date and time."""
    valid: bool = True
    course_deg: float | None = None
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = None
    fix_quality: int | None = None
    satellites: int | None = None
    sentence: str = "RMC"
    speed_accuracy_mps: float | None = None
    """The receiver's own 1-sigma speed accuracy estimate, where it gives one (UBX NAV-PVT sAcc)."""


@dataclass(frozen=True, slots=True)
class WheelEstimate:
    slip: float | None
    re_m: float | None
    r0_m: float
    cx_n: float | None
    force_n: float | None
    speed_mps: float | None
    """Wheel circumferential speed omega*r0 over the window."""
    r0_source: str = "tire_size"
    """Where r0 came from: 'calibrated' (converged), 'calibrating' (usable, not yet converged), 'other_wheels'
    (the calibrated wheels' mean), 'tire_size' or 'configured' (tire.free_radius_m)."""
    slip_nd: float | None = None
    """Slip against the non-driven wheels' speed (driven wheels only; no GPS needed)."""
    cx_fit_n: float | None = None
    """Stiffness fitted over the run so far (initial slope of force against slip)."""
    cx_fit_conf: float | None = None


@dataclass(frozen=True, slots=True)
class Estimate:
    """Windowed estimate centred on one GPS epoch (or on the wheels' clock while GPS is lost)."""

    time_s: float
    speed_mps: float
    accel_mps2: float | None
    force_n: float | None
    window_s: float
    wheels: dict[str, WheelEstimate]
    phase: str = "cruise"
    """standstill | accelerate | cruise | brake"""
    source: str = "gps"
    """'gps': centred on a GPS epoch; 'wheels': GPS lost, speed from the non-driven wheels."""
    gps_latency_s: float = 0.0
    latency_source: str = "fixed"

    def as_row(self) -> dict[str, float | str | None]:
        """Flat mapping in the CSV/MCAP column names."""
        row: dict[str, float | str | None] = {
            "time_s": self.time_s,
            "speed_mps": self.speed_mps,
            "accel_mps2": self.accel_mps2,
            "force_n": self.force_n,
        }
        for w, e in self.wheels.items():
            row[f"slip_{w}"] = e.slip
            row[f"re_{w}_m"] = e.re_m
            row[f"r0_{w}_m"] = e.r0_m
            row[f"cx_{w}_n"] = e.cx_n
        row["phase"] = self.phase
        row["source"] = self.source
        row["gps_latency_s"] = self.gps_latency_s
        row["latency_source"] = self.latency_source
        for w, e in self.wheels.items():
            row[f"r0_source_{w}"] = e.r0_source
            row[f"slip_nd_{w}"] = e.slip_nd
            row[f"cx_fit_{w}_n"] = e.cx_fit_n
            row[f"cx_fit_{w}_conf"] = e.cx_fit_conf
        return row


@dataclass(slots=True)
class Diagnostics:
    """Running counters of what the pipeline saw; a snapshot is logged about once a second."""

    time_s: float = 0.0
    can_frames: int = 0
    wpt_frames: dict[str, int] = field(default_factory=dict)
    """Wheel samples decoded per wheel (WPT frames, or wheel-speed samples)."""
    lost_frames: dict[str, int] = field(default_factory=dict)
    count_wraps: dict[str, int] = field(default_factory=dict)
    counter_resets: dict[str, int] = field(default_factory=dict)
    unknown_frames: int = 0
    error_frames: int = 0
    bad_frames: int = 0
    nmea_lines: int = 0
    bad_sentences: int = 0
    dropped_sentences: dict[str, int] = field(default_factory=dict)
    """NMEA lines that gave the estimator nothing, by reason (NmeaDecoder.dropped; bad_sentences is bad_checksum +
    unparsable)."""
    gps_fixes: int = 0
    ubx_frames: int = 0
    bad_ubx_frames: int = 0
    estimates: int = 0
    estimator: dict[str, object] = field(default_factory=dict)
    """Calibration state: latency by each method, r0 and its standard error, fitted Cx, per wheel."""

    def as_dict(self) -> dict[str, object]:
        return {
            "time_s": self.time_s,
            "can_frames": self.can_frames,
            "wpt_frames": dict(self.wpt_frames),
            "lost_frames": dict(self.lost_frames),
            "count_wraps": dict(self.count_wraps),
            "counter_resets": dict(self.counter_resets),
            "unknown_frames": self.unknown_frames,
            "error_frames": self.error_frames,
            "bad_frames": self.bad_frames,
            "nmea_lines": self.nmea_lines,
            "bad_sentences": self.bad_sentences,
            "dropped_sentences": dict(self.dropped_sentences),
            "gps_fixes": self.gps_fixes,
            "ubx_frames": self.ubx_frames,
            "bad_ubx_frames": self.bad_ubx_frames,
            "estimates": self.estimates,
            "estimator": dict(self.estimator),
        }
