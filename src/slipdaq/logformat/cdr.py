"""The batched raw topics: /can/raw and /wpt/count as one MCAP message per batch, ros2msg schema, CDR encoding.

CDR (XCDR1, little endian) is what ROS 2 bags use; Foxglove and mcap-ros2-support decode it without ROS from the
schema text below. A batch is built from numpy columns with no per-frame Python, and read back with np.frombuffer.
Logs written before the batches (one JSON message per frame) are still read (logformat.reader), and batches
written before /can/raw had its `channel` field (their own schema ends at `data`): every frame then has channel 0.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from slipdaq.records import FLAG_DLC, FLAG_REMOTE, CanFrameBatch, WheelSampleBatch, payload_lengths

CAN_BATCH_SCHEMA_NAME = "slipdaq/msg/CanFrameBatch"
CAN_BATCH_SCHEMA = """# Consecutive raw CAN frames, in the order the pipeline processed them
uint64 first_index      # frames processed before the first one (NMEA and UBX lines carry can_index, the same count)
float64[] timestamp_s   # receive timestamps
uint32[] id             # arbitration id
uint8[] flags           # bit 0: extended id, 1: error frame, 2: remote frame, 3: CAN FD, 4: FD bit rate switch,
                        # 5: FD error state indicator, 6: transmitted (python-can is_rx false: Tx, or sent from this host)
                        # 7: the DLC is not the payload's length (8 bytes of payload, dlc the frame's DLC, e.g. 9..15)
uint8[] dlc             # payload length in bytes; a remote frame: the length it asks for
uint8[] data            # the payloads back to back: frame i's dlc[i] bytes (none for a remote frame, 8 with bit 7)
uint16[] channel        # index into the list of channel names in the log's slipdaq metadata (can_channels)
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
_CAN_DTYPES = ("<f8", "<u4", "u1", "u1", "u1", "<u2")
_CAN_DTYPES_BEFORE_CHANNEL = 5
"""/can/raw messages of logs written before the channel field end after its first five arrays."""
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


def _decode(buf: bytes, dtypes: tuple[str, ...], canonical: list[bool] | None = None,
            required: int | None = None) -> tuple[int, list[np.ndarray]]:
    """canonical (if given) gets whether buf is exactly what _encode writes for the arrays: padding zero, nothing
    after the last array. With `required`, the message may end after that many arrays (a schema that had fewer
    fields): the rest are left out."""
    if buf[:4] != _HEADER:
        raise ValueError("not a little-endian CDR message")
    first = struct.unpack_from("<Q", buf, 4)[0]
    pos = 8
    out = []
    zero = True
    for k, dt in enumerate(dtypes):
        if required is not None and k >= required and 4 + pos + (-pos) % 4 + 4 > len(buf):
            break
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
    if width == 8 and n and bool((batch.dlc == 8).all()) and not (batch.flags & (FLAG_REMOTE | FLAG_DLC)).any():
        return batch.data.reshape(-1)
    return batch.data[np.arange(width) < batch.payload_lengths()[:, None]]


def encode_can_batch(first_index: int, batch: CanFrameBatch) -> bytes:
    return _encode(first_index, [
        np.ascontiguousarray(batch.timestamp_s, dtype="<f8"), np.ascontiguousarray(batch.arbitration_id, dtype="<u4"),
        np.ascontiguousarray(batch.flags, dtype="u1"), np.ascontiguousarray(batch.dlc, dtype="u1"),
        np.ascontiguousarray(packed_payloads(batch), dtype="u1"), np.ascontiguousarray(batch.channel, dtype="<u2"),
    ])


@dataclass(frozen=True, slots=True, eq=False)
class LoggedCanFrameBatch(CanFrameBatch):
    """A batch read from a /can/raw message whose bytes are exactly what encode_can_batch writes for it: a log
    writing the same frames as one batch again copies them (with its own first_index) instead of encoding them."""

    message: bytes = b""


def decode_can_batch(buf: bytes, channels: tuple[str | None, ...] = (None,)) -> tuple[int, CanFrameBatch]:
    """(first_index, frames); a LoggedCanFrameBatch when buf is as encode_can_batch writes it. channels: the log's
    channel names (its can_channels), which the frames' channel indices refer to."""
    canonical: list[bool] = []
    first, arrays = _decode(buf, _CAN_DTYPES, canonical, required=_CAN_DTYPES_BEFORE_CHANNEL)
    ts, ids, flags, dlc, packed = arrays[:5]
    n = len(ts)
    channel = arrays[5] if len(arrays) > 5 else np.zeros(n, dtype=np.uint16)
    if n and bool((dlc == 8).all()) and len(packed) == 8 * n:
        data = packed.reshape(n, 8)
    else:
        lengths = payload_lengths(flags, dlc)
        width = max(8, int(lengths.max())) if n else 8
        data = np.zeros((n, width), dtype=np.uint8)
        data[np.arange(width) < lengths[:, None]] = packed
    if n and int(channel.max()) >= len(channels):  # a name the log does not list (cut before its metadata)
        channels = channels + (None,) * (int(channel.max()) + 1 - len(channels))
    if canonical[0] and len(arrays) > 5:
        return first, LoggedCanFrameBatch(ts, ids, flags, dlc, data, channel, channels, bytes(buf))
    return first, CanFrameBatch(ts, ids, flags, dlc, data, channel, channels)


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
