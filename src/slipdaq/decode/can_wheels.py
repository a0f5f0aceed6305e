"""CAN frames -> WheelSample per wheel, by DBC message and signal names (cantools). Two kinds of wheel source:

- count: a cumulative pulse counter (WPT default: WPT_<W>.PulseCount, wrapping at 2^bits of the signal), unwrapped;
  an optional rolling sequence counter (WPT: Seq) whose gaps are lost frames. A jump the wheel cannot have made
  since the last frame (forwards faster than MAX_REV_PER_S, backwards faster than MAX_REVERSE_REV_PER_S, plus a
  tenth of a revolution) is a counter node reset: a new segment, continued at the wheel's last rate instead of a
  huge slip, and counted.
- speed: a wheel-speed signal (km/h, kph, m/s, mph, rpm, rad/s, deg/s; from the DBC's unit or the config), integrated
  over time (trapezoids) into revolutions. Linear speeds are turned into revolutions with the tire's radius, so a
  calibrated r0 for such a wheel is that radius times the signal's scale error.
Several wheels may share one message (one WHEEL_SPEEDS frame for all four).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cantools

from slipdaq import WHEELS
from slipdaq.config import Config, WheelSourceConfig
from slipdaq.records import CanFrame, WheelSample

MAX_REV_PER_S = 100.0
"""No road wheel turns faster (100 rev/s at r = 0.3 m is 680 km/h)."""
MAX_REVERSE_REV_PER_S = 5.0
"""Nor reverses faster (5 rev/s at r = 0.3 m is 34 km/h)."""
MAX_INTEGRATION_GAP_S = 1.0
"""A speed signal silent for longer than this is not integrated over the gap."""

_REV_PER_S_PER_UNIT = {"rpm": 1.0 / 60.0, "rad/s": 1.0 / (2 * math.pi), "deg/s": 1.0 / 360.0}
_MPS_PER_UNIT = {"km/h": 1.0 / 3.6, "kph": 1.0 / 3.6, "kmh": 1.0 / 3.6, "m/s": 1.0, "mph": 0.44704}


class DbcError(ValueError):
    """The DBC lacks a message or signal slipdaq needs, or cannot be parsed."""


def load_dbc(text: str) -> cantools.database.Database:
    try:
        return cantools.database.load_string(text, database_format="dbc", strict=False)
    except Exception as e:  # cantools raises several parse error types
        raise DbcError(f"cannot parse DBC: {e}") from None


@dataclass(slots=True)
class _Source:
    wheel: str
    kind: str
    signal: cantools.database.Signal
    seq_signal: cantools.database.Signal | None
    pulses_per_rev: int
    rev_per_s_per_unit: float
    last_raw: int | None = None
    last_seq: int | None = None
    last_t: float | None = None
    last_rate: float = 0.0
    """count: pulses per second over the last interval; speed: revolutions per second."""
    count: int = 0
    revolutions: float = 0.0

    @property
    def count_modulus(self) -> int:
        return 1 << self.signal.length


@dataclass(slots=True)
class _Message:
    message: cantools.database.Message
    sources: list[_Source] = field(default_factory=list)


def _rev_per_s_per_unit(wheel: str, src: WheelSourceConfig, signal: cantools.database.Signal, radius_m: float) -> float:
    unit = (src.unit or signal.unit or "").strip().lower().replace("kph", "km/h").replace("kmh", "km/h")
    if unit in _REV_PER_S_PER_UNIT:
        return _REV_PER_S_PER_UNIT[unit]
    if unit in _MPS_PER_UNIT:
        return _MPS_PER_UNIT[unit] / (2 * math.pi * radius_m)
    raise DbcError(
        f"wheels.{wheel}: speed signal {src.message}.{src.signal} has unit {signal.unit!r}: "
        f"set wheels.{wheel}.unit to one of km/h, m/s, mph, rpm, rad/s, deg/s"
    )


def _signal(msg: cantools.database.Message, name: str, wheel: str, key: str) -> cantools.database.Signal:
    for s in msg.signals:
        if s.name == name:
            return s
    raise DbcError(f"wheels.{wheel}.{key}: signal {msg.name}.{name} not found in DBC")


class WheelDecoder:
    """Stateful, pure: decode wheel frames in arrival order into cumulative revolutions per wheel."""

    def __init__(self, config: Config, dbc_text: str | None = None) -> None:
        db = load_dbc(dbc_text if dbc_text is not None else config.load_dbc_text())
        self._by_id: dict[int, _Message] = {}
        for w in WHEELS:
            src = config.wheel_source(w)
            try:
                msg = db.get_message_by_name(src.message)
            except KeyError:
                raise DbcError(f"wheels.{w}.message: message {src.message} not found in DBC") from None
            sig = _signal(msg, src.signal, w, "signal")
            seq = _signal(msg, src.seq_signal, w, "seq_signal") if src.seq_signal else None
            rate = _rev_per_s_per_unit(w, src, sig, config.tire.radius_m) if src.kind == "speed" else 0.0
            entry = self._by_id.setdefault(msg.frame_id, _Message(msg))
            entry.sources.append(_Source(w, src.kind, sig, seq, src.pulses_per_rev or config.wpt.pulses_per_rev, rate))
        self.lost_frames: dict[str, int] = {w: 0 for w in WHEELS}
        self.count_wraps: dict[str, int] = {w: 0 for w in WHEELS}
        self.counter_resets: dict[str, int] = {w: 0 for w in WHEELS}
        self.frames: dict[str, int] = {w: 0 for w in WHEELS}
        self.bad_frames = 0

    def is_wheel_frame(self, frame: CanFrame) -> bool:
        return not frame.is_extended_id and frame.arbitration_id in self._by_id

    def decode(self, frame: CanFrame) -> list[WheelSample]:
        """The frame's WheelSamples (one per wheel it carries); none for a frame of another ID or a bad one."""
        if frame.is_error_frame or frame.is_extended_id:
            return []
        entry = self._by_id.get(frame.arbitration_id)
        if entry is None:
            return []
        try:
            values = entry.message.decode(frame.data, decode_choices=False, scaling=False)
        except Exception:  # wrong DLC or bytes cantools cannot decode
            self.bad_frames += 1
            return []
        out = []
        for src in entry.sources:
            raw = values.get(src.signal.name)
            if raw is None:
                continue
            sample = self._count(src, int(raw), values, frame.timestamp_s) if src.kind == "count" else \
                self._speed(src, raw, frame.timestamp_s)
            self.frames[src.wheel] += 1
            out.append(sample)
        return out

    def _count(self, src: _Source, raw: int, values: dict, t: float) -> WheelSample:
        w = src.wheel
        lost = 0
        seq = int(values[src.seq_signal.name]) if src.seq_signal is not None else None
        if src.last_raw is not None and src.last_t is not None:
            modulus = src.count_modulus
            delta = (raw - src.last_raw) % modulus
            if delta >= modulus // 2:  # rolling backwards
                delta -= modulus
            dt = t - src.last_t
            limit = MAX_REV_PER_S if delta >= 0 else MAX_REVERSE_REV_PER_S
            reset = abs(delta) > src.pulses_per_rev * (limit * max(dt, 0.0) + 0.1)
            if reset:
                self.counter_resets[w] += 1  # a new segment: continue at the last rate
                delta = round(src.last_rate * max(dt, 0.0))
            else:
                if raw < src.last_raw and delta > 0:
                    self.count_wraps[w] += 1
                if dt > 0:
                    src.last_rate = delta / dt
            src.count += delta
            # a node reset restarts its Seq too: the reset frame starts a new Seq sequence, not a gap
            if seq is not None and src.last_seq is not None and src.seq_signal is not None and not reset:
                lost = (seq - src.last_seq - 1) % (1 << src.seq_signal.length)
                self.lost_frames[w] += lost
        src.last_raw, src.last_seq, src.last_t = raw, seq, t
        return WheelSample(t, w, src.count / src.pulses_per_rev, src.count, float(raw), seq, lost)

    def _speed(self, src: _Source, raw: float, t: float) -> WheelSample:
        sig = src.signal
        rate = (raw * sig.scale + sig.offset) * src.rev_per_s_per_unit
        if src.last_t is not None:
            dt = t - src.last_t
            if 0 < dt <= MAX_INTEGRATION_GAP_S:
                src.revolutions += 0.5 * (src.last_rate + rate) * dt
        src.last_rate, src.last_t = rate, t
        return WheelSample(t, src.wheel, src.revolutions, None, float(raw * sig.scale + sig.offset), None, 0)
