"""What a two-pass run's first pass decoded, played back to its second pass: the pipeline's wheel decoder and NMEA
decoder made into ones that record (the first pass) or play back (the second) their outputs and counters.

Both passes read the same records in the same order, and the pipeline cuts the wheel frames into the same batches in
both (where a diagnostics snapshot falls due, by the records' times alone), so the second pass's calls are the first
pass's, one for one: each played call is checked against the recorded one (its batch's frames, its line's time), and a
call that differs raises TapeMismatch. The counters read between calls (diagnostics) are the ones recorded after the
call before. A tape holds its outputs within a budget of bytes (TAPE_BYTES); past it, it records nothing more and
plays nothing (`complete` False): the second pass then decodes, as a single pass does.

A tape can also be fed (DecoderTape(fed=True), feed): the first pass's entries recorded in another process that makes
the same decoder calls over the same items (first_pass_feed), played to the first pass as they come and kept for the
second within the budget."""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Iterator
from operator import attrgetter
from typing import Any

import numpy as np

from slipdaq.config import Config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.nmea import DROP_REASONS, NmeaDecoder
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrameBatch, GpsFix, NmeaLine, WheelSampleBatch

TAPE_BYTES = 256 * 1024 * 1024
"""A tape keeps what it recorded while its outputs' arrays stay within this many bytes (about 15 minutes of 4 WPT
messages at 1 kHz: 58 bytes a wheel sample)."""
_LINE_BYTES = 200
"""What a recorded NMEA line's entry is counted as (its fix and counters)."""


WheelEntry = tuple[int, float, WheelSampleBatch, np.ndarray, int]
"""A decode_batch call: its frames, first frame's time, the samples, the counters and bad frames after it."""
LineEntry = tuple[float, GpsFix | None, tuple[int, ...]]
"""An NMEA line: its time, the decoder's fix and its counters after it (NmeaDecoder.COUNTERS, `dropped`)."""


class TapeMismatch(RuntimeError):
    """A second pass's decoder call that is not the first pass's."""


class DecoderTape:
    """The pipeline's wheel and NMEA decoders' outputs over a first pass (record) for its second pass (play)."""

    def __init__(self, budget_bytes: int | None = None, *, fed: bool = False) -> None:
        """fed: the first pass plays what feed gives it (entries another process recorded), not its decoders."""
        self._budget = TAPE_BYTES if budget_bytes is None else budget_bytes
        self.bytes = 0
        self.complete = True
        """False once the budget was exceeded: nothing is kept, nothing is played."""
        self.wheels: list[WheelEntry] = []
        """Per decode_batch call: frames, first frame's time, the samples, the counters and bad frames after it."""
        self.lines: list[LineEntry] = []
        """Per NMEA line: its time, the decoder's fix and its counters after it (NmeaDecoder.COUNTERS, `dropped`)."""
        self._recorded = False
        self._fed: tuple[deque[WheelEntry], deque[LineEntry]] | None = (deque(), deque()) if fed else None
        """A fed tape's entries not yet played to the first pass."""

    def room_for(self, nbytes: int) -> bool:
        """Count nbytes in: whether the tape keeps them (False, and the tape dropped, past the budget)."""
        self.bytes += nbytes
        if self.bytes > self._budget:
            self.drop()
        return self.complete

    def drop(self) -> None:
        """Keep nothing, play nothing (a second pass over records read again, which need not be the same)."""
        self.complete = False
        self.wheels, self.lines = [], []

    def feed(self, wheels: list[WheelEntry], lines: list[LineEntry]) -> None:
        """A fed tape's next entries (a run's decoder calls, recorded elsewhere): played to the first pass, kept for the
        second within the budget."""
        assert self._fed is not None, "feed on a tape that records its first pass"
        self._fed[0].extend(wheels)
        self._fed[1].extend(lines)
        if self.complete and self.room_for(sum(_nbytes(w[2]) + w[3].nbytes for w in wheels) + _LINE_BYTES * len(lines)):
            self.wheels.extend(wheels)
            self.lines.extend(lines)

    def attach(self, pipeline: Pipeline) -> None:
        """Give the pipeline (a fresh one) taped decoders: recording on the first call (a fed tape: playing what is
        fed), playing on the second (when the tape is complete; otherwise the pipeline keeps its own)."""
        if self._recorded and not self.complete:
            return
        wheels: Iterator[WheelEntry] | None = None  # the first call records
        lines: Iterator[LineEntry] | None = None
        if self._recorded:  # the second plays what was kept
            wheels, lines = iter(self.wheels), iter(self.lines)
        elif self._fed is not None:  # a fed tape's first plays what is fed
            wheels, lines = _Taken(self._fed[0]), _Taken(self._fed[1])
        self._recorded = True
        pipeline.wheels = TapedWheelDecoder(pipeline.config, self, wheels)
        pipeline.nmea = TapedNmeaDecoder(self, lines)


