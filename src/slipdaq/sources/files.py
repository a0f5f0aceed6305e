"""Import sources: CAN log files (any format python-can reads: candump, ASC, BLF, TRC, CSV, and ASAM MDF4 through
python-can's MF4 reader with asammdf) and timestamped NMEA logs. Several CAN logs of one session (a CANedge splits a
session into numbered MF4 files) are joined in time order.

A receiver's raw capture (iter_gps_capture) has no stamps: its messages take their own GNSS time.

NMEA log lines are `(EPOCH_SECONDS) $SENTENCE` in the CAN log's clock; bare `$SENTENCE` lines are
accepted too and take the time of the sentence itself (RMC date + time, or a UBX NAV-PVT's UTC time), else of the
record before. The bytes after the
time stamps are framed as the live serial reader frames them (decode/framing.py): a receiver's raw capture that mixes
UBX or RTCM with NMEA gives the same records as it would live.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import replace
from itertools import chain
from pathlib import Path

import can
import numpy as np

from slipdaq.decode.framing import GpsFramer
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.decode.ubx import UbxDecoder
from slipdaq.records import CanFrameBatch, NmeaLine, RawRecord, RtcmFrame, UbxFrame
from slipdaq.sources.candump import CandumpError, iter_candump
from slipdaq.sources.read_errors import InputError, guarded, read_error

_STAMPED = re.compile(rb"[ \t]*\([ \t]*(?P<t>[-+]?\d+(?:\.\d*)?)[ \t]*\)[ \t]?")
CAN_SUFFIXES = (".log", ".asc", ".blf", ".trc", ".csv", ".mf4")
MAX_LOG_TIME_S = (2**64 - 1) / 1e9
"""The latest time a log holds (MCAP's log time: nanoseconds since 1970 in 64 bits, about the year 2554)."""


def _stamp_error(p: Path, what: str, t: float) -> ImportError_ | None:
    """The error for a time stamp a log cannot hold (infinite, NaN, after MAX_LOG_TIME_S); None when it can."""
    if math.isfinite(t) and t < MAX_LOG_TIME_S:
        return None
    return ImportError_(f"{p}: {what} is stamped {t!r} s, which no log holds (at most {MAX_LOG_TIME_S:.0f} s after "
                        "1970): not a time stamp")


class ImportError_(InputError):
    """A file that cannot be imported; the message names the file."""


MESSAGES_PER_BATCH = 4096
"""python-can's messages of a log handed on as one CanFrameBatch."""


def iter_can_log(path: str | Path) -> Iterator[CanFrameBatch]:
    """A CAN log's frames in file order, in batches: a candump -L log (.log) through sources/candump.py, any other
    format through python-can's LogReader; each stamp checked (_stamp_error)."""
    p = Path(path)
    if not p.is_file():
        raise ImportError_(f"{p}: no such CAN log")
    if p.suffix.lower() == ".log":
        yield from _candump_batches(p)
        return
    try:
        reader = can.LogReader(str(p))
    except Exception as e:  # an unknown suffix, or a file that does not start like its format (BLFParseError)
        formats = "" if p.suffix.lower() in CAN_SUFFIXES else f"; formats: {', '.join(CAN_SUFFIXES)}"
        raise ImportError_(f"{p}: python-can cannot read it ({e}){formats}") from None
    frames = 0
    msgs: list[can.Message] = []
    with reader:
        try:
            for msg in guarded(p, reader):
                msgs.append(msg)
                if len(msgs) == MESSAGES_PER_BATCH:
                    yield _checked(p, CanFrameBatch.from_frames(msgs, [m.timestamp for m in msgs]), frames)
                    frames += len(msgs)
                    msgs = []
        except InputError:
            if msgs:  # a stamp no log holds before the damage is named first, as frame by frame
                _checked(p, CanFrameBatch.from_frames(msgs, [m.timestamp for m in msgs]), frames)
            raise
    if msgs:
        yield _checked(p, CanFrameBatch.from_frames(msgs, [m.timestamp for m in msgs]), frames)


def _checked(p: Path, batch: CanFrameBatch, frames_before: int) -> CanFrameBatch:
    """The batch, when a log holds each of its stamps; else the error naming the first frame that it does not."""
    t = batch.timestamp_s
    bad = np.flatnonzero(~(np.isfinite(t) & (t < MAX_LOG_TIME_S)))
    if len(bad):
        i = int(bad[0])
        raise _stamp_error(p, f"frame {frames_before + i + 1}", float(t[i])) or AssertionError(t[i])
    return batch


def _candump_batches(p: Path) -> Iterator[CanFrameBatch]:
    """iter_candump's batches, each stamp checked (_stamp_error); a line python-can cannot read is one InputError
    naming the file and the frames read before it, as guarded() names them."""
    frames = 0
    batches = iter_candump(p)
    while True:
        try:
            batch = next(batches, None)
        except CandumpError as e:
            raise read_error(p, e.error, e.frames_before) from None
        except Exception as e:
            raise read_error(p, e, frames) from None
        if batch is None:
            return
        yield _checked(p, batch, frames)
        frames += len(batch)


def _first_time(p: str | Path) -> float | None:
    """The stamp of a CAN log's first frame (None: no frame)."""
    for batch in iter_can_log(p):
        return float(batch.timestamp_s[0])
    return None


def iter_can_logs(paths: Sequence[str | Path]) -> Iterator[CanFrameBatch]:
    """The frames of several CAN logs of one session, file after file in the order of their first frame's time (the
    files' own names need not sort); a file that starts before the previous one ended is refused (not one session)."""
    if len(paths) == 1:
        yield from iter_can_log(paths[0])
        return
    firsts: list[tuple[float, int, str | Path]] = []
    for i, p in enumerate(paths):
        first = _first_time(p)
        if first is None:
            raise ImportError_(f"{p}: no CAN frames in it")
        firsts.append((first, i, p))
    last_t, last_p = float("-inf"), None
    for t0, _, p in sorted(firsts, key=lambda x: (x[0], x[1])):
        if t0 < last_t:
            raise ImportError_(f"{p}: starts at {t0:.6f}, before {last_p} ends ({last_t:.6f}): the files are not "
                               f"one session's consecutive parts")
        for batch in iter_can_log(p):
            last_t = max(last_t, float(batch.timestamp_s.max()))
            yield batch
        last_p = p


class _OwnTimes:
    """GPS records placed at the latest time known: a stamp, or a record's own GNSS time (an RMC's date and time, a
    NAV-PVT's UTC time); the records before the first time known take that time."""

    def __init__(self, p: Path) -> None:
        self.p = p
        self.last_t: float | None = None
        self.pending: list[NmeaLine | UbxFrame | RtcmFrame] = []
        self._nmea, self._ubx = NmeaDecoder(), UbxDecoder()

    def read_time(self, record: NmeaLine | UbxFrame | RtcmFrame) -> None:
        """The record's own GNSS time, where it has one, as the latest time."""
        fix = self._nmea.decode(record) if isinstance(record, NmeaLine) else \
            self._ubx.decode(record) if isinstance(record, UbxFrame) else None
        if fix is not None and fix.fix_time_utc_s is not None and not _stamp_error(self.p, "", fix.fix_time_utc_s):
            self.last_t = fix.fix_time_utc_s

    def place(self, record: NmeaLine | UbxFrame | RtcmFrame) -> Iterator[NmeaLine | UbxFrame | RtcmFrame]:
        """The record (and those pending before it) at the latest time, once one is known."""
        if self.last_t is None:
            self.pending.append(record)
            return
        for earlier in self.pending:
            yield replace(earlier, timestamp_s=self.last_t)
        self.pending.clear()
        yield replace(record, timestamp_s=self.last_t)


def iter_nmea_log(path: str | Path) -> Iterator[NmeaLine | UbxFrame | RtcmFrame]:
    p = Path(path)
    if not p.is_file():
        raise ImportError_(f"{p}: no such NMEA log")
    times = _OwnTimes(p)
    framer = GpsFramer()  # the live reader's framing: the same bytes give the same records
    with open(p, "rb") as f:
        for n, raw in enumerate(chain(guarded(p, f, "line"), [None]), 1):
            m = _STAMPED.match(raw) if raw is not None else None
            if m and raw is not None:
                times.last_t = float(m["t"])
                if (bad := _stamp_error(p, f"line {n}", times.last_t)) is not None:
                    raise bad
                raw = raw[m.end() :]
            for record in framer.feed(raw, times.last_t or 0.0) if raw is not None else framer.flush():
                if m is None:
                    times.read_time(record)
                yield from times.place(record)
    yield from times.pending  # a file with no time at all


CAPTURE_READ_BYTES = 1 << 16


def iter_gps_capture(path: str | Path) -> Iterator[NmeaLine | UbxFrame | RtcmFrame]:
    """A receiver's raw byte capture (NMEA, UBX and RTCM mixed as the port sent them, no host stamps: u-center's
    .ubx, `cat /dev/ttyACM0 > FILE`), framed as the live reader frames it (decode/framing.py). Each record takes its
    own GNSS time as a bare sentence of an NMEA log does (an RMC's date and time, a NAV-PVT's UTC time), else the
    time of the record before (the records before the first such time take that time): the CAN log's clock is
    taken to be UTC. The bytes are read as they are: a stamp-like `(123.4)` is no stamp here."""
    p = Path(path)
    if not p.is_file():
        raise ImportError_(f"{p}: no such GPS capture")
    times = _OwnTimes(p)
    framer = GpsFramer()
    with open(p, "rb") as f:
        chunks = iter(lambda: f.read(CAPTURE_READ_BYTES), b"")
        for chunk in chain(guarded(p, chunks, "block"), [None]):
            for record in framer.feed(chunk, 0.0) if chunk is not None else framer.flush():
                times.read_time(record)
                yield from times.place(record)
    if times.pending:
        raise ImportError_(f"{p}: no message with a GNSS time in it (an RMC with date and time, or a UBX NAV-PVT "
                           "with valid UTC): the capture cannot be placed on the CAN log's clock")


MERGE_RUN_FRAMES = 4096
"""Most frames of a batch stream merge_by_time hands on as one slice."""


def merge_by_time(*streams: Iterator[RawRecord | CanFrameBatch]) -> Iterator[RawRecord | CanFrameBatch]:
    """One stream in timestamp order, as heapq.merge by timestamp would give it frame by frame: the record (or
    frame of a CanFrameBatch) first whose time is least, on equal times the earlier stream's. A batch comes out as
    slices of its consecutive frames (at most MERGE_RUN_FRAMES each)."""
    heads: list[list] = []  # [time, stream index, item, iterator, position in a batch]
    for i, stream in enumerate(streams):
        it = iter(stream)
        if (head := _head(next(it, None), i, it)) is not None:
            heads.append(head)
    while heads:
        best = min(heads, key=lambda h: (h[0], h[1]))
        t, i, item, it, pos = best
        if isinstance(item, CanFrameBatch):
            others = [(h[0], h[1]) for h in heads if h is not best]
            window = item.timestamp_s[pos : pos + MERGE_RUN_FRAMES]
            if others:
                bound, j = min(others)
                ahead = window < bound if i > j else window <= bound
                stop = pos + (len(window) if ahead.all() else max(int(ahead.argmin()), 1))
            else:
                stop = pos + len(window)
            yield item if (pos, stop) == (0, len(item)) else item.slice(pos, stop)
            if stop < len(item):
                best[0], best[4] = float(item.timestamp_s[stop]), stop
                continue
        else:
            yield item
        if (head := _head(next(it, None), i, it)) is None:
            heads.remove(best)
        else:
            best[:] = head


def _head(item: RawRecord | CanFrameBatch | None, i: int, it: Iterator[RawRecord | CanFrameBatch]) -> list | None:
    """A stream's head for merge_by_time (an empty batch skipped); None when the stream has ended."""
    while isinstance(item, CanFrameBatch) and len(item) == 0:
        item = next(it, None)
    if item is None:
        return None
    return [float(item.timestamp_s[0]) if isinstance(item, CanFrameBatch) else item.timestamp_s, i, item, it, 0]
