"""Typed records that flow between modules: sources -> decode -> estimator -> sinks.

Times are seconds in the log's clock (host wall clock for live runs, the files' clock for imports).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, record_row
from slipdaq.records.pickling import by_fields


@dataclass(slots=True)
class CanFrame:
    """One raw CAN frame as received, with its receive timestamp: every field python-can's Message gives.

    Not changed once made, but not a frozen dataclass: that costs a call per field to construct (2.5 us a frame at
    these 12 fields, against 0.4 us)."""

    timestamp_s: float
    arbitration_id: int
    data: bytes
    is_extended_id: bool = False
    is_error_frame: bool = False
    is_remote_frame: bool = False
    is_fd: bool = False
    bitrate_switch: bool = False
    error_state_indicator: bool = False
    is_rx: bool = True
    """False: transmitted (python-can's direction: a log's Tx; on SocketCAN, sent from this host)."""
    channel: str | None = None
    """The bus channel as python-can names it (an int channel as its str)."""
    dlc: int | None = None
    """python-can's DLC where it is not len(data): a remote frame's requested length, or the DLC of an 8-byte
    payload that gave another (a classic frame's DLC 9..15); else None."""

    @property
    def flags(self) -> int:
        """The FLAG_* bits of this frame."""
        return pack_flags(self)

    @classmethod
    def from_flags(cls, timestamp_s: float, arbitration_id: int, data: bytes, flags: int, dlc: int = 0,
                   channel: str | None = None) -> CanFrame:
        """The frame with FLAG_* bits `flags` and the batch's `dlc` column (see CanFrameBatch.dlc): data is ignored
        for a remote frame."""
        remote = flags & FLAG_REMOTE
        return cls(timestamp_s, arbitration_id, b"" if remote else data, bool(flags & FLAG_EXTENDED),
                   bool(flags & FLAG_ERROR), bool(remote), bool(flags & FLAG_FD), bool(flags & FLAG_BRS),
                   bool(flags & FLAG_ESI), not flags & FLAG_TX, channel, dlc if flags & (FLAG_REMOTE | FLAG_DLC) else None)

    @property
    def length(self) -> int:
        """The batch's `dlc` column: python-can's DLC (see `dlc`), else the payload's length."""
        if self.is_remote_frame:
            return self.dlc or 0
        n = len(self.data)
        return self.dlc if n == 8 and self.dlc is not None else n


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


@dataclass(frozen=True, slots=True)
class RtcmFrame:
    """One RTCM 3 frame (preamble 0xD3 to its CRC-24Q) from the GPS serial port, kept as received (not decoded)."""

    timestamp_s: float
    data: bytes


@dataclass(frozen=True, slots=True)
class XbusBytes:
    """One raw record of an Xsens MTi's serial stream (decode/xbus.py) and its host receive time: an Xbus message, or
    bytes between messages that frame none (kept: the raw log is lossless)."""

    timestamp_s: float
    data: bytes


RawRecord = CanFrame | NmeaLine | UbxFrame | RtcmFrame | XbusBytes

FLAG_EXTENDED = 1
FLAG_ERROR = 2
FLAG_REMOTE = 4
"""A remote frame (RTR): no payload; its dlc is the length it asks for."""
FLAG_FD = 8
FLAG_BRS = 16
"""CAN FD bit rate switch."""
FLAG_ESI = 32
"""CAN FD error state indicator."""
FLAG_TX = 64
"""Transmitted (python-can's is_rx False)."""
FLAG_DLC = 128
"""An 8-byte payload whose frame gave another DLC (a classic frame's DLC 9..15, as python-can gives it): the batch's
dlc is that DLC."""


def pack_flags(frame: CanFrame | Any) -> int:
    """The FLAG_* bits of a CanFrame or of python-can's Message (the same attribute names)."""
    flags = (frame.is_extended_id | frame.is_error_frame << 1 | frame.is_remote_frame << 2 | frame.is_fd << 3
             | frame.bitrate_switch << 4 | frame.error_state_indicator << 5 | (not frame.is_rx) << 6)
    dlc = frame.dlc
    if dlc is not None and dlc != 8 and not frame.is_remote_frame and len(frame.data) == 8:
        flags |= FLAG_DLC
    return flags


def payload_lengths(flags: np.ndarray, dlc: np.ndarray) -> np.ndarray:
    """Bytes of payload per frame of a batch: its dlc, 0 for a remote frame, 8 with FLAG_DLC."""
    if not (flags & (FLAG_REMOTE | FLAG_DLC)).any():
        return dlc
    return np.where(flags & FLAG_REMOTE, 0, np.where(flags & FLAG_DLC, 8, dlc)).astype(np.uint8)


def channel_name(channel: object) -> str | None:
    """A python-can channel as a log keeps it: str (an int channel as its str), or None."""
    return None if channel is None else str(channel)


def channel_indices(channels: Sequence[object]) -> tuple[np.ndarray, tuple[str | None, ...]]:
    """Per frame its channel's index in the distinct channels, in the order they first appear; and their names
    (channel_name). `channels`: python-can's channels or their names."""
    first = channels[0] if channels else None
    if channels.count(first) == len(channels):  # one channel (the usual case)
        return np.zeros(len(channels), dtype=np.uint16), (channel_name(first),)
    index: dict[object, int] = {}
    out = np.fromiter((index.setdefault(c, len(index)) for c in channels), dtype=np.uint16, count=len(channels))
    names = tuple(dict.fromkeys(map(channel_name, index)))
    if len(names) < len(index):  # 0 and "0": one name
        lut = np.array([names.index(channel_name(c)) for c in index], dtype=np.uint16)
        out = lut[out]
    return out, names


@dataclass(frozen=True, slots=True, eq=False)
class CanFrameBatch:
    """Consecutive raw CAN frames in arrival order, as numpy columns (one row per frame)."""

    timestamp_s: np.ndarray
    """float64 receive timestamps."""
    arbitration_id: np.ndarray
    """uint32."""
    flags: np.ndarray
    """uint8: FLAG_* bits."""
    dlc: np.ndarray
    """uint8: payload length in bytes; a remote frame: the length it asks for; with FLAG_DLC: the frame's DLC (its
    payload is 8 bytes)."""
    data: np.ndarray
    """uint8 [n, width]: frame i's payload in data[i, :payload_lengths()[i]], zero-padded (a remote frame's row is
    zeros); width >= 8 (64 for CAN FD)."""
    channel: np.ndarray = None  # type: ignore[assignment]  # None: every frame on channel 0 (__post_init__ fills it)
    """uint16: index of each frame's channel in `channels` (default: all 0)."""
    channels: tuple[str | None, ...] = (None,)
    """The channel names the indices refer to."""

    def __post_init__(self) -> None:
        if self.channel is None:
            object.__setattr__(self, "channel", np.zeros(len(self.timestamp_s), dtype=np.uint16))

    def __len__(self) -> int:
        return len(self.timestamp_s)

    @classmethod
    def from_columns(cls, timestamp_s: Sequence[float], arbitration_id: Sequence[int],
                     flags: Sequence[int] | np.ndarray, payloads: Sequence[bytes], dlc: Sequence[int] | None = None,
                     channels: Sequence[object] | None = None) -> CanFrameBatch:
        """dlc: per frame its `dlc` column (default: the payloads' lengths; a remote frame's payload is empty, one
        with FLAG_DLC has 8 bytes); channels: per frame its channel, python-can's or its name (default: None)."""
        n = len(payloads)
        lengths = np.fromiter(map(len, payloads), dtype=np.uint8, count=n)
        width = max(8, int(lengths.max())) if n else 8
        if n and width == 8 and bool((lengths == 8).all()):
            data = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(n, 8)
        else:
            data = np.frombuffer(b"".join(p.ljust(width, b"\0") for p in payloads), dtype=np.uint8).reshape(n, width)
        channel, names = (np.zeros(n, dtype=np.uint16), (None,)) if channels is None else channel_indices(channels)
        return cls(np.asarray(timestamp_s, dtype=np.float64), np.asarray(arbitration_id, dtype=np.uint32),
                   np.asarray(flags, dtype=np.uint8), lengths if dlc is None else np.asarray(dlc, dtype=np.uint8),
                   data, channel, names)

    @classmethod
    def from_frames(cls, frames: Sequence[CanFrame | Any], timestamp_s: Sequence[float] | None = None
                    ) -> CanFrameBatch:
        """CanFrames, or python-can's Messages (the same attribute names) stamped timestamp_s."""
        flags = np.fromiter(map(pack_flags, frames), dtype=np.uint8, count=len(frames))
        odd = (flags & (FLAG_REMOTE | FLAG_DLC)) != 0
        payloads = [f.data for f in frames]
        dlc = None
        if odd.any():  # a remote frame: no payload, its DLC; FLAG_DLC: the frame's DLC
            dlc = [(f.dlc or 0) if o else len(p) for f, o, p in zip(frames, odd.tolist(), payloads)]
            payloads = [b"" if f.is_remote_frame else p for f, p in zip(frames, payloads)]
        return cls.from_columns([f.timestamp_s for f in frames] if timestamp_s is None else timestamp_s,
                                [f.arbitration_id for f in frames], flags, payloads, dlc, [f.channel for f in frames])

    def payload(self, i: int) -> bytes:
        fl = self.flags[i]
        return b"" if fl & FLAG_REMOTE else self.data[i, : 8 if fl & FLAG_DLC else self.dlc[i]].tobytes()

    def payload_lengths(self) -> np.ndarray:
        """Bytes of payload per frame."""
        return payload_lengths(self.flags, self.dlc)

    def frames(self) -> Iterator[CanFrame]:
        """The frames one by one (the general path)."""
        rows = self.data.tolist()
        names = self.channels
        for t, fid, fl, n, row, ch in zip(self.timestamp_s.tolist(), self.arbitration_id.tolist(),
                                          self.flags.tolist(), self.dlc.tolist(), rows, self.channel.tolist()):
            if fl < FLAG_REMOTE:  # a plain data frame
                yield CanFrame(t, fid, bytes(row[:n]), bool(fl & FLAG_EXTENDED), bool(fl & FLAG_ERROR), False, False,
                               False, False, True, names[ch])
            else:
                yield CanFrame.from_flags(t, fid, bytes(row[: 8 if fl & FLAG_DLC else n]), fl, n, names[ch])

    def slice(self, start: int, stop: int) -> CanFrameBatch:
        return CanFrameBatch(self.timestamp_s[start:stop], self.arbitration_id[start:stop], self.flags[start:stop],
                             self.dlc[start:stop], self.data[start:stop], self.channel[start:stop], self.channels)

    def renamed(self, channels: Sequence[str | None]) -> CanFrameBatch:
        """The same frames with their channel indices into `channels` (which holds every name of this batch's)."""
        channels = tuple(channels)
        if channels == self.channels:
            return self
        if channels[: len(self.channels)] == self.channels:  # the same indices
            return replace(self, channels=channels)
        lut = np.array([channels.index(name) for name in self.channels], dtype=np.uint16)
        return CanFrameBatch(self.timestamp_s, self.arbitration_id, self.flags, self.dlc, self.data,
                             lut[self.channel], channels)

    @classmethod
    def concat(cls, parts: Sequence[CanFrameBatch]) -> CanFrameBatch:
        """The batches' frames in order, as one batch (payloads zero-padded to the widest)."""
        width = max(p.data.shape[1] for p in parts)
        data = [p.data if p.data.shape[1] == width else np.pad(p.data, ((0, 0), (0, width - p.data.shape[1])))
                for p in parts]
        channels = max((p.channels for p in parts), key=len)
        if any(p.channels != channels[: len(p.channels)] for p in parts):
            channels = tuple(dict.fromkeys(name for p in parts for name in p.channels))
        parts = [p.renamed(channels) for p in parts]
        return cls(np.concatenate([p.timestamp_s for p in parts]), np.concatenate([p.arbitration_id for p in parts]),
                   np.concatenate([p.flags for p in parts]), np.concatenate([p.dlc for p in parts]),
                   np.concatenate(data), np.concatenate([p.channel for p in parts]), channels)


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

    @classmethod
    def empty(cls) -> WheelSampleBatch:
        e = np.empty(0, dtype=np.int64)
        f = np.empty(0, dtype=np.float64)
        return cls(e, e.astype(np.uint8), f, f, e, f, e, e, e.astype(np.uint8))

    def of_frames(self, start: int, stop: int) -> WheelSampleBatch:
        """The samples of frames start..stop, their frame indices counted from start (itself: all of them, from 0)."""
        i, k = int(self.frame.searchsorted(start)), int(self.frame.searchsorted(stop))
        return self if (i, k, start) == (0, len(self), 0) else WheelSampleBatch(
            self.frame[i:k] - start, self.wheel[i:k], self.timestamp_s[i:k], self.revolutions[i:k], self.count[i:k],
            self.raw[i:k], self.seq[i:k], self.lost_frames[i:k], self.flags[i:k])

    def samples(self, wheels: Sequence[str]) -> Iterator[WheelSample]:
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


SENSOR_KINDS = ("reference_speed", "imu_accel", "brake", "brake_mark")


@dataclass(frozen=True, slots=True)
class SensorSample:
    """One value of the vehicle's other sensors, decoded from a CAN frame (decode/can_signals.py), in SI units."""

    time_s: float
    """The frame's receive time."""
    kind: str = field(metadata={"enum": SENSOR_KINDS})
    """reference_speed (m/s), imu_accel (forward, m/s^2), brake (1 pressed, 0 released) or brake_mark (1: pressed)."""
    value: float
    valid: bool = True
    """reference_speed: false when its valid signal says so."""
    accuracy: float | None = None
    """reference_speed: its stated 1-sigma accuracy (m/s)."""


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
    quality: str = "ok"
    """'ok'; 'uncalibrated': the GPS latency unknown or a wheel's radius not calibrated (taken from the tire size or
    the other wheels); 'disturbed': a gap in a wheel's samples (reader stall, frames lost) or in the GPS fixes inside
    the window, or GPS lost (estimates on the wheels' clock)."""
    accel_source: str = "gps"
    """Where accel_mps2 (and so Fx = M*a) comes from: 'imu' (the mean of the IMU's samples over the window) or 'gps'
    (the central difference of the reference speed)."""

    def as_row(self) -> dict[str, float | str | None]:
        """Flat mapping in the log's and the CSV's column names (ESTIMATE_COLUMNS, wheels in this estimate's order)."""
        return record_row(self, ESTIMATE_COLUMNS)


@dataclass(slots=True)
class FastWheel:
    slip: float | None
    """(omega*r0 - V) / V at this instant; None below the minimum speed or without the wheel's samples around it."""
    speed_mps: float | None
    """Wheel circumferential speed omega*r0."""


@dataclass(slots=True)
class FastSlip:
    """High-rate slip: each wheel's circumferential speed against the vehicle speed at one instant of a fixed grid
    (estimator.fast_rate_hz), the vehicle speed fused from the reference speed and the IMU (not frozen: see CanFrame)."""

    time_s: float
    speed_mps: float
    accel_mps2: float
    accel_source: str
    """'imu' when the IMU's samples fed the filter, else 'gps'."""
    wheels: dict[str, FastWheel]

    def as_row(self) -> dict[str, float | str | None]:
        """Flat mapping in the /slip/fast JSON's and the fast CSV's column names (FAST_SLIP_COLUMNS)."""
        return record_row(self, FAST_SLIP_COLUMNS)


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
        """Every field in declaration order (the /diagnostics JSON), the dicts copied."""
        return {name: dict(v) if isinstance(v, dict) else v for name in self.__slots__
                for v in (getattr(self, name),)}

# ---- source and log events: what happened to the devices and the log file (a GPS unplugged, the disk full, the host
# clock stepped...), on /diagnostics/events and the live view; the estimates depend only on the raw records.

@dataclass(frozen=True, slots=True)
class SourceEvent:
    time_s: float
    """When it happened, in the log's clock."""
    source: str = field(metadata={"enum": ("gps", "can", "log", "clock", "calibration", "imu")})
    event: str
    """gps (and imu, an MTi on serial): connected, disconnected, silent, unreadable, readable, emit_error; can:
    reader_error, down, up; log: write_failed, resumed, rotated; clock: stepped; calibration: replaced (the run
    contradicted a stored value beyond its uncertainty and uses its own)."""
    detail: str = ""
    gap_s: float | None = None
    """For connected/resumed/up/readable: how long the outage lasted."""
    counters: dict[str, int] = field(default_factory=dict)
    """The source's running counters at that moment (gaps, reconnects, unreadable periods, dropped messages...)."""

    def as_dict(self) -> dict[str, Any]:
        return {"time_s": self.time_s, "source": self.source, "event": self.event, "detail": self.detail,
                "gap_s": self.gap_s, "counters": dict(self.counters)}


EventHandler = Callable[[SourceEvent], None]
by_fields(GpsFix, WheelEstimate, Estimate, NmeaLine, CanFrameBatch, WheelSampleBatch)