class _Taken(Iterator[Any]):
    """A fed tape's entries, each let go as it is played (empty until fed: a call then finds no entry)."""

    def __init__(self, entries: deque[Any]) -> None:
        self._entries = entries

    def __next__(self) -> Any:
        if not self._entries:
            raise StopIteration
        return self._entries.popleft()


def _batch_key(batch: CanFrameBatch) -> tuple[int, float]:
    return len(batch), float(batch.timestamp_s[0]) if len(batch) else 0.0


def _same(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
    """a == b, a NaN equal to a NaN."""
    return a == b or all(x == y or (x != x and y != y) for x, y in zip(a, b, strict=True))


def _nbytes(samples: WheelSampleBatch) -> int:
    return sum(getattr(samples, f.name).nbytes for f in dataclasses.fields(samples))


class TapedWheelDecoder(WheelDecoder):
    """A WheelDecoder whose decode_batch records its outputs on a tape, or plays them back (play: the entries) without
    decoding."""

    def __init__(self, config: Config, tape: DecoderTape, play: Iterator[WheelEntry] | None) -> None:
        super().__init__(config)
        self._tape = tape
        self._play = play

    def decode_batch(self, batch: CanFrameBatch, which: np.ndarray | None = None) -> WheelSampleBatch:
        tape = self._tape
        if self._play is not None:
            n, t, samples, counters, bad = next(self._play, (-1, 0.0, WheelSampleBatch.empty(), self._counters, 0))
            if not _same((n, t), _batch_key(batch)):
                raise TapeMismatch(f"the second pass decodes other wheel frames than the first pass: {len(batch)} from "
                                   f"{_batch_key(batch)[1]} s against {n} from {t} s")
            self._counters, self.bad_frames = counters, bad
            return samples
        samples = super().decode_batch(batch, which)
        if tape.complete and tape.room_for(_nbytes(samples) + self._counters.nbytes):
            tape.wheels.append((*_batch_key(batch), samples, self._counters.copy(), self.bad_frames))
        return samples


class TapedNmeaDecoder(NmeaDecoder):
    """An NmeaDecoder whose decode records its fix and counters on a tape (COUNTERS, then `dropped`'s values), or
    plays them back (play: the entries)."""

    def __init__(self, tape: DecoderTape, play: Iterator[LineEntry] | None) -> None:
        super().__init__()
        self._tape = tape
        self._play = play
        self._dropped_at: tuple[int, ...] = tuple(self.dropped.values())

    def decode(self, line: NmeaLine) -> GpsFix | None:
        if self._play is not None:
            t, fix, counters = next(self._play, (-1.0, None, ()))
            if not counters or not _same((t,), (line.timestamp_s,)):
                raise TapeMismatch(f"the second pass decodes an NMEA line at {line.timestamp_s} where the first pass "
                                   f"decoded one at {t}")
            k = len(self.COUNTERS)
            for name, value in zip(self.COUNTERS, counters[:k]):
                setattr(self, name, value)
            if counters[k:] != self._dropped_at:
                self._dropped_at = counters[k:]
                self.dropped = dict(zip(DROP_REASONS, self._dropped_at))
            return fix
        fix = super().decode(line)
        tape = self._tape
        if tape.complete and tape.room_for(_LINE_BYTES):
            tape.lines.append((line.timestamp_s, fix, (*_nmea_counters(self), *self.dropped.values())))
        return fix


_nmea_counters = attrgetter(*NmeaDecoder.COUNTERS)
