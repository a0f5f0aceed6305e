"""Prototypes of the redesign proposed in docs/performance.md, measured by benchmarks/perf.py. Not used by src/.

They are written against slipdaq's current internals (SlipEstimator's rings, _drain, _gps, _pending; WptDecoder's
DBC layouts) so that they reuse the real estimator maths and can be checked bit for bit against Pipeline.process:

- CachedUtcLatency: UtcLatency.estimate() memoised until the next add() (today it takes two numpy medians on
  every wheel frame, through SlipEstimator.latency in _drain).
- WptStructLayout: a precompiled decoder for byte-aligned little-endian unsigned PulseCount/Seq signals (the WPT
  layout), as struct and numpy dtype, verified against cantools' decode at construction; None otherwise (cantools
  stays the general path).
- CDR batches: raw CAN frames and decoded wheel samples as one MCAP message per batch, schema encoding ros2msg,
  message encoding cdr (Foxglove reads both without ROS), built from numpy arrays with no per-frame Python.
- FastPipeline: CAN frames in batches -> raw batch logged -> vectorised decode, unwrap and Seq gaps per wheel ->
  samples appended to the estimator's rings in bulk -> SlipEstimator._drain called exactly where per-frame
  processing would have produced an estimate (so the estimates are the same, whatever the batch boundaries) ->
  estimates and fixes as JSON, as today. NMEA lines go one by one through NmeaDecoder and add_gps, as today.
- replay_fast: reads a FastPipeline log back (np.frombuffer on the batches) and runs it through a new FastPipeline.
"""

from __future__ import annotations

import json
import math
import struct
from collections import deque
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

import slipdaq
from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.decode.can_wheels import COUNT_SIGNAL, SEQ_SIGNAL, load_dbc, wheel_layouts
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.estimator import EstimatorParams, SlipEstimator
from slipdaq.estimator.latency import UtcLatency
from slipdaq.records import NmeaLine
from slipdaq.sinks.mcap_log import (
    METADATA_NAME, SCHEMAS, TOPIC_CAN, TOPIC_DIAGNOSTICS, TOPIC_ESTIMATE, TOPIC_GPS, TOPIC_NMEA, TOPIC_WPT,
    estimate_to_dict,
)

# ---- 1. the GPS latency, memoised ---------------------------------------------------------------------------
_UNSET = object()


class CachedUtcLatency(UtcLatency):
    """UtcLatency whose estimate() is computed once per add() instead of once per call."""

    @classmethod
    def replacing(cls, old: UtcLatency) -> "CachedUtcLatency":
        new = cls.__new__(cls)
        new.__dict__.update(old.__dict__)
        new._cached = _UNSET
        return new

    def add(self, arrival_s: float, fix_utc_s: float | None) -> None:
        super().add(arrival_s, fix_utc_s)
        self._cached = _UNSET

    def estimate(self) -> float | None:
        if self._cached is _UNSET:
            self._cached = super().estimate()
        return self._cached  # type: ignore[return-value]


def install_cached_latency(estimator: SlipEstimator) -> None:
    estimator._utc = CachedUtcLatency.replacing(estimator._utc)


# ---- 2. precompiled WPT decoder -------------------------------------------------------------------------------
_NP_UINT = {8: "u1", 16: "<u2", 32: "<u4", 64: "<u8"}
_ST_UINT = {8: "B", 16: "H", 32: "I", 64: "Q"}


