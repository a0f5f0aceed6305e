"""CAN frames -> WheelSample per wheel, by DBC message and signal names (cantools). Two kinds of wheel source:

- count: a cumulative pulse counter (WPT default: WPT_<W>.PulseCount, wrapping at 2^bits of the signal), unwrapped;
  an optional rolling sequence counter (WPT: Seq) whose gaps are lost frames; a jump the wheel cannot have made is a
  counter node reset (decode/wheel_unwrap.py: the rule, one kernel for every batch).
- speed: a wheel-speed signal (km/h, kph, m/s, mph, rpm, rad/s, deg/s; from the DBC's unit or the config), integrated
  over time (trapezoids) into revolutions. Linear speeds are turned into revolutions with the tire's radius, so a
  calibrated r0 for such a wheel is that radius times the signal's scale error.
Several wheels may share one message (one WHEEL_SPEEDS frame for all four).

A message whose wheel sources are all counts with byte-aligned, unsigned, little-endian signals of 8/16/32 bits,
scale 1 and offset 0 (WPT's PulseCount and Seq) is read by a numpy layout built at start-up, checked against
cantools' decode on edge and random payloads (any difference: it stays on cantools); every other message goes through
cantools frame by frame. Either way the signals go through the same unwrap kernel.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config, WheelSourceConfig
from slipdaq.decode import layout_cache
from slipdaq.decode.wheel_unwrap import (
    C_FRAMES,
    C_LOST,
    C_RESETS,
    C_WRAPS,
    KIND_COUNT,
    KIND_SPEED,
    MAX_COUNT_BITS,
    P_KIND,
    P_SEQ_MODULUS,
    new_state,
    unwrap,
)
from slipdaq.records import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_REMOTE,
    SAMPLE_HAS_COUNT,
    SAMPLE_HAS_SEQ,
    CanFrame,
    CanFrameBatch,
    WheelSample,
    WheelSampleBatch,
)

if TYPE_CHECKING:
    import cantools

NOT_WHEEL_DATA = FLAG_EXTENDED | FLAG_ERROR | FLAG_REMOTE
"""Frames that carry no wheel data whatever their ID."""

_REV_PER_S_PER_UNIT = {"rpm": 1.0 / 60.0, "rad/s": 1.0 / (2 * math.pi), "deg/s": 1.0 / 360.0}
MPS_PER_UNIT = {"km/h": 1.0 / 3.6, "kph": 1.0 / 3.6, "kmh": 1.0 / 3.6, "m/s": 1.0, "mps": 1.0, "mph": 0.44704,
                "kn": 1852.0 / 3600.0, "kt": 1852.0 / 3600.0, "knots": 1852.0 / 3600.0}
"""m/s per unit of a linear speed signal (DBC unit names, lower case)."""


class DbcError(ValueError):
    """The DBC lacks a message or signal slipdaq needs, or cannot be parsed."""


def load_dbc(text: str) -> cantools.database.Database:
    from slipdaq.__main__ import import_cantools

    cantools = import_cantools()
    try:
        db = cantools.database.load_string(text, database_format="dbc", strict=False)
    except Exception as e:  # cantools raises several parse error types
        raise DbcError(f"cannot parse DBC: {e}") from None
    if not isinstance(db, cantools.database.can.Database):
        raise DbcError("not a CAN database")
    return db


@dataclass(frozen=True, slots=True)
class _Named:
    """A DBC message or signal as a decoder that reads it through a numpy layout needs it: its name (a message's ID
    too), from the layout cache."""

    name: str
    frame_id: int = -1


@dataclass(slots=True)
class _Source:
    wheel: str
    index: int
    """in WHEELS."""
    kind: str
    signal: cantools.database.Signal | _Named
    seq_signal: cantools.database.Signal | _Named | None


@dataclass(slots=True)
class _FastLayout:
    """A message's count (and Seq) signals as one numpy dtype (see the module docstring)."""

    length: int
    names: list[str]
    dtype: np.dtype


@dataclass(slots=True)
class _Message:
    message: cantools.database.Message | _Named
    sources: list[_Source] = field(default_factory=list)
    fast: _FastLayout | None = None


_FAST_BITS = (8, 16, 32)


