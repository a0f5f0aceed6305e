"""The batched raw topics: /can/raw and /wpt/count as one MCAP message per batch, ros2msg schema, CDR encoding.

CDR (XCDR1, little endian) is what ROS 2 bags use; Foxglove and mcap-ros2-support decode it without ROS from the
schema text below. A batch is built from numpy columns with no per-frame Python, and read back with np.frombuffer.
Logs written before the batches (one JSON message per frame) are still read (sources.mcap_log).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from slipdaq.records import CanFrameBatch, WheelSampleBatch

CAN_BATCH_SCHEMA_NAME = "slipdaq/msg/CanFrameBatch"
CAN_BATCH_SCHEMA = """# Consecutive raw CAN frames, in the order the pipeline processed them
uint64 first_index      # frames processed before the first one (NMEA and UBX lines carry can_index, the same count)
float64[] timestamp_s   # receive timestamps
uint32[] id             # arbitration id
uint8[] flags           # bit 0: extended id, bit 1: error frame
uint8[] dlc             # payload length in bytes
uint8[] data            # the payloads back to back: frame i's dlc[i] bytes
"""
WHEEL_BATCH_SCHEMA_NAME = "slipdaq/msg/WheelSampleBatch"
WHEEL_BATCH_SCHEMA = """# Decoded wheel samples, in record order
uint64 first_index      # samples logged before the first one
float64[] timestamp_s
uint8[] wheel           # 0 FL, 1 FR, 2 RL, 3 RR
float64[] revolutions   # cumulative revolutions since the wheel's first sample
int64[] count           # cumulative pulses, unwrapped (count sources; 0 where flags bit 0 is clear)
float64[] raw           # the signal as sent: raw count, or wheel speed in the signal's unit
int64[] seq             # sequence counter (0 where flags bit 1 is clear)
uint32[] lost_frames    # frames missing before this one (Seq gap)
uint8[] flags           # bit 0: count present, bit 1: seq present
"""
ENCODING = "cdr"
SCHEMA_ENCODING = "ros2msg"

_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian
_CAN_DTYPES = ("<f8", "<u4", "u1", "u1", "u1")
_WHEEL_DTYPES = ("<f8", "u1", "<f8", "<i8", "<f8", "<i8", "<u4", "u1")


def _encode(first_index: int, arrays: list[np.ndarray]) -> bytes:
    """uint64 first_index, then sequences (uint32 length, elements aligned to their size), offsets after the header."""
    parts = [_HEADER, struct.pack("<Q", first_index)]
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


def _decode(buf: bytes, dtypes: tuple[str, ...], canonical: list[bool] | None = None) -> tuple[int, list[np.ndarray]]:
    """canonical (if given) gets whether buf is exactly what _encode writes for the arrays: padding zero, nothing
    after the last array."""
    if buf[:4] != _HEADER:
        raise ValueError("not a little-endian CDR message")
    first = struct.unpack_from("<Q", buf, 4)[0]
    pos = 8
    out = []
    zero = True
    for dt in dtypes:
        d = np.dtype(dt)
        pad = (-pos) % 4
        if pad and canonical is not None:
            zero = zero and not any(buf[4 + pos : 4 + pos + pad])
        pos += pad
        n = struct.unpack_from("<I", buf, 4 + pos)[0]
        pos += 4
        pad = (-pos) % d.itemsize
        if pad and canonical is not None:
            zero = zero and not any(buf[4 + pos : 4 + pos + pad])
        pos += pad
        out.append(np.frombuffer(buf, dtype=d, count=n, offset=4 + pos))
        pos += n * d.itemsize
    if canonical is not None:
        canonical.append(zero and len(buf) == 4 + pos)
    return first, out


def packed_payloads(batch: CanFrameBatch) -> np.ndarray:
    """The payload bytes back to back (uint8)."""
    n, width = batch.data.shape
    if width == 8 and n and bool((batch.dlc == 8).all()):
        return batch.data.reshape(-1)
    return batch.data[np.arange(width) < batch.dlc[:, None]]


def encode_can_batch(first_index: int, batch: CanFrameBatch) -> bytes:
    return _encode(first_index, [
        np.ascontiguousarray(batch.timestamp_s, dtype="<f8"), np.ascontiguousarray(batch.arbitration_id, dtype="<u4"),
        np.ascontiguousarray(batch.flags, dtype="u1"), np.ascontiguousarray(batch.dlc, dtype="u1"),
        np.ascontiguousarray(packed_payloads(batch), dtype="u1"),
    ])


@dataclass(frozen=True, slots=True, eq=False)
class LoggedCanFrameBatch(CanFrameBatch):
    """A batch read from a /can/raw message whose bytes are exactly what encode_can_batch writes for it: a log
    writing the same frames as one batch again copies them (with its own first_index) instead of encoding them."""

    message: bytes = b""


def decode_can_batch(buf: bytes) -> tuple[int, CanFrameBatch]:
    """(first_index, frames); a LoggedCanFrameBatch when buf is as encode_can_batch writes it."""
    canonical: list[bool] = []
    first, (ts, ids, flags, dlc, packed) = _decode(buf, _CAN_DTYPES, canonical)
    n = len(ts)
    if n and bool((dlc == 8).all()) and len(packed) == 8 * n:
        data = packed.reshape(n, 8)
    else:
        width = max(8, int(dlc.max())) if n else 8
        data = np.zeros((n, width), dtype=np.uint8)
        data[np.arange(width) < dlc[:, None]] = packed
    if canonical[0]:
        return first, LoggedCanFrameBatch(ts, ids, flags, dlc, data, bytes(buf))
    return first, CanFrameBatch(ts, ids, flags, dlc, data)


def reencode_can_batch(first_index: int, batch: CanFrameBatch) -> bytes:
    """encode_can_batch(first_index, batch); a LoggedCanFrameBatch's message bytes with first_index put in."""
    if type(batch) is LoggedCanFrameBatch and batch.message:
        m = batch.message
        return m[:4] + struct.pack("<Q", first_index) + m[12:]
    return encode_can_batch(first_index, batch)


def encode_wheel_batch(first_index: int, s: WheelSampleBatch) -> bytes:
    cols = (s.timestamp_s, s.wheel, s.revolutions, s.count, s.raw, s.seq, s.lost_frames, s.flags)
    return _encode(first_index, [np.ascontiguousarray(c, dtype=d) for c, d in zip(cols, _WHEEL_DTYPES)])


def decode_wheel_batch(buf: bytes) -> tuple[int, WheelSampleBatch]:
    first, (t, wheel, rev, count, raw, seq, lost, flags) = _decode(buf, _WHEEL_DTYPES)
    frame = np.full(len(t), -1, dtype=np.int64)  # not logged
    return first, WheelSampleBatch(frame, wheel, t, rev, count, raw, seq, lost.astype(np.int64), flags)
