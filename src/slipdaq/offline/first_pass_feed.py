"""A two-pass run's first pass fed by a process that reads the log, on the core that pass leaves idle: the log's
process, which reads it anyway (LogProcess with read, feed), or one of its own (FeedProcess, FedPasses: the
report's, and a replay's of a log too long for the log's process to feed whole). That process decodes the input's
items and makes the pipeline's wheel and NMEA decoder calls over them (DecodingPipeline: Pipeline's own cuts, no
estimator), and sends the run each run of items (items.read_ahead) with those calls' tape entries (decoder_tape)
before it takes the run further. The pass then neither reads nor decodes: it plays the entries as they come
(DecoderTape(fed=True)); the second pass plays them again (a log fed whole), is fed in the same way by a process of
its own (the report's, past FEED_BYTES), or reads and decodes the log itself. Both pipelines get the same items in
the same runs, and Pipeline cuts the wheel frames by the records' times alone, so the calls are the same one for
one; a played call is checked against its entry (TapeMismatch)."""

from __future__ import annotations

import pickle
import sys
from collections.abc import Callable, Generator, Iterable, Iterator
from multiprocessing import get_context
from multiprocessing.connection import Connection
from pathlib import Path
from types import TracebackType
from typing import Any, NoReturn

from slipdaq import compiled
from slipdaq.config import Config
from slipdaq.decode.timemark import TimeMark
from slipdaq.logformat.reader import data_bytes
from slipdaq.offline.decoder_tape import DecoderTape
from slipdaq.offline.forked import send_error, sized_pipe, started
from slipdaq.offline.items import Decode, Item, let_go, read_ahead
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrameBatch, GpsFix, SensorSample

FEED_BYTES = 128 << 20
"""A log is fed whole up to this many bytes of messages uncompressed (logformat.reader.data_bytes, every topic: 300 s
of 4 WPT messages at 1 kHz and 20 Hz NMEA take 32 MB raw, 122 MB as a run records them): the first pass's items are
kept for the second (in the run and, a log's process feeding them, there too: about twice the raw data in each). A
log's process feeds no longer log; past it, FedPasses's second pass reads and decodes the log itself."""


def fed_whole(log: str | Path) -> bool:
    """The log's messages take at most FEED_BYTES uncompressed (its summary's chunk indexes); False for a log without
    a summary (not finished: its size is not known before it is read)."""
    size = data_bytes(log)
    return size is not None and size <= FEED_BYTES


class DecodingPipeline(Pipeline):
    """A pipeline that makes only its decoders' calls (with Pipeline's cuts and diagnostics times): no estimator, no
    maneuver, no sink, no snapshot."""

    def _can_segment(self, batch: CanFrameBatch, parts: object, offset: int) -> None:
        self._segment_samples(batch)
        self.can_frames += len(batch)
        self._tick(float(batch.timestamp_s[-1]))

    def _fix(self, fix: GpsFix, log_time_s: float) -> None:
        pass

    def _sensor(self, sample: SensorSample) -> None:
        pass

    def _time_mark(self, mark: TimeMark | None) -> None:
        pass

    def emit_diagnostics(self) -> None:
        pass


class FeedSender:
    """In the process that reads the log (the log's process, a FeedProcess): the items it reads, each run decoded by a
    DecodingPipeline and sent to the run, send((run, its wheel entries, its line entries)), before the process takes
    it further; last send((None, end())) (a scan's result)."""

    def __init__(self, config: Config, send: Callable[[tuple[Any, ...]], None], end: Callable[[], Any] | None) -> None:
        self._tape = DecoderTape(sys.maxsize)  # the entries go to the run: the run's tape keeps them within its budget
        self._pipeline = DecodingPipeline(config, [], maneuvers=False, fast_slip=False)
        self._tape.attach(self._pipeline)
        self._send = send
        self._end = end

    def runs(self, items: Iterable[Item]) -> Iterator[Item]:
        """The items, each run of them sent (with its calls' entries) before it is given."""
        tape = self._tape
        for run in read_ahead(items):
            self._pipeline.process_all(run)
            self._send((run, tape.wheels, tape.lines))
            tape.wheels, tape.lines = [], []
            yield from run
        self._send((None, self._end() if self._end is not None else None))


def sending(feed: Connection) -> Callable[[tuple[Any, ...]], None]:
    """A FeedSender's send over a pipe (LogProcess.fed reads it)."""
    return lambda message: feed.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))


def received(feed: Connection, tape: DecoderTape, lost: Callable[[], NoReturn]) -> Generator[Item, None, Any]:
    """The items a FeedSender sends, each run's entries fed to tape before its items; returns the end's value, raises
    the error sent in its place (FeedProcess), or lost()'s (the sender's end closed without either)."""
    while True:
        try:
            data = feed.recv_bytes()
        except EOFError:
            lost()
        run, *rest = pickle.loads(data)
        if run is None:
            if len(rest) > 1:
                raise rest[1]
            return rest[0]
        tape.feed(*rest)
        yield from run


def _feed(config: Config, read: Callable[[], Iterable[Any]], decode: Decode, feed: Connection,
          parent_ends: tuple[Connection, ...], go: Connection | None, end: Callable[[], Any] | None) -> None:
    """A FeedProcess: (go given: once told to) the input read, decoded and sent run by run, then end()'s value; an
    error sent in place of the end."""
    started(parent_ends)
    if go is not None:
        try:
            go.recv_bytes()
        except EOFError:  # the run ended without the pass: nothing to read
            return
    send = sending(feed)
    try:
        for _ in FeedSender(config, send, end).runs(decode(read())):
            pass
    except BaseException as e:
        send_error(lambda error: send((None, None, error)), e, "the feed's process", RuntimeError)