def _fast_layout(entry: _Message) -> _FastLayout | None:
    """The precompiled layout when every source is a count on simple signals and it decodes as cantools does."""
    msg = entry.message
    assert not isinstance(msg, _Named), "a layout is made from the DBC"
    if msg.is_extended_frame or msg.is_multiplexed() or getattr(msg, "is_container", False) or not entry.sources:
        return None
    sigs: dict[str, cantools.database.Signal] = {}
    for src in entry.sources:
        if src.kind != "count":
            return None
        assert not isinstance(src.signal, _Named) and not isinstance(src.seq_signal, _Named)
        sigs[src.signal.name] = src.signal
        if src.seq_signal is not None:
            sigs[src.seq_signal.name] = src.seq_signal
    fields = []
    for sig in sigs.values():
        if (sig.byte_order != "little_endian" or sig.is_signed or sig.is_float or sig.start % 8
                or sig.length not in _FAST_BITS or sig.scale != 1
                or sig.offset != 0 or sig.multiplexer_ids or sig.start // 8 + sig.length // 8 > msg.length):
            return None
        fields.append((sig.start // 8, sig.length // 8, sig.name))
    fields.sort()
    pos = 0
    for off, size, _name in fields:
        if off < pos:
            return None  # overlapping fields
        pos = off + size
    names = [f[2] for f in fields]
    dtype = np.dtype({"names": names, "formats": [f"<u{f[1]}" for f in fields], "offsets": [f[0] for f in fields],
                      "itemsize": msg.length})
    layout = _FastLayout(msg.length, names, dtype)
    rng = np.random.default_rng(7)
    n = msg.length
    payloads = [bytes(n), b"\xff" * n] + [bytes([1 << (k % 8)]) * n for k in range(8)] + \
        [rng.bytes(n) for _ in range(256)] + [rng.bytes(n + 4), rng.bytes(64)]  # excess bytes: cantools ignores them
    for p in payloads:
        try:
            ref = msg.decode_simple(p, decode_choices=False, scaling=False)
        except Exception:
            return None
        arr = np.frombuffer(p[:n], dtype=dtype)[0]
        if any(type(ref[k]) is not int or ref[k] != int(arr[k]) for k in names):
            return None
    return layout


def _rev_per_s_per_unit(wheel: str, src: WheelSourceConfig, signal: cantools.database.Signal, radius_m: float) -> float:
    unit = (src.unit or signal.unit or "").strip().lower().replace("kph", "km/h").replace("kmh", "km/h")
    if unit in _REV_PER_S_PER_UNIT:
        return _REV_PER_S_PER_UNIT[unit]
    if unit in MPS_PER_UNIT:
        return MPS_PER_UNIT[unit] / (2 * math.pi * radius_m)
    raise DbcError(
        f"wheels.{wheel}: speed signal {src.message}.{src.signal} has unit {signal.unit!r}: "
        f"set wheels.{wheel}.unit to one of km/h, m/s, mph, rpm, rad/s, deg/s"
    )


def _signal(msg: cantools.database.Message, name: str, wheel: str, key: str) -> cantools.database.Signal:
    for s in msg.signals:
        if s.name == name:
            return s
    raise DbcError(f"wheels.{wheel}.{key}: signal {msg.name}.{name} not found in DBC")


LAYOUT_CACHE_NAME = "wheel-layout"
"""The layout cache's name for a WheelDecoder's messages, sources and parameters."""
LAYOUT_FORMAT = "1"
"""The cached layout's form: part of its key."""


@functools.cache
def _code_version() -> bytes:
    """What a layout depends on besides the DBC and the config, once a process: this module's code and the versions
    of cantools and numpy."""
    return hashlib.sha256(Path(__file__).read_bytes() + json.dumps(
        [LAYOUT_FORMAT, importlib.metadata.version("cantools"), np.__version__]).encode()).digest()


def _layout_key(config: Config, text: str) -> str:
    """The layout cache's key: a SHA-256 over the DBC's text, the wheel sources (and what the parameters take from
    the config) and _code_version."""
    h = hashlib.sha256(_code_version())
    sources = [config.wheel_source(w).model_dump(mode="json") for w in WHEELS]
    h.update(json.dumps([sources, config.wpt.pulses_per_rev, config.tire.radius_m], sort_keys=True).encode())
    h.update(text.encode("utf-8", "surrogateescape"))
    return h.hexdigest()[:24]


def _from_dbc(config: Config, text: str) -> tuple[dict[int, _Message], np.ndarray, np.ndarray]:
    """The wheel messages by frame ID (with their numpy layouts where cantools decodes them the same), and the
    unwrap kernel's integer and float parameters per wheel, from the DBC (cantools)."""
    db = load_dbc(text)
    by_id: dict[int, _Message] = {}
    params = np.zeros((len(WHEELS), 4), dtype=np.int64)
    params_f = np.zeros((len(WHEELS), 3), dtype=np.float64)
    for i, w in enumerate(WHEELS):
        src = config.wheel_source(w)
        try:
            msg = db.get_message_by_name(src.message)
        except KeyError:
            raise DbcError(f"wheels.{w}.message: message {src.message} not found in DBC") from None
        sig = _signal(msg, src.signal, w, "signal")
        seq = _signal(msg, src.seq_signal, w, "seq_signal") if src.seq_signal else None
        ppr = src.pulses_per_rev or config.wpt.pulses_per_rev
        if src.kind == "count":
            for s, key in ((sig, "signal"), (seq, "seq_signal")):
                if s is not None and s.length > MAX_COUNT_BITS:
                    raise DbcError(f"wheels.{w}.{key}: {msg.name}.{s.name} has {s.length} bits; a counter may "
                                   f"have at most {MAX_COUNT_BITS}")
            params[i] = (KIND_COUNT, 1 << sig.length, ppr, (1 << seq.length) if seq is not None else 0)
        else:
            params[i] = (KIND_SPEED, 0, ppr, 0)
            params_f[i] = (float(sig.scale), float(sig.offset), _rev_per_s_per_unit(w, src, sig, config.tire.radius_m))
        entry = by_id.setdefault(msg.frame_id, _Message(msg))
        entry.sources.append(_Source(w, i, src.kind, sig, seq))
    for entry in by_id.values():
        entry.fast = _fast_layout(entry)
    return by_id, params, params_f


Plain = list[tuple[int, str, list[tuple[str, int, str, str, str | None]], tuple[int, list[str], np.dtype]]]
"""A decoder's messages as plain data (_plain): frame ID, name, sources (wheel, index, kind, signal, Seq signal),
layout (length, field names, dtype)."""


def _plain(by_id: dict[int, _Message]) -> Plain | None:
    """The messages as plain data where every one reads through its numpy layout; None where cantools decodes some
    (their decoder needs the DBC's messages)."""
    if any(e.fast is None for e in by_id.values()):
        return None
    return [(fid, e.message.name,
             [(s.wheel, s.index, s.kind, s.signal.name, s.seq_signal.name if s.seq_signal is not None else None)
              for s in e.sources],
             (e.fast.length, e.fast.names, e.fast.dtype))
            for fid, e in by_id.items() if e.fast is not None]


def _from_plain(plain: Plain) -> dict[int, _Message]:
    return {fid: _Message(_Named(name, fid),
                          [_Source(w, i, kind, _Named(sig), _Named(seq) if seq is not None else None)
                           for w, i, kind, sig, seq in sources],
                          _FastLayout(*fast))
            for fid, name, sources, fast in plain}


class WheelDecoder:
    """Stateful, pure: decode wheel frames in arrival order into cumulative revolutions per wheel
    (decode/wheel_unwrap.py: the unwrap, reset, Seq and integration rule)."""

    def __init__(self, config: Config, dbc_text: str | None = None) -> None:
        """config: the wheel sources and their DBC (dbc_text: that DBC's text where the caller has it). A DBC whose
        wheel messages all read through numpy layouts is parsed once: the layouts are kept in the cache directory
        (layout_cache), under a key of the DBC, the wheel sources and cantools' version, and cantools (and
        python-can) is not imported where they are found there."""
        text = dbc_text if dbc_text is not None else config.load_dbc_text()
        key = _layout_key(config, text)
        cached = layout_cache.load(LAYOUT_CACHE_NAME, key)
        if cached is not None:
            plain, self._params, self._params_f = cached
            self._by_id = _from_plain(plain)
        else:
            self._by_id, self._params, self._params_f = _from_dbc(config, text)
            plain = _plain(self._by_id)
            if plain is not None:
                layout_cache.store(LAYOUT_CACHE_NAME, key, (plain, self._params, self._params_f))
        self._state, self._state_f, self._counters = new_state(len(WHEELS))
        self._sample_flags = np.where(self._params[:, P_KIND] == KIND_COUNT, SAMPLE_HAS_COUNT, 0).astype(np.uint8) | \
            np.where(self._params[:, P_SEQ_MODULUS] > 0, SAMPLE_HAS_SEQ, 0).astype(np.uint8)
        """per wheel: the flags of its samples."""
        self.bad_frames = 0
        self._entries = list(self._by_id.values())
        self._lut = np.full(2048, -1, dtype=np.int64)  # standard ID -> index in _entries
        for i, entry in enumerate(self._entries):
            if entry.message.frame_id < 2048:
                self._lut[entry.message.frame_id] = i
        self._ids_beyond_lut = any(fid >= 2048 for fid in self._by_id)
        self._groups = _groups(self._entries)
        self._on_cantools = np.array([e.fast is None for e in self._entries] + [False], dtype=bool)
        """by entry index (index -1, no wheel message: False)."""
        self._any_on_cantools = bool(self._on_cantools.any())

    # ---- counters, per wheel ------------------------------------------------------------------------
    def _per_wheel(self, column: int) -> dict[str, int]:
        return dict(zip(WHEELS, self._counters[:, column].tolist()))

    @property
    def frames(self) -> dict[str, int]:
        """Samples decoded."""
        return self._per_wheel(C_FRAMES)

    @property
    def lost_frames(self) -> dict[str, int]:
        """Frames missing by the Seq counter."""
        return self._per_wheel(C_LOST)

    @property
    def count_wraps(self) -> dict[str, int]:
        return self._per_wheel(C_WRAPS)

    @property
    def counter_resets(self) -> dict[str, int]:
        return self._per_wheel(C_RESETS)

    @property
    def fast_messages(self) -> list[str]:
        """Names of the messages decoded by their numpy layout instead of cantools."""
        return [e.message.name for e in self._entries if e.fast is not None]

    def wheel_frames(self, batch: CanFrameBatch) -> np.ndarray:
        """Per frame: the index of its wheel message (in _entries), or -1 (another ID, extended, error or remote
        frame)."""
        ids = batch.arbitration_id
        idx = self._lut[np.minimum(ids, 2047)]
        if self._ids_beyond_lut:  # a wheel message with an 11-bit ID above 2047 cannot exist, but a DBC may say so
            idx = np.where(ids < 2048, idx, -1)
            for i, entry in enumerate(self._entries):
                if entry.message.frame_id >= 2048:
                    idx = np.where(ids == entry.message.frame_id, i, idx)
            return np.where((batch.flags & NOT_WHEEL_DATA) == 0, idx, -1)
        return np.where((ids < 2048) & ((batch.flags & NOT_WHEEL_DATA) == 0), idx, -1)

    def decode(self, frame: CanFrame) -> list[WheelSample]:
        """The frame's WheelSamples (one per wheel it carries; none for a frame of another ID or a bad one): a batch
        of one."""
        return list(self.decode_batch(CanFrameBatch.from_frames([frame])).samples(WHEELS))

    def decode_batch(self, batch: CanFrameBatch, which: np.ndarray | None = None) -> WheelSampleBatch:
        """The batch's wheel samples in frame order (a frame's samples in its message's source order); the decoder's
        state and counters move on past them.

        which: wheel_frames(batch), when the caller has it already."""
        if which is None:
            which = self.wheel_frames(batch)
        parts: list[tuple[np.ndarray, ...]] = []  # (frame, source order, wheel, raw int, raw float, seq)
        for g in self._groups:
            parts += self._layout_columns(g, batch, which)
        rest = np.flatnonzero(self._on_cantools[which]) if self._any_on_cantools else ()
        if len(rest):
            entry_of = which[rest]
            for e in np.unique(entry_of).tolist():
                parts += self._cantools_columns(self._entries[e], batch, rest[entry_of == e])
        if not parts:
            return WheelSampleBatch.empty()
        if len(parts) > 1:  # each part is in frame order already; merge them (a frame's samples in source order)
            cols = [np.concatenate(c) for c in zip(*parts)]
            o = np.lexsort((cols[1], cols[0]))
            frame, _order, wheel, raw_int, raw_float, seq = (c[o] for c in cols)
        else:
            frame, _order, wheel, raw_int, raw_float, seq = parts[0]
        n = len(frame)
        count = np.empty(n, dtype=np.int64)
        revolutions = np.empty(n, dtype=np.float64)
        lost = np.empty(n, dtype=np.int64)
        raw = np.empty(n, dtype=np.float64)
        unwrap()(wheel, batch.timestamp_s[frame], raw_int, raw_float, seq, self._params, self._params_f, self._state,
                  self._state_f, self._counters, count, revolutions, lost, raw)
        return WheelSampleBatch(frame, wheel.astype(np.uint8), batch.timestamp_s[frame], revolutions, count, raw, seq,
                                lost, self._sample_flags[wheel])

    def _layout_columns(self, g: _LayoutGroup, batch: CanFrameBatch, which: np.ndarray) -> list[tuple[np.ndarray, ...]]:
        """The signals of the group's frames, read through its numpy layout."""
        sel = np.flatnonzero(g.member[which])
        if len(sel) == 0:
            return []
        good = batch.payload_lengths()[sel] >= g.layout.length
        if not good.all():  # cantools: wrong data size
            self.bad_frames += int(np.count_nonzero(~good))
            sel = sel[good]
            if len(sel) == 0:
                return []
        fields = batch.data[sel, : g.layout.length].copy().view(g.layout.dtype).reshape(-1)
        entry_of = which[sel]
        out: list[tuple[np.ndarray, ...]] = []
        for order, (count_name, seq_name) in enumerate(g.signals):
            raw = fields[count_name].astype(np.int64)
            seq = fields[seq_name].astype(np.int64) if seq_name is not None else np.zeros_like(raw)
            out.append((sel, np.full(len(sel), order), g.wheel_of[entry_of, order], raw, raw.astype(np.float64), seq))
        return out

    def _cantools_columns(self, entry: _Message, batch: CanFrameBatch,
                          sel: np.ndarray) -> list[tuple[np.ndarray, ...]]:
        msg = entry.message
        assert not isinstance(msg, _Named), "a message cantools decodes is never from the layout cache"
        rows = []
        for i in sel.tolist():
            try:
                values = msg.decode_simple(batch.payload(i), decode_choices=False, scaling=False)
            except Exception:  # wrong DLC or bytes cantools cannot decode
                self.bad_frames += 1
                continue
            for order, src in enumerate(entry.sources):
                raw = values.get(src.signal.name)
                if not isinstance(raw, int | float):  # absent (multiplexed out); numbers only without choices
                    continue
                if src.kind == "count":
                    q = values[src.seq_signal.name] if src.seq_signal is not None else 0
                    rows.append((i, order, src.index, int(raw), float(raw), int(q) if isinstance(q, int | float) else 0))
                else:
                    rows.append((i, order, src.index, 0, float(raw), 0))
        if not rows:
            return []
        return [tuple(np.array(c, dtype=d) for c, d in zip(zip(*rows), _COLUMN_DTYPES))]


@dataclass(slots=True)
class _LayoutGroup:
    """Messages read through the same numpy layout (WPT_FL..RR): their frames are read at once."""

    layout: _FastLayout
    signals: list[tuple[str, str | None]]
    """Per source, in order: its count's and its Seq's field names."""
    member: np.ndarray
    """bool, by entry index (wheel_frames' values; index -1, no wheel message, is False)."""
    wheel_of: np.ndarray
    """int64 [entry index, source order] -> wheel index."""


def _groups(entries: list[_Message]) -> list[_LayoutGroup]:
    by_key: dict[tuple, list[int]] = {}
    for e, entry in enumerate(entries):
        if entry.fast is not None:
            signals = tuple((s.signal.name, s.seq_signal.name if s.seq_signal else None) for s in entry.sources)
            by_key.setdefault((entry.fast.length, str(entry.fast.dtype.descr), signals), []).append(e)
    out = []
    for (_length, _descr, signals), members in by_key.items():
        member = np.zeros(len(entries) + 1, dtype=bool)
        member[members] = True
        wheel_of = np.full((len(entries) + 1, len(signals)), -1, dtype=np.int64)
        for e in members:
            wheel_of[e] = [s.index for s in entries[e].sources]
        out.append(_LayoutGroup(entries[members[0]].fast, list(signals), member, wheel_of))  # type: ignore[arg-type]  # members have a layout
    return out


_COLUMN_DTYPES = (np.int64, np.int64, np.int64, np.int64, np.float64, np.int64)