class WptStructLayout:
    """Frame ID -> (wheel index, count modulus, seq modulus) with one numpy dtype and one struct for all WPT IDs."""

    def __init__(self, ids: dict[int, int], count_bits: int, seq_bits: int, dtype: np.dtype, st: struct.Struct):
        self.ids = ids
        self.count_modulus = 1 << count_bits
        self.seq_modulus = 1 << seq_bits
        self.dtype = dtype
        self.struct = st

    @classmethod
    def from_dbc(cls, dbc_text: str) -> "WptStructLayout | None":
        """The fast layout when every WPT message is 8 bytes with byte-aligned LE unsigned signals, else None."""
        layouts = wheel_layouts(load_dbc(dbc_text))
        shapes = set()
        ids: dict[int, int] = {}
        for frame_id, lay in layouts.items():
            msg = lay.message
            sig = {s.name: s for s in msg.signals}
            c, q = sig[COUNT_SIGNAL], sig[SEQ_SIGNAL]
            for s in (c, q):
                if (s.byte_order != "little_endian" or s.is_signed or s.start % 8 or s.length not in _NP_UINT
                        or s.scale != 1 or s.offset != 0 or s.is_multiplexer or s.multiplexer_ids):
                    return None
            if msg.length != 8 or msg.is_extended_frame:
                return None
            shapes.add((c.start // 8, c.length, q.start // 8, q.length))
            ids[frame_id] = WHEELS.index(lay.wheel)
        if len(shapes) != 1:
            return None
        (cb, cl, qb, ql), = shapes
        if max(cb + cl // 8, qb + ql // 8) > 8 or not (cb + cl // 8 <= qb or qb + ql // 8 <= cb):
            return None
        dtype = np.dtype({"names": ["count", "seq"], "formats": [_NP_UINT[cl], _NP_UINT[ql]],
                          "offsets": [cb, qb], "itemsize": 8})
        fields = sorted([(cb, _ST_UINT[cl], cl // 8), (qb, _ST_UINT[ql], ql // 8)])
        fmt, pos = "<", 0
        for off, code, size in fields:
            fmt += f"{off - pos}x" if off > pos else ""
            fmt += code
            pos = off + size
        fmt += f"{8 - pos}x" if pos < 8 else ""
        st = struct.Struct(fmt)
        count_first = fields[0][0] == cb
        layout = cls(ids, cl, ql, dtype, st)
        layout._count_first = count_first
        # verified against cantools on edge and random payloads; any difference: no fast path
        rng = np.random.default_rng(7)
        payloads = [bytes(8), b"\xff" * 8] + [rng.bytes(8) for _ in range(256)]
        for frame_id, lay in layouts.items():
            for p in payloads:
                ref = lay.message.decode(p, decode_choices=False, scaling=False)
                got = layout.unpack(p)
                arr = np.frombuffer(p, dtype=dtype)[0]
                if (int(ref[COUNT_SIGNAL]), int(ref[SEQ_SIGNAL])) != got or got != (int(arr["count"]),
                                                                                  int(arr["seq"])):
                    return None
        return layout

    def unpack(self, payload: bytes) -> tuple[int, int]:
        a, b = self.struct.unpack(payload)
        return (a, b) if self._count_first else (b, a)


def cantools_decode_all(dbc_text: str, frames: list[tuple[int, bytes]]) -> list[tuple[int, int]]:
    layouts = wheel_layouts(load_dbc(dbc_text))
    out = []
    for fid, data in frames:
        v = layouts[fid].message.decode(data, decode_choices=False, scaling=False)
        out.append((int(v[COUNT_SIGNAL]), int(v[SEQ_SIGNAL])))
    return out


# ---- 3. CDR batches (ros2msg schemas) -------------------------------------------------------------------------
CAN_BATCH_SCHEMA = """# slipdaq/msg/CanFrameBatch: consecutive raw CAN frames in arrival order
uint64 first_index      # running index of the first frame (NMEA lines carry can_index to sit between frames)
float64[] timestamp_s   # receive timestamps
uint32[] id
uint8[] flags           # bit 0 extended id, bit 1 error frame
uint8[] dlc
uint8[] data            # 8 bytes per frame, zero-padded: frame i at [8i, 8i+8)
"""
WHEEL_BATCH_SCHEMA = """# slipdaq/msg/WheelSampleBatch: decoded WPT samples in arrival order
uint64 first_index
float64[] timestamp_s
uint8[] wheel           # 0 FL, 1 FR, 2 RL, 3 RR
int64[] count           # unwrapped cumulative pulses since the wheel's first frame
uint32[] raw_count
uint8[] seq
uint16[] lost_frames
"""
_CDR_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian


def _cdr(first_index: int, arrays: list[np.ndarray]) -> bytes:
    """XCDR1 little endian: uint64, then sequences (uint32 length, elements aligned to their size)."""
    parts = [_CDR_HEADER, struct.pack("<Q", first_index)]
    pos = 8
    for a in arrays:
        pad = (-pos) % 4
        parts.append(b"\0" * pad + struct.pack("<I", a.size))
        pos += pad + 4
        pad = (-pos) % a.dtype.itemsize
        if pad:
            parts.append(b"\0" * pad)
            pos += pad
        b = a.tobytes()
        parts.append(b)
        pos += len(b)
    return b"".join(parts)


def _cdr_read(buf: bytes, dtypes: list[str]) -> tuple[int, list[np.ndarray]]:
    first = struct.unpack_from("<Q", buf, 4)[0]
    pos = 8
    out = []
    for dt in dtypes:
        d = np.dtype(dt)
        pos += (-pos) % 4
        n = struct.unpack_from("<I", buf, 4 + pos)[0]
        pos += 4
        pos += (-pos) % d.itemsize
        out.append(np.frombuffer(buf, dtype=d, count=n, offset=4 + pos))
        pos += n * d.itemsize
    return first, out


CAN_DTYPES = ["<f8", "<u4", "u1", "u1", "u1"]
WHEEL_DTYPES = ["<f8", "u1", "<i8", "<u4", "u1", "<u2"]


class _Batcher:
    """Coalesces chunks of columns (numpy path) and rows (scalar path) into one message of at least max_frames
    frames or max_span_s of log time."""

    def __init__(self, write, dtypes: list[str], max_frames: int = 512, max_span_s: float = 0.05) -> None:
        self._write = write
        self.dtypes = [np.dtype(d) for d in dtypes]
        self.max_frames, self.max_span_s = max_frames, max_span_s
        self.chunks: list[list[np.ndarray]] = []
        self.rows: list[tuple[Any, ...]] = []
        self.n = 0
        self.first_index = 0
        self.t0 = 0.0

    def _rows_to_chunk(self) -> None:
        if self.rows:
            cols = list(zip(*self.rows))
            chunk = [np.array(c, dtype=d) if not isinstance(c[0], bytes) else
                     np.frombuffer(b"".join(c), dtype=np.uint8) for c, d in zip(cols, self.dtypes)]
            self.chunks.append(chunk)
            self.rows = []

    def add(self, index: int, t0: float, t1: float, cols: list[np.ndarray]) -> None:
        if not self.chunks and not self.rows:
            self.first_index, self.t0 = index, t0
        self._rows_to_chunk()
        self.chunks.append(cols)
        self.n += len(cols[0])
        if self.n >= self.max_frames or t1 - self.t0 >= self.max_span_s:
            self.flush(t1)

    def add_row(self, index: int, row: tuple[Any, ...]) -> None:
        if not self.chunks and not self.rows:
            self.first_index, self.t0 = index, row[0]
        self.rows.append(row)
        self.n += 1
        if self.n >= self.max_frames or row[0] - self.t0 >= self.max_span_s:
            self.flush(row[0])

    def flush(self, log_time_s: float | None = None) -> None:
        self._rows_to_chunk()
        if not self.chunks:
            return
        cols = [np.concatenate(c) if len(c) > 1 else c[0] for c in zip(*self.chunks)]
        self._write(self.first_index, self.t0 if log_time_s is None else log_time_s, cols)
        self.chunks = []
        self.n = 0


def _ns(t_s: float) -> int:
    return max(int(round(t_s * 1e9)), 0)


class BatchLog:
    """The prototype's MCAP file: CDR batches for /can/raw and /wpt/count, JSON (as today) for the rest."""

    def __init__(self, path: str | Path, config: Config, mode: str, *, max_frames: int = 512,
                 max_span_s: float = 0.05) -> None:
        self._file = open(path, "wb")
        self._w = Writer(self._file, chunk_size=config.log.chunk_size_bytes, compression=CompressionType.ZSTD)
        self._w.start(profile="slipdaq", library=f"slipdaq {slipdaq.__version__} (perf prototype)")
        self._ch: dict[str, int] = {}
        sid = self._w.register_schema("slipdaq/msg/CanFrameBatch", "ros2msg", CAN_BATCH_SCHEMA.encode())
        self._ch[TOPIC_CAN] = self._w.register_channel(TOPIC_CAN, "cdr", sid)
        sid = self._w.register_schema("slipdaq/msg/WheelSampleBatch", "ros2msg", WHEEL_BATCH_SCHEMA.encode())
        self._ch[TOPIC_WPT] = self._w.register_channel(TOPIC_WPT, "cdr", sid)
        for topic in (TOPIC_NMEA, TOPIC_GPS, TOPIC_ESTIMATE, TOPIC_DIAGNOSTICS):
            schema = dict(SCHEMAS[topic])
            if topic == TOPIC_NMEA:
                schema = {**schema, "properties": {**schema["properties"], "can_index": {"type": "integer"}}}
            sid = self._w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._ch[topic] = self._w.register_channel(topic, "json", sid)
        self._w.add_metadata(METADATA_NAME, {
            "version": slipdaq.__version__, "mode": mode, "config_toml": config.to_toml(),
            "config_source_toml": config.source_text, "dbc": config.load_dbc_text(), "format": "perf-prototype"})
        self._seq = 0
        self.can = _Batcher(self._write_can, CAN_DTYPES, max_frames, max_span_s)
        self.wheels = _Batcher(self._write_wheels, WHEEL_DTYPES, max_frames, max_span_s)

    def _add(self, topic: str, t_s: float, data: bytes) -> None:
        self._seq += 1
        ns = _ns(t_s)
        self._w.add_message(self._ch[topic], log_time=ns, publish_time=ns, sequence=self._seq, data=data)

    def _write_can(self, first: int, t_s: float, cols: list[np.ndarray]) -> None:
        self._add(TOPIC_CAN, t_s, _cdr(first, cols))

    def _write_wheels(self, first: int, t_s: float, cols: list[np.ndarray]) -> None:
        self._add(TOPIC_WPT, t_s, _cdr(first, cols))

    def json(self, topic: str, t_s: float, payload: dict[str, Any]) -> None:
        self._add(topic, t_s, json.dumps(payload, separators=(",", ":")).encode())

    def close(self) -> None:
        self.can.flush()
        self.wheels.flush()
        self._w.finish()
        self._file.close()


# ---- 4. the batched pipeline ----------------------------------------------------------------------------------
def _ring_extend(ring: Any, ts: np.ndarray, vs: np.ndarray) -> None:
    """SeriesRing.append for many samples, with _make_room at the same points as one-by-one appends."""
    i, n = 0, len(ts)
    while i < n:
        if ring._end == len(ring._t):
            ring._make_room()
        k = min(n - i, len(ring._t) - ring._end)
        ring._t[ring._end:ring._end + k] = ts[i:i + k]
        ring._v[ring._end:ring._end + k] = vs[i:i + k]
        ring._end += k
        i += k


class FastPipeline:
    """Batched CAN path with the current estimator; the estimates equal Pipeline.process's, bit for bit."""

    def __init__(self, config: Config, log: BatchLog | None) -> None:
        self.log = log
        self.est = SlipEstimator(EstimatorParams.from_config(config))
        install_cached_latency(self.est)
        self.nmea = NmeaDecoder()
        layout = WptStructLayout.from_dbc(config.load_dbc_text())
        if layout is None:
            raise NotImplementedError("prototype: only the byte-aligned WPT layout (cantools path not prototyped)")
        self.layout = layout
        self._lut = np.full(2048, -1, dtype=np.int8)
        for fid, w in layout.ids.items():
            self._lut[fid] = w
        self.can_index = 0
        self.last_raw = [None] * 4
        self.last_seq = [0] * 4
        self.count = [0] * 4
        self.frames = [0] * 4
        self.lost = [0] * 4
        self.wraps = [0] * 4
        self.unknown_frames = self.error_frames = self.bad_frames = 0
        self.estimates: list[Any] = []
        self.keep_estimates = False
        self.n_estimates = 0
        self.last_time_s: float | None = None
        self._next_diag_s: float | None = None
        self._rings = [self.est._wheels[w] for w in WHEELS]
        self._lt = [-math.inf] * 4  # the rings' last times as Python floats (scalar path)
        self._rc: tuple[float, ...] | None = None  # readiness constants of the head epoch (scalar path)
        self.scalar_max = 64
        """Batches smaller than this take the scalar path (numpy's fixed cost per call dominates below it)."""

    # -- CAN, dispatch ----------------------------------------------------------------------------------------
    def process_msgs(self, msgs: list[Any]) -> None:
        """A reader's batch of python-can Messages: scalar path when small, numpy path when large."""
        if len(msgs) < self.scalar_max:
            self.process_msgs_scalar(msgs)
        else:
            self.process_can(*columns_from_messages(msgs))

    # -- CAN, scalar path (live: a wake-up brings a few frames) --------------------------------------------------
    def _ready_consts(self) -> tuple[float, ...]:
        """(gps condition: 0 never, 1 now, 2 wheels decide; need; since) for the head epoch, as _ready computes."""
        est = self.est
        p = est.p
        lat = est.latency.latency_s
        arrival = est._pending[0]
        half = 0.5 * p.window_s
        t1 = arrival - lat + half
        gps_last = est._gps.last_time - lat
        if gps_last < t1:
            return (0.0, 0.0, 0.0)
        if gps_last >= t1 + max(p.window_s, 0.5):
            return (1.0, 0.0, 0.0)
        need = max(t1, arrival) if p.gps_latency_s is None else t1
        return (2.0, need, t1 - 3 * half)

    def process_msgs_scalar(self, msgs: list[Any]) -> None:
        est = self.est
        rings, lt = self._rings, self._lt
        unpack = self.layout.struct.unpack
        count_first = self.layout._count_first
        ids = self.layout.ids
        cm, sm = self.layout.count_modulus, self.layout.seq_modulus
        half_cm = cm // 2
        lost_after = est.p.gps_lost_after_s
        log = self.log
        t = 0.0
        for m in msgs:
            t = m.timestamp
            data = bytes(m.data)
            flags = m.is_extended_id | (m.is_error_frame << 1)
            index = self.can_index
            self.can_index += 1
            if log is not None:
                log.can.add_row(index, (t, m.arbitration_id, flags, len(data), data.ljust(8, b"\0")))
            if flags:
                if flags & 2:
                    self.error_frames += 1
                else:
                    self.unknown_frames += 1
                continue
            w = ids.get(m.arbitration_id)
            if w is None:
                self.unknown_frames += 1
                continue
            if len(data) != 8:
                self.bad_frames += 1
                continue
            a, b = unpack(data)
            raw, seq = (a, b) if count_first else (b, a)
            last = self.last_raw[w]
            if last is None:
                count, lost = 0, 0
            else:
                d = (raw - last) % cm
                if d >= half_cm:
                    d -= cm
                if raw < last and d > 0:
                    self.wraps[w] += 1
                count = self.count[w] + d
                lost = (seq - self.last_seq[w] - 1) % sm
                self.lost[w] += lost
            self.last_raw[w], self.last_seq[w], self.count[w] = raw, seq, count
            self.frames[w] += 1
            if log is not None:
                log.wheels.add_row(index, (t, w, count, raw, seq, lost))
            # SlipEstimator.add_wheel, with the readiness test on Python floats
            if t < lt[w]:
                continue
            if t - est._gps.last_time > lost_after:
                self._emit(est.add_wheel(SimpleNamespace(timestamp_s=t, wheel=WHEELS[w], count=float(count))), t)
                lt[w] = rings[w].last_time
                self._rc = None
                continue
            rings[w].append(t, float(count))
            lt[w] = t
            if est._pending:
                rc = self._rc
                if rc is None:
                    rc = self._rc = self._ready_consts()
                mode = rc[0]
                if mode == 0.0:
                    continue
                if mode == 2.0:
                    need, since = rc[1], rc[2]
                    if not all(x >= need for x in lt if x >= since):
                        continue
                self._emit(est._drain(), t)
                self._rc = None
        if msgs:
            self._after(t)

    # -- CAN -------------------------------------------------------------------------------------------------
    def process_can(self, ts: np.ndarray, ids: np.ndarray, flags: np.ndarray, dlc: np.ndarray,
                    data: np.ndarray, cuts: list[tuple[int, list[NmeaLine]]] = ()) -> None:  # type: ignore[assignment]
        """One batch of consecutive frames: ts float64, ids uint32, flags/dlc uint8, data uint8[n*8]. cuts: NMEA
        lines that came between frames, as (index of the first frame after them, lines), in order (replay)."""
        n = len(ts)
        if n == 0:
            for _i, lines in cuts:
                for line in lines:
                    self.process_nmea(line)
            return
        first = self.can_index
        std = (flags == 0) & (ids < 2048)
        w_all = np.where(std, self._lut[np.minimum(ids, 2047)], -1)
        is_wpt = w_all >= 0
        ok = is_wpt & (dlc == 8)
        self.error_frames += int(np.count_nonzero(flags & 2))
        self.unknown_frames += int(np.count_nonzero(~is_wpt & ((flags & 2) == 0)))
        self.bad_frames += int(np.count_nonzero(is_wpt & (dlc != 8)))
        idx = np.flatnonzero(ok)
        payload = data.reshape(n, 8)[idx].copy().view(self.layout.dtype).reshape(-1)
        raw = payload["count"].astype(np.int64)
        seq = payload["seq"].astype(np.int64)
        wheel = w_all[idx]
        t = ts[idx]
        count = np.empty(len(idx), dtype=np.int64)
        lost = np.zeros(len(idx), dtype=np.int64)
        cm, sm = self.layout.count_modulus, self.layout.seq_modulus
        for w in range(4):
            sel = np.flatnonzero(wheel == w)
            if len(sel) == 0:
                continue
            r, q = raw[sel], seq[sel]
            if self.last_raw[w] is None:
                prev_r, prev_q, base = r[0], q[0] - 1, 0  # first frame ever: count 0, nothing lost
            else:
                prev_r, prev_q, base = self.last_raw[w], self.last_seq[w], self.count[w]
            rr = np.concatenate(([prev_r], r))
            d = (rr[1:] - rr[:-1]) % cm
            d[d >= cm // 2] -= cm
            self.wraps[w] += int(np.count_nonzero((rr[1:] < rr[:-1]) & (d > 0)))
            c = base + np.cumsum(d)
            qq = np.concatenate(([prev_q], q))
            lw = (qq[1:] - qq[:-1] - 1) % sm
            count[sel] = c
            lost[sel] = lw
            self.lost[w] += int(lw.sum())
            self.frames[w] += len(sel)
            self.last_raw[w], self.last_seq[w], self.count[w] = int(r[-1]), int(q[-1]), int(c[-1])
        log = self.log
        raw_cols = [ts, ids, flags, dlc, data]
        wheel_cols = [t, wheel.astype(np.uint8), count, raw.astype(np.uint32), seq.astype(np.uint8),
                      lost.astype(np.uint16)]
        self._feed(first, n, idx, t, wheel, count.astype(np.float64), raw_cols, wheel_cols,
                   list(cuts) + [(n, [])])

    def _feed(self, first: int, n: int, idx: np.ndarray, t: np.ndarray, wheel: np.ndarray, value: np.ndarray,
              raw_cols: list[np.ndarray], wheel_cols: list[np.ndarray],
              cuts: list[tuple[int, list[NmeaLine]]]) -> None:
        """add_wheel for each sample in order, with _drain only where it would emit (see module docstring); the
        NMEA lines of `cuts` processed between the frames where they came, and everything logged in that order."""
        est, rings, log = self.est, self._rings, self.log
        p = est.p
        # out-of-order samples are skipped per wheel (t < the wheel's latest time); NMEA does not move the rings
        keep = np.ones(len(t), dtype=bool)
        for w in range(4):
            sel = np.flatnonzero(wheel == w)
            if len(sel) == 0:
                continue
            tw = t[sel]
            run = np.maximum.accumulate(np.concatenate(([rings[w].last_time], tw)))[:-1]
            keep[sel] = tw >= run
        kidx = idx
        if not keep.all():
            t, wheel, value, kidx = t[keep], wheel[keep], value[keep], idx[keep]
        m = len(t)
        sel_w = [np.flatnonzero(wheel == w) for w in range(4)]
        ptr = [0, 0, 0, 0]  # per wheel: samples of this batch already appended

        def append_upto(k: int) -> None:  # kept samples with position < k
            for w in range(4):
                s = sel_w[w]
                j = ptr[w]
                e = int(np.searchsorted(s, k, side="left"))
                if e > j:
                    _ring_extend(rings[w], t[s[j:e]], value[s[j:e]])
                    ptr[w] = e

        seg_start = 0  # kept position
        raw_from = 0  # original frame index
        dec_from = 0  # decoded-sample position
        for cut, lines in cuts:
            seg_end = m if cut >= n else int(np.searchsorted(kidx, cut, side="left"))
            if log is not None and cut > raw_from:
                log.can.add(first + raw_from, float(raw_cols[0][raw_from]), float(raw_cols[0][cut - 1]),
                            [c[raw_from:cut] if k < 4 else c[8 * raw_from:8 * cut] for k, c in enumerate(raw_cols)])
                dec_to = int(np.searchsorted(idx, cut, side="left"))
                if dec_to > dec_from:
                    log.wheels.add(first + raw_from, float(wheel_cols[0][dec_from]), float(wheel_cols[0][dec_to - 1]),
                                   [c[dec_from:dec_to] for c in wheel_cols])
                    dec_from = dec_to
            self.can_index = first + cut
            t_last = float(raw_cols[0][cut - 1]) if cut > 0 else (self.last_time_s or 0.0)
            if seg_end > seg_start:
                gps_last = est._gps.last_time
                lost_at = np.flatnonzero(t[seg_start:seg_end] - gps_last > p.gps_lost_after_s)
                stop = seg_start + int(lost_at[0]) if len(lost_at) else seg_end
                pos = seg_start
                while pos < stop and est._pending:
                    k = self._ready_index(pos, stop, t, sel_w, ptr)
                    if k is None:
                        break
                    append_upto(k + 1)
                    self._emit(est._drain(), t_last)
                    pos = k + 1
                append_upto(stop)
                for i in range(stop, seg_end):  # GPS lost: one by one, exactly as add_wheel
                    append_upto(i)
                    w = int(wheel[i])
                    s = SimpleNamespace(timestamp_s=float(t[i]), wheel=WHEELS[w], count=float(value[i]))
                    ptr[w] += 1
                    self._emit(est.add_wheel(s), t_last)  # type: ignore[arg-type]
            raw_from = max(raw_from, cut)
            seg_start = seg_end
            for line in lines:
                self.process_nmea(line)
        self.can_index = first + n
        self._lt = [r.last_time for r in rings]
        self._rc = None
        self._after(float(raw_cols[0][-1]))

    def _ready_index(self, pos: int, stop: int, t: np.ndarray, sel_w: list[np.ndarray],
                     ptr: list[int]) -> int | None:
        """The first batch position k >= pos after whose append the head epoch is ready, or None before stop."""
        est = self.est
        p = est.p
        lat = est.latency.latency_s
        arrival = est._pending[0]
        half = 0.5 * p.window_s
        t1 = arrival - lat + half
        gps_last = est._gps.last_time - lat
        if gps_last < t1:
            return None
        if gps_last >= t1 + max(p.window_s, 0.5):
            return pos
        need = max(t1, arrival) if p.gps_latency_s is None else t1
        since = t1 - 3 * half
        blocks: list[tuple[int, int]] = []  # [enter, reach): positions where wheel w is reporting but short
        inf = 1 << 62
        for w in range(4):
            ring = self._rings[w]
            s = sel_w[w]
            ts_w = t[s[ptr[w]:]]
            pos_w = s[ptr[w]:]
            lt = ring.last_time if len(ring) else -math.inf
            if lt >= need:
                continue
            j = int(np.searchsorted(ts_w, need, side="left"))
            reach = int(pos_w[j]) if j < len(ts_w) else inf
            if lt >= since:
                enter = -1
            else:
                j2 = int(np.searchsorted(ts_w, since, side="left"))
                enter = int(pos_w[j2]) if j2 < len(ts_w) else inf
            if enter < reach:
                blocks.append((enter, reach))
        k = pos
        moved = True
        while moved:
            moved = False
            for enter, reach in blocks:
                if enter <= k < reach:
                    k = reach
                    moved = True
        return k if k < stop else None

    # -- NMEA ------------------------------------------------------------------------------------------------
    def process_nmea(self, line: NmeaLine) -> None:
        t = line.timestamp_s
        if self.log is not None:
            self.log.json(TOPIC_NMEA, t, {"timestamp_s": t, "line": line.line, "can_index": self.can_index})
        fix = self.nmea.decode(line)
        if fix is not None:
            if self.log is not None:
                self.log.json(TOPIC_GPS, fix.timestamp_s, {k: getattr(fix, k) for k in fix.__slots__})
            self._emit(self.est.add_gps(fix), t)
            self._rc = None
        self._after(t)

    # -- out -------------------------------------------------------------------------------------------------
    def _emit(self, estimates: list[Any], t: float) -> None:
        for e in estimates:
            self.n_estimates += 1
            if self.keep_estimates:
                self.estimates.append(e)
            if self.log is not None:
                self.log.json(TOPIC_ESTIMATE, t, estimate_to_dict(e))

    def _after(self, t: float) -> None:
        self.last_time_s = t
        if self._next_diag_s is None:
            self._next_diag_s = t + 1.0
        elif t >= self._next_diag_s:
            self.emit_diagnostics()
            self._next_diag_s = t + 1.0

    def emit_diagnostics(self) -> None:
        if self.log is None or self.last_time_s is None:
            return
        d = {"time_s": self.last_time_s, "can_frames": self.can_index,
             "wpt_frames": dict(zip(WHEELS, self.frames)), "lost_frames": dict(zip(WHEELS, self.lost)),
             "count_wraps": dict(zip(WHEELS, self.wraps)), "unknown_frames": self.unknown_frames,
             "error_frames": self.error_frames, "bad_frames": self.bad_frames, "nmea_lines": self.nmea.lines,
             "bad_sentences": self.nmea.bad_sentences, "gps_fixes": self.nmea.fixes,
             "estimates": self.n_estimates, "estimator": self.est.status()}
        self.log.json(TOPIC_DIAGNOSTICS, self.last_time_s, d)

    def finish(self) -> None:
        self.emit_diagnostics()
        if self.log is not None:
            self.log.close()


def columns_from_messages(msgs: list[Any]) -> tuple[np.ndarray, ...]:
    """python-can Messages -> the FastPipeline's columns (the one per-frame Python step left)."""
    n = len(msgs)
    ts = np.fromiter([m.timestamp for m in msgs], dtype=np.float64, count=n)
    ids = np.fromiter([m.arbitration_id for m in msgs], dtype=np.uint32, count=n)
    flags = np.fromiter([m.is_extended_id | (m.is_error_frame << 1) for m in msgs], dtype=np.uint8, count=n)
    dlc = np.fromiter([m.dlc for m in msgs], dtype=np.uint8, count=n)
    data = np.frombuffer(b"".join([bytes(m.data).ljust(8, b"\0") for m in msgs]), dtype=np.uint8)
    return ts, ids, flags, dlc, data


def run_fast(config: Config, stream: Iterable[Any], log: BatchLog | None, *, keep: bool = False) -> FastPipeline:
    """stream: lists of python-can Messages (a reader's batch) and NmeaLine records, in order."""
    fp = FastPipeline(config, log)
    fp.keep_estimates = keep
    for item in stream:
        if isinstance(item, list):
            fp.process_msgs(item)
        else:
            fp.process_nmea(item)
    fp.finish()
    return fp


# ---- 5. replay of a prototype log -------------------------------------------------------------------------------
def iter_fast_log(path: str | Path) -> Iterator[Any]:
    """(columns, cuts) per CAN batch and lone NmeaLine records of a BatchLog, in processing order: each NMEA line
    goes between the frames where it came (its can_index), as a cut of the batch that holds that position."""
    pending: deque[tuple[int, NmeaLine]] = deque()
    with open(path, "rb") as f:
        for _s, ch, msg in make_reader(f).iter_messages(topics=[TOPIC_CAN, TOPIC_NMEA], log_time_order=False):
            if ch.topic == TOPIC_NMEA:
                d = json.loads(msg.data)
                pending.append((d["can_index"], NmeaLine(d["timestamp_s"], d["line"])))
                continue
            first, cols = _cdr_read(msg.data, CAN_DTYPES)
            n = len(cols[0])
            cuts: list[tuple[int, list[NmeaLine]]] = []
            while pending and pending[0][0] < first + n:
                at, line = pending.popleft()
                at = max(at - first, 0)
                if cuts and cuts[-1][0] == at:
                    cuts[-1][1].append(line)
                else:
                    cuts.append((at, [line]))
            yield tuple(cols), cuts
    while pending:
        yield pending.popleft()[1]


def replay_fast(config: Config, src: str | Path, out: str | Path) -> FastPipeline:
    fp = FastPipeline(config, BatchLog(out, config, "replay"))
    for item in iter_fast_log(src):
        if isinstance(item, tuple):
            cols, cuts = item
            fp.process_can(*cols, cuts=cuts)
        else:
            fp.process_nmea(item)
    fp.finish()
    return fp


# ---- 6. logging alternatives, per frame -------------------------------------------------------------------------
def json_batch(ts: np.ndarray, ids: np.ndarray, flags: np.ndarray, dlc: np.ndarray, data: np.ndarray) -> bytes:
    """Keep JSON, one message per batch: columns as arrays, payloads as hex strings."""
    hexes = data.tobytes().hex()
    return json.dumps({"timestamp_s": ts.tolist(), "id": ids.tolist(), "flags": flags.tolist(),
                       "dlc": dlc.tolist(), "data": [hexes[16 * i:16 * i + 16] for i in range(len(ts))]},
                      separators=(",", ":")).encode()


def verify_cdr_with_mcap_ros2(path: str | Path) -> str:
    """Decode the CDR topics of a BatchLog with mcap-ros2-support (an independent ros2msg/CDR decoder)."""
    try:
        from mcap_ros2.decoder import DecoderFactory
    except ImportError:
        return "not checked (pip install mcap-ros2-support)"
    n = 0
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _s, ch, msg, dec in reader.iter_decoded_messages(topics=[TOPIC_CAN, TOPIC_WPT], log_time_order=False):
            cols = _cdr_read(msg.data, CAN_DTYPES if ch.topic == TOPIC_CAN else WHEEL_DTYPES)[1]
            ref = [dec.timestamp_s, dec.id, dec.flags, dec.dlc, dec.data] if ch.topic == TOPIC_CAN else [
                dec.timestamp_s, dec.wheel, dec.count, dec.raw_count, dec.seq, dec.lost_frames]
            for a, b in zip(cols, ref):
                b = np.frombuffer(b, dtype=np.uint8) if isinstance(b, (bytes, bytearray)) else np.asarray(b)
                if not np.array_equal(a, b):
                    return f"MISMATCH in {ch.topic}"
            n += 1
            if n >= 50:
                break
    return f"ok ({n} batches decoded by mcap-ros2-support identically)"