class FeedProcess:
    """A forked process that reads an input (read()), decodes it (decode) and feeds it to a pass: items(tape). It
    reads ahead only as far as the pipe holds; waiting: not before items() is first iterated (a process forked at the
    run's start, before any thread, for a pass that comes later). close() ends it where it is (a pass that stopped
    early, or never came). end: what the process sends after the input (a scan of the log read there), fed_end once
    the items are taken."""

    def __init__(self, config: Config, read: Callable[[], Iterable[Any]], decode: Decode, *,
                 waiting: bool = False, end: Callable[[], Any] | None = None) -> None:
        compiled.prepare()  # the kernels loaded once, before the fork
        self._feed, writing = sized_pipe()
        self._go: Connection | None = None
        go = None
        if waiting:
            go, self._go = get_context("fork").Pipe(duplex=False)
        ends = (self._feed,) if self._go is None else (self._feed, self._go)
        self.fed_end: Any = None
        self.process = get_context("fork").Process(target=_feed, args=(config, read, decode, writing, ends, go, end),
                                                   name="slipdaq-feed", daemon=True)
        self.process.start()
        writing.close()
        if go is not None:
            go.close()

    def items(self, tape: DecoderTape) -> Iterator[Item]:
        """The input's items, each run's decoder calls fed to tape (a fed DecoderTape) before its items."""
        self._let_go(read=True)
        self.fed_end = yield from received(self._feed, tape, self._lost)

    def _let_go(self, read: bool) -> None:
        """A waiting process told, once, to read (read) or, never told to, to end."""
        if self._go is not None:
            if read:
                self._go.send_bytes(b"go")
            self._go.close()
            self._go = None

    def _lost(self) -> NoReturn:
        self.process.join()
        raise RuntimeError(f"the feed's process ended without its input's end (exit status {self.process.exitcode})")

    def close(self) -> None:
        self._let_go(read=False)
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()
        self._feed.close()


class FedPasses:
    """A two-pass run's input (as read_once.ReadOnce: first(), second(), tape), the first pass fed by fed(tape) (a log's
    process's LogProcess.fed, or a FeedProcess's: forked), on the core that pass leaves idle: its items, and its fed
    tape, kept for the second. Given again (a log too long to keep), the second pass's items are again(tape): fed
    (again_fed: by a second FeedProcess, forked waiting; `tape` is then the second pass's own fed tape once the first
    pass has ended), or read and decoded by the second pass itself (its tape dropped: it decodes)."""

    def __init__(self, fed: Callable[[DecoderTape], Iterable[Item]],
                 again: Callable[[DecoderTape], Iterable[Item]] | None = None, tape_bytes: int | None = None, *,
                 again_fed: bool = False, end: Callable[[], Any] = lambda: None) -> None:
        """end: what the first pass's feed sent after its input, once that pass has ended (its fed_end)."""
        self.tape = DecoderTape(tape_bytes, fed=True)
        self.fed_end = end
        self._fed, self._again, self._again_fed = fed, again, again_fed
        if again is not None:
            self.tape.drop()  # nothing kept: played to the first pass as it is fed
        self._items: list[Item] = []
        self._feeds: list[FeedProcess] = []
        """The processes that feed the passes, where they are this run's own (forked)."""

    @classmethod
    def forked(cls, config: Config, read: Callable[[], Iterable[Any]], decode: Decode, keep: bool, *,
               read_again: Callable[[], Iterable[Any]] | None = None, end: Callable[[], Any] | None = None
               ) -> FedPasses:
        """The first pass fed by a FeedProcess forked here (before any thread: the summaries' process after it; end:
        what it sends after the input, its fed_end); keep: a log fed whole (fed_whole); else the second pass fed by
        another, forked here too and waiting until the second pass begins, or (read_again given: the other core
        busy in the second pass) reading and decoding decode(read_again()) itself."""
        feeds = [FeedProcess(config, read, decode, end=end)]
        again: Callable[[DecoderTape], Iterable[Item]] | None = None
        if not keep and read_again is None:
            feeds.append(FeedProcess(config, read, decode, waiting=True))
            again = feeds[1].items
        elif not keep and read_again is not None:
            again_read = read_again
            again = lambda _: decode(again_read())  # noqa: E731
        passes = cls(feeds[0].items, again, again_fed=not keep and read_again is None,
                     end=lambda: feeds[0].fed_end)
        passes._feeds = feeds
        return passes

    def first(self) -> Iterator[Item]:
        keep = self._again is None
        for item in self._fed(self.tape):
            if keep:
                self._items.append(item)
            yield item
        if self._feeds:
            self._feeds[0].close()
        if self._again_fed:  # the second pass plays what its own feed sends, keeping nothing
            self.tape = DecoderTape(0, fed=True)
            self.tape.drop()

    def second(self) -> Iterator[Item]:
        if self._again is not None:
            yield from self._again(self.tape)
            self.close()
            return
        kept, self._items = self._items, []
        yield from let_go(kept)

    def close(self) -> None:
        for feed in self._feeds:
            feed.close()

    def __enter__(self) -> FedPasses:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
