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

Fast path: a message whose wheel sources are all counts with byte-aligned, unsigned, little-endian signals of
8/16/32 bits, scale 1 and offset 0 (WPT's PulseCount and Seq) gets a precompiled struct and numpy layout at start-up,
checked against cantools' decode on edge and random payloads (any difference: it stays on cantools). decode_batch
decodes, unwraps and counts Seq gaps of such frames with numpy over a CanFrameBatch; everything else goes through the
same scalar code as decode. Both give the same samples and counters, whatever the batches.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

import cantools
import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config, WheelSourceConfig
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

NOT_WHEEL_DATA = FLAG_EXTENDED | FLAG_ERROR | FLAG_REMOTE
"""Frames that carry no wheel data whatever their ID."""
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
        db = cantools.database.load_string(text, database_format="dbc", strict=False)
    except Exception as e:  # cantools raises several parse error types
        raise DbcError(f"cannot parse DBC: {e}") from None
    if not isinstance(db, cantools.database.can.Database):
        raise DbcError("not a CAN database")
    return db


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
class _FastLayout:
    """A message's count (and Seq) signals as one struct and one numpy dtype (see the module docstring)."""

    length: int
    struct: struct.Struct
    """unpack_from(payload) -> the fields in `names` order."""
    names: list[str]
    dtype: np.dtype
    plan: list[tuple[_Source, int, int]] = field(default_factory=list)
    """Per source: its count's and Seq's positions in the unpacked fields (-1: no Seq)."""


@dataclass(slots=True)
class _Message:
    message: cantools.database.Message
    sources: list[_Source] = field(default_factory=list)
    fast: _FastLayout | None = None


_UINT_CODES = {8: "B", 16: "H", 32: "I"}
MAX_FAST_COUNT_BITS = 32
"""Fast-path counters fit int64 arithmetic with room to spare."""


def _fast_layout(entry: _Message) -> _FastLayout | None:
    """The precompiled layout when every source is a count on simple signals and it decodes as cantools does."""
    msg = entry.message
    if msg.is_extended_frame or msg.is_multiplexed() or getattr(msg, "is_container", False) or not entry.sources:
        return None
    sigs: dict[str, cantools.database.Signal] = {}
    for src in entry.sources:
        if src.kind != "count":
            return None
        sigs[src.signal.name] = src.signal
        if src.seq_signal is not None:
            sigs[src.seq_signal.name] = src.seq_signal
    fields = []
    for sig in sigs.values():
        if (sig.byte_order != "little_endian" or sig.is_signed or sig.is_float or sig.start % 8
                or sig.length not in _UINT_CODES or sig.length > MAX_FAST_COUNT_BITS or sig.scale != 1
                or sig.offset != 0 or sig.multiplexer_ids or sig.start // 8 + sig.length // 8 > msg.length):
            return None
        fields.append((sig.start // 8, sig.length // 8, sig.name, _UINT_CODES[sig.length]))
    fields.sort()
    fmt, pos = "<", 0
    for off, size, _name, code in fields:
        if off < pos:
            return None  # overlapping fields
        fmt += (f"{off - pos}x" if off > pos else "") + code
        pos = off + size
    names = [f[2] for f in fields]
    dtype = np.dtype({"names": names, "formats": [f"<u{f[1]}" for f in fields], "offsets": [f[0] for f in fields],
                      "itemsize": msg.length})
    plan = [(src, names.index(src.signal.name), names.index(src.seq_signal.name) if src.seq_signal else -1)
            for src in entry.sources]
    layout = _FastLayout(msg.length, struct.Struct(fmt), names, dtype, plan)
    rng = np.random.default_rng(7)
    n = msg.length
    payloads = [bytes(n), b"\xff" * n] + [bytes([1 << (k % 8)]) * n for k in range(8)] + \
        [rng.bytes(n) for _ in range(256)] + [rng.bytes(n + 4), rng.bytes(64)]  # excess bytes: cantools ignores them
    for p in payloads:
        try:
            ref = msg.decode_simple(p, decode_choices=False, scaling=False)
        except Exception:
            return None
        got = dict(zip(names, layout.struct.unpack_from(p)))
        arr = np.frombuffer(p[:n], dtype=dtype)[0]
        if any(type(ref[k]) is not int or ref[k] != got[k] or int(arr[k]) != got[k] for k in names):
            return None
    return layout


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
        for entry in self._by_id.values():
            entry.fast = _fast_layout(entry)
        self._wheel_index = {w: i for i, w in enumerate(WHEELS)}
        self._entries = list(self._by_id.values())
        self._lut = np.full(2048, -1, dtype=np.int16)  # standard ID -> index in _entries
        for i, entry in enumerate(self._entries):
            if entry.message.frame_id < 2048:
                self._lut[entry.message.frame_id] = i
        self._ids_beyond_lut = any(fid >= 2048 for fid in self._by_id)
        self._groups = _groups(self._entries, self._wheel_index)

    @property
    def fast_messages(self) -> list[str]:
        """Names of the messages on the precompiled fast path."""
        return [e.message.name for e in self._entries if e.fast is not None]

    def is_wheel_frame(self, frame: CanFrame) -> bool:
        """A data frame with a wheel message's standard ID (not a remote frame asking for one)."""
        return not (frame.is_extended_id or frame.is_remote_frame) and frame.arbitration_id in self._by_id

    def wheel_frames(self, batch: CanFrameBatch) -> np.ndarray:
        """Per frame: the index of its wheel message (in _entries), or -1 (another ID, extended, error or remote
        frame)."""
        ids = batch.arbitration_id
        idx = self._lut[np.minimum(ids, 2047)]
        idx = np.where(ids < 2048, idx, -1)
        if self._ids_beyond_lut:  # a wheel message with an 11-bit ID above 2047 cannot exist, but a DBC may say so
            for i, entry in enumerate(self._entries):
                if entry.message.frame_id >= 2048:
                    idx = np.where(ids == entry.message.frame_id, i, idx)
        return np.where((batch.flags & NOT_WHEEL_DATA) == 0, idx, -1).astype(np.int64)

    def decode(self, frame: CanFrame) -> list[WheelSample]:
        """The frame's WheelSamples (one per wheel it carries); none for a frame of another ID or a bad one."""
        if frame.is_error_frame or frame.is_extended_id or frame.is_remote_frame:
            return []
        entry = self._by_id.get(frame.arbitration_id)
        if entry is None:
            return []
        return self._decode(entry, frame.data, frame.timestamp_s)

    def _decode(self, entry: _Message, data: bytes, t: float) -> list[WheelSample]:
        fast = entry.fast
        if fast is not None:
            if len(data) < fast.length:  # cantools: wrong data size
                self.bad_frames += 1
                return []
            fields = fast.struct.unpack_from(data)
            out = []
            for src, ci, qi in fast.plan:
                raw = fields[ci]
                seq = fields[qi] if qi >= 0 else None
                count, lost = self._count_step(src, raw, seq, t)
                self.frames[src.wheel] += 1
                out.append(WheelSample(t, src.wheel, count / src.pulses_per_rev, count, float(raw), seq, lost))
            return out
        else:
            try:
                values = entry.message.decode_simple(data, decode_choices=False, scaling=False)
            except Exception:  # wrong DLC or bytes cantools cannot decode
                self.bad_frames += 1
                return []
        out = []
        for src in entry.sources:
            raw = values.get(src.signal.name)
            if not isinstance(raw, int | float):  # absent (multiplexed out); numbers only without choices
                continue
            sample = self._count(src, int(raw), values, t) if src.kind == "count" else self._speed(src, raw, t)
            self.frames[src.wheel] += 1
            out.append(sample)
        return out

    def _count(self, src: _Source, raw: int, values: dict, t: float) -> WheelSample:
        seq = int(values[src.seq_signal.name]) if src.seq_signal is not None else None
        count, lost = self._count_step(src, raw, seq, t)
        return WheelSample(t, src.wheel, count / src.pulses_per_rev, count, float(raw), seq, lost)

    def _count_step(self, src: _Source, raw: int, seq: int | None, t: float) -> tuple[int, int]:
        """One count frame: unwrap, reset and Seq-gap logic; returns (cumulative count, frames lost before it)."""
        w = src.wheel
        lost = 0
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
        return src.count, lost

    def _speed(self, src: _Source, raw: float, t: float) -> WheelSample:
        sig = src.signal
        rate = (raw * sig.scale + sig.offset) * src.rev_per_s_per_unit
        if src.last_t is not None:
            dt = t - src.last_t
            if 0 < dt <= MAX_INTEGRATION_GAP_S:
                src.revolutions += 0.5 * (src.last_rate + rate) * dt
        src.last_rate, src.last_t = rate, t
        return WheelSample(t, src.wheel, src.revolutions, None, float(raw * sig.scale + sig.offset), None, 0)

    # ---- batches ------------------------------------------------------------------------------------
    def decode_batch(self, batch: CanFrameBatch, which: np.ndarray | None = None) -> WheelSampleBatch:
        """decode() of every frame of the batch in order, as columns: the same samples and counters.

        which: wheel_frames(batch), when the caller has it already."""
        if which is None:
            which = self.wheel_frames(batch)
        cols: list[tuple[np.ndarray, ...]] = []  # (frame, source order, wheel, t, rev, count, raw, seq, lost, flags)
        ts = batch.timestamp_s
        done: set[int] = set()
        for g in self._groups:
            c = self._group_columns(g, batch, which)
            if c is not None:
                done.update(g.entries)
                if len(c[0]):
                    cols.append(c)
        for e, entry in enumerate(self._entries):
            if e in done:
                continue
            sel = np.flatnonzero(which == e)
            if len(sel) == 0:
                continue
            fast = entry.fast
            if fast is not None:
                good = batch.payload_lengths()[sel] >= fast.length
                if not good.all():
                    self.bad_frames += int(np.count_nonzero(~good))
                    sel = sel[good]
                    if len(sel) == 0:
                        continue
                fields = batch.data[sel, : fast.length].copy().view(fast.dtype).reshape(-1)
                for order, src in enumerate(entry.sources):
                    seq = fields[src.seq_signal.name].astype(np.int64) if src.seq_signal is not None else None
                    cols.append(self._count_columns(src, order, sel, ts[sel], fields[src.signal.name].astype(np.int64),
                                                    seq))
            else:
                cols.append(self._scalar_columns(entry, batch, sel))
        if not cols:
            return _empty_samples()
        if len(cols) > 1:  # each part is in frame order already; merge them (ties in source order)
            cat = [np.concatenate(c) for c in zip(*cols)]
            o = np.lexsort((cat[1], cat[0]))
            cat = [c[o] for c in cat]
        else:
            cat = list(cols[0])
        frame, _order, wheel, t, rev, count, raw, seq, lost, flags = cat
        return WheelSampleBatch(frame, wheel.astype(np.uint8), t, rev, count, raw, seq, lost, flags.astype(np.uint8))

    def _group_columns(self, g: _Group, batch: CanFrameBatch, which: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """_count_step over the frames of every message of a group at once (sorted by source, vectorised); None
        (nothing changed) when a counter reset needs the frame-by-frame path."""
        slot = g.slot_of[which]
        sel = np.flatnonzero(slot >= 0)
        if len(sel) == 0:
            return tuple(np.empty(0, dtype=d) for d in _COLUMN_DTYPES)
        good = batch.payload_lengths()[sel] >= g.length
        if not good.all():
            sel = sel[good]
            if len(sel) == 0:
                self.bad_frames += len(good)
                return tuple(np.empty(0, dtype=d) for d in _COLUMN_DTYPES)
        s0 = slot[sel]
        fields = batch.data[sel, : g.length].copy().view(g.dtype).reshape(-1)
        r0 = fields[g.count_name].astype(np.int64)
        q0 = fields[g.seq_name].astype(np.int64) if g.seq_name is not None else None
        t0 = batch.timestamp_s[sel]
        order = np.argsort(s0, kind="stable")  # by source, each source's frames in order
        s, r, t = s0[order], r0[order], t0[order]
        q = q0[order] if q0 is not None else None
        n = len(sel)
        brk = np.flatnonzero(s[1:] != s[:-1]) + 1
        starts = [0, *brk.tolist()]
        ends = [*brk.tolist(), n]
        srcs = [g.sources[k] for k in s[starts].tolist()]
        prev_r = np.empty_like(r)
        prev_r[1:] = r[:-1]
        prev_t = np.empty_like(t)
        prev_t[1:] = t[:-1]
        firsts = []
        for k, src in zip(starts, srcs):
            if src.last_raw is None or src.last_t is None:
                prev_r[k], prev_t[k] = r[k], t[k]
                firsts.append(k)
            else:
                prev_r[k], prev_t[k] = src.last_raw, src.last_t
        modulus = g.count_modulus
        delta = (r - prev_r) % modulus
        delta[delta >= modulus // 2] -= modulus
        dt = t - prev_t
        # A reset needs |delta| > ppr * (limit * max(dt, 0) + 0.1) >= ppr * 0.1: check in full only above that.
        if np.abs(delta).max() > g.pulses_per_rev * 0.1:
            limit = np.where(delta >= 0, MAX_REV_PER_S, MAX_REVERSE_REV_PER_S)
            if bool((np.abs(delta) > g.pulses_per_rev * (limit * np.maximum(dt, 0.0) + 0.1)).any()):
                return None  # a counter reset: the per-source path (the reset continues at the last rate)
        self.bad_frames += int(np.count_nonzero(~good))
        if firsts:
            delta[firsts] = 0
        wraps = np.add.reduceat(((r < prev_r) & (delta > 0)).astype(np.int64), starts).tolist()
        cs = np.cumsum(delta)
        bases = np.array([src.count for src in srcs], dtype=np.int64) - (cs[starts] - delta[starts])
        count_s = cs + np.repeat(bases, np.subtract(ends, starts))
        count = np.empty(n, dtype=np.int64)
        count[order] = count_s  # back to frame order
        lost = np.zeros(n, dtype=np.int64)
        lost_sums: list[int] = [0] * len(srcs)
        if q is not None:
            prev_q = np.empty_like(q)
            prev_q[1:] = q[:-1]
            for k, src in zip(starts, srcs):
                prev_q[k] = q[k] - 1 if (k in firsts or src.last_seq is None) else src.last_seq
            lost_s = (q - prev_q - 1) % g.seq_modulus
            lost_sums = np.add.reduceat(lost_s, starts).tolist()
            lost[order] = lost_s
        dt_last = dt[np.subtract(ends, 1)].tolist()
        for j, (k0, k1, src) in enumerate(zip(starts, ends, srcs)):
            w = src.wheel
            self.frames[w] += k1 - k0
            self.count_wraps[w] += wraps[j]
            self.lost_frames[w] += lost_sums[j]
            last = k1 - 1
            if dt_last[j] > 0:
                m = last
            else:  # the last frame with dt > 0 sets the rate
                moving = np.flatnonzero(dt[k0:k1] > 0)
                m = k0 + int(moving[-1]) if len(moving) else -1
            if m >= 0:
                src.last_rate = int(delta[m]) / float(dt[m])
            src.count = int(count_s[last])
            src.last_raw, src.last_t = int(r[last]), float(t[last])
            src.last_seq = int(q[last]) if q is not None else None
        zeros = np.zeros(n, dtype=np.int64)
        return (sel.astype(np.int64), zeros, g.wheel_of[s0], t0, count / g.pulses_per_rev, count,
                r0.astype(np.float64), q0 if q0 is not None else zeros, lost, np.full(n, g.flags, dtype=np.int64))

    def _scalar_columns(self, entry: _Message, batch: CanFrameBatch, sel: np.ndarray) -> tuple[np.ndarray, ...]:
        rows = []
        order = {id(src): k for k, src in enumerate(entry.sources)}
        by_wheel = {src.wheel: src for src in entry.sources}
        for i in sel.tolist():
            for s in self._decode(entry, batch.payload(i), float(batch.timestamp_s[i])):
                fl = (SAMPLE_HAS_COUNT if s.count is not None else 0) | (SAMPLE_HAS_SEQ if s.seq is not None else 0)
                rows.append((i, order[id(by_wheel[s.wheel])], self._wheel_index[s.wheel], s.timestamp_s,
                             s.revolutions, s.count or 0, s.raw, s.seq or 0, s.lost_frames, fl))
        if not rows:
            return tuple(np.empty(0, dtype=d) for d in _COLUMN_DTYPES)
        return tuple(np.array(c, dtype=d) for c, d in zip(zip(*rows), _COLUMN_DTYPES))

    def _count_columns(self, src: _Source, order: int, frame: np.ndarray, t: np.ndarray, raw: np.ndarray,
                       seq: np.ndarray | None) -> tuple[np.ndarray, ...]:
        """_count_step over one source's frames of a batch, vectorised; a batch with a counter reset goes frame by
        frame (the reset continues at the last rate, which depends on every frame before it)."""
        n = len(raw)
        w = src.wheel
        count = np.empty(n, dtype=np.int64)
        lost = np.zeros(n, dtype=np.int64)
        last_raw, last_t = src.last_raw, src.last_t
        first = last_raw is None or last_t is None
        if last_raw is None or last_t is None:  # the source's first frame: count and lost stay as they are
            prev_raw = np.concatenate((raw[:1], raw[:-1]))
            prev_t = np.concatenate((t[:1], t[:-1]))
        else:
            prev_raw = np.concatenate(([last_raw], raw[:-1]))
            prev_t = np.concatenate(([last_t], t[:-1]))
        modulus = src.count_modulus
        delta = (raw - prev_raw) % modulus
        delta[delta >= modulus // 2] -= modulus
        dt = t - prev_t
        limit = np.where(delta >= 0, MAX_REV_PER_S, MAX_REVERSE_REV_PER_S)
        reset = np.abs(delta) > src.pulses_per_rev * (limit * np.maximum(dt, 0.0) + 0.1)
        if bool(reset.any()):
            for k, (r, q, tk) in enumerate(zip(raw.tolist(), seq.tolist() if seq is not None else [None] * n,
                                                t.tolist())):
                count[k], lost[k] = self._count_step(src, r, q, tk)
        else:
            if first:
                delta[0] = 0
            self.count_wraps[w] += int(np.count_nonzero((raw < prev_raw) & (delta > 0)))
            np.cumsum(delta, out=count)
            count += src.count
            moving = np.flatnonzero(dt > 0)
            if len(moving):
                k = int(moving[-1])
                src.last_rate = int(delta[k]) / float(dt[k])
            if seq is not None and src.seq_signal is not None:
                if first:
                    prev_seq = np.concatenate((seq[:1] - 1, seq[:-1]))
                else:
                    prev_seq = np.concatenate(([src.last_seq if src.last_seq is not None else 0], seq[:-1]))
                lost = (seq - prev_seq - 1) % (1 << src.seq_signal.length)
                if first or src.last_seq is None:
                    lost[0] = 0
                self.lost_frames[w] += int(lost.sum())
            src.count = int(count[-1])
            src.last_raw, src.last_t = int(raw[-1]), float(t[-1])
            src.last_seq = int(seq[-1]) if seq is not None else None
        self.frames[w] += n
        flags = SAMPLE_HAS_COUNT | (SAMPLE_HAS_SEQ if seq is not None else 0)
        return (frame.astype(np.int64), np.full(n, order, dtype=np.int64), np.full(n, self._wheel_index[w], np.int64),
                t.astype(np.float64), count / src.pulses_per_rev, count, raw.astype(np.float64),
                seq if seq is not None else np.zeros(n, dtype=np.int64), lost, np.full(n, flags, dtype=np.int64))


@dataclass(slots=True)
class _Group:
    """Fast messages of one source each that share a layout (WPT_FL..RR): decoded and unwrapped together."""

    entries: list[int]
    sources: list[_Source]
    slot_of: np.ndarray
    """entry index (which) -> slot in `sources`, -1 for others; index -1 (no wheel message) gives -1."""
    wheel_of: np.ndarray
    length: int
    dtype: np.dtype
    count_name: str
    seq_name: str | None
    count_modulus: int
    seq_modulus: int
    pulses_per_rev: int
    flags: int


def _groups(entries: list[_Message], wheel_index: dict[str, int]) -> list[_Group]:
    by_key: dict[tuple, list[int]] = {}
    for e, entry in enumerate(entries):
        if entry.fast is None or len(entry.sources) != 1:
            continue
        src = entry.sources[0]
        seq = src.seq_signal
        key = (entry.fast.length, str(entry.fast.dtype.descr), src.signal.name, seq.name if seq else None,
               src.signal.length, seq.length if seq else 0, src.pulses_per_rev)
        by_key.setdefault(key, []).append(e)
    out = []
    for (length, _descr, count_name, seq_name, count_bits, seq_bits, ppr), idx in by_key.items():
        slot_of = np.full(len(entries) + 1, -1, dtype=np.int64)
        slot_of[idx] = np.arange(len(idx))
        sources = [entries[e].sources[0] for e in idx]
        out.append(_Group(idx, sources, slot_of, np.array([wheel_index[s.wheel] for s in sources], dtype=np.int64),
                          length, entries[idx[0]].fast.dtype, count_name, seq_name,  # type: ignore[union-attr]  # every entry of a group has a fast layout
                          1 << count_bits, 1 << seq_bits, ppr,
                          SAMPLE_HAS_COUNT | (SAMPLE_HAS_SEQ if seq_name else 0)))
    return out


_COLUMN_DTYPES = (np.int64, np.int64, np.int64, np.float64, np.float64, np.int64, np.float64, np.int64, np.int64,
                  np.int64)


def _empty_samples() -> WheelSampleBatch:
    e = np.empty(0, dtype=np.int64)
    f = np.empty(0, dtype=np.float64)
    return WheelSampleBatch(e, e.astype(np.uint8), f, f, e, f, e, e, e.astype(np.uint8))
