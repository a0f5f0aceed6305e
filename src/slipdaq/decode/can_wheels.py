"""WPT frames -> WheelSample: decoded by DBC message and signal names, counts unwrapped, Seq gaps counted.

Another DBC works unchanged as long as it defines messages WPT_FL, WPT_FR, WPT_RL, WPT_RR with signals
PulseCount (cumulative, unsigned, wraps at 2^bits) and Seq (rolling counter).
"""

from __future__ import annotations

from dataclasses import dataclass

import cantools

from slipdaq import WHEELS
from slipdaq.records import CanFrame, WheelSample

COUNT_SIGNAL = "PulseCount"
SEQ_SIGNAL = "Seq"


class DbcError(ValueError):
    """The DBC lacks a message or signal slipdaq needs, or cannot be parsed."""


@dataclass(frozen=True, slots=True)
class _WheelLayout:
    wheel: str
    message: cantools.database.Message
    count_modulus: int
    seq_modulus: int


def load_dbc(text: str) -> cantools.database.Database:
    try:
        return cantools.database.load_string(text, database_format="dbc", strict=False)
    except Exception as e:  # cantools raises several parse error types
        raise DbcError(f"cannot parse DBC: {e}") from None


def wheel_layouts(db: cantools.database.Database) -> dict[int, _WheelLayout]:
    """Frame ID -> layout for each wheel's WPT_<W> message; DbcError names what is missing."""
    layouts: dict[int, _WheelLayout] = {}
    for w in WHEELS:
        name = f"WPT_{w}"
        try:
            msg = db.get_message_by_name(name)
        except KeyError:
            raise DbcError(f"message {name} not found in DBC") from None
        sigs = {s.name: s for s in msg.signals}
        for needed in (COUNT_SIGNAL, SEQ_SIGNAL):
            if needed not in sigs:
                raise DbcError(f"signal {name}.{needed} not found in DBC")
        layouts[msg.frame_id] = _WheelLayout(
            w, msg, 1 << sigs[COUNT_SIGNAL].length, 1 << sigs[SEQ_SIGNAL].length
        )
    return layouts


class WptDecoder:
    """Stateful, pure: decode WPT frames in arrival order into unwrapped cumulative counts."""

    def __init__(self, dbc_text: str) -> None:
        self._layouts = wheel_layouts(load_dbc(dbc_text))
        self._last_raw: dict[str, int] = {}
        self._last_seq: dict[str, int] = {}
        self._count: dict[str, int] = {}
        self.lost_frames: dict[str, int] = {w: 0 for w in WHEELS}
        self.count_wraps: dict[str, int] = {w: 0 for w in WHEELS}
        self.frames: dict[str, int] = {w: 0 for w in WHEELS}
        self.bad_frames = 0

    def is_wheel_frame(self, frame: CanFrame) -> bool:
        return not frame.is_extended_id and frame.arbitration_id in self._layouts

    def decode(self, frame: CanFrame) -> WheelSample | None:
        """The frame's WheelSample, or None for a frame of another ID or one that does not decode."""
        if frame.is_error_frame or frame.is_extended_id:
            return None
        layout = self._layouts.get(frame.arbitration_id)
        if layout is None:
            return None
        try:
            values = layout.message.decode(frame.data, decode_choices=False, scaling=False)
        except Exception:  # wrong DLC or bytes cantools cannot decode
            self.bad_frames += 1
            return None
        raw = int(values[COUNT_SIGNAL])
        seq = int(values[SEQ_SIGNAL])
        w = layout.wheel
        lost = 0
        if w in self._last_raw:
            delta = (raw - self._last_raw[w]) % layout.count_modulus
            if delta >= layout.count_modulus // 2:  # rolling backwards
                delta -= layout.count_modulus
            if raw < self._last_raw[w] and delta > 0:
                self.count_wraps[w] += 1
            self._count[w] += delta
            lost = (seq - self._last_seq[w] - 1) % layout.seq_modulus
            self.lost_frames[w] += lost
        else:
            self._count[w] = 0
        self._last_raw[w] = raw
        self._last_seq[w] = seq
        self.frames[w] += 1
        return WheelSample(frame.timestamp_s, w, self._count[w], raw, seq, lost)
