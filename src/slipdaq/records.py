"""Typed records that flow between modules: sources -> decode -> estimator -> sinks.

Times are seconds in the log's clock (host wall clock for live runs, the files' clock for imports).
"""

from __future__ import annotations

from dataclasses import dataclass, field


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
            "gps_fixes": self.gps_fixes,
            "ubx_frames": self.ubx_frames,
            "bad_ubx_frames": self.bad_ubx_frames,
            "estimates": self.estimates,
            "estimator": dict(self.estimator),
        }
