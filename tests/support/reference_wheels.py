"""The wheel decoder's rule written frame by frame with Python ints and cantools alone: the oracle the decoder's
kernel (decode/wheel_unwrap.py) is checked against. Not used by slipdaq."""

from __future__ import annotations

from dataclasses import dataclass

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.decode import can_wheels
from slipdaq.decode.wheel_unwrap import MAX_INTEGRATION_GAP_S, MAX_REV_PER_S, MAX_REVERSE_REV_PER_S
from slipdaq.records import CanFrame, WheelSample


@dataclass
class _Wheel:
    wheel: str
    kind: str
    signal: object
    seq_signal: object
    pulses_per_rev: int
    rev_per_s_per_unit: float
    last_raw: int | None = None
    last_seq: int | None = None
    last_t: float | None = None
    last_rate: float = 0.0
    count: int = 0
    revolutions: float = 0.0


class ReferenceWheelDecoder:
    def __init__(self, config: Config) -> None:
        db = can_wheels.load_dbc(config.load_dbc_text())
        self.by_id: dict[int, tuple[object, list[_Wheel]]] = {}
        for w in WHEELS:
            src = config.wheel_source(w)
            msg = db.get_message_by_name(src.message)
            sig = next(s for s in msg.signals if s.name == src.signal)
            seq = next(s for s in msg.signals if s.name == src.seq_signal) if src.seq_signal else None
            rate = can_wheels._rev_per_s_per_unit(w, src, sig, config.tire.radius_m) if src.kind == "speed" else 0.0
            self.by_id.setdefault(msg.frame_id, (msg, []))[1].append(
                _Wheel(w, src.kind, sig, seq, src.pulses_per_rev or config.wpt.pulses_per_rev, rate))
        self.lost_frames = {w: 0 for w in WHEELS}
        self.count_wraps = {w: 0 for w in WHEELS}
        self.counter_resets = {w: 0 for w in WHEELS}
        self.frames = {w: 0 for w in WHEELS}
        self.bad_frames = 0

    def decode(self, frame: CanFrame) -> list[WheelSample]:
        if frame.is_error_frame or frame.is_extended_id or frame.is_remote_frame:
            return []
        if frame.arbitration_id not in self.by_id:
            return []
        msg, wheels = self.by_id[frame.arbitration_id]
        try:
            values = msg.decode_simple(frame.data, decode_choices=False, scaling=False)  # type: ignore[attr-defined]
        except Exception:
            self.bad_frames += 1
            return []
        out = []
        for src in wheels:
            raw = values.get(src.signal.name)  # type: ignore[attr-defined]
            if not isinstance(raw, int | float):
                continue
            t = frame.timestamp_s
            if src.kind == "count":
                seq = int(values[src.seq_signal.name]) if src.seq_signal is not None else None  # type: ignore[attr-defined]
                count, lost = self._count_step(src, int(raw), seq, t)
                sample = WheelSample(t, src.wheel, count / src.pulses_per_rev, count, float(raw), seq, lost)
            else:
                sample = self._speed(src, raw, t)
            self.frames[src.wheel] += 1
            out.append(sample)
        return out

    def _count_step(self, src: _Wheel, raw: int, seq: int | None, t: float) -> tuple[int, int]:
        w = src.wheel
        lost = 0
        if src.last_raw is not None and src.last_t is not None:
            modulus = 1 << src.signal.length  # type: ignore[attr-defined]
            delta = (raw - src.last_raw) % modulus
            if delta >= modulus // 2:
                delta -= modulus
            dt = t - src.last_t
            limit = MAX_REV_PER_S if delta >= 0 else MAX_REVERSE_REV_PER_S
            reset = abs(delta) > src.pulses_per_rev * (limit * max(dt, 0.0) + 0.1)
            if reset:
                self.counter_resets[w] += 1
                delta = round(src.last_rate * max(dt, 0.0))
            else:
                if raw < src.last_raw and delta > 0:
                    self.count_wraps[w] += 1
                if dt > 0:
                    src.last_rate = delta / dt
            src.count += delta
            if seq is not None and src.last_seq is not None and not reset:
                lost = (seq - src.last_seq - 1) % (1 << src.seq_signal.length)  # type: ignore[attr-defined]
                self.lost_frames[w] += lost
        src.last_raw, src.last_seq, src.last_t = raw, seq, t
        return src.count, lost

    def _speed(self, src: _Wheel, raw: float, t: float) -> WheelSample:
        sig = src.signal
        value = raw * sig.scale + sig.offset  # type: ignore[attr-defined]
        rate = value * src.rev_per_s_per_unit
        if src.last_t is not None:
            dt = t - src.last_t
            if 0 < dt <= MAX_INTEGRATION_GAP_S:
                src.revolutions += 0.5 * (src.last_rate + rate) * dt
        src.last_rate, src.last_t = rate, t
        return WheelSample(t, src.wheel, src.revolutions, None, float(value), None, 0)
