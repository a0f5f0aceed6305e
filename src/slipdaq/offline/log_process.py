"""A replay's log written in a process of its own (LogProcess): the run's sink calls go, in order, to a forked process
that makes the log's sink and calls it. The CAN frames, their wheel samples and the other raw records, most of what a
sink gets, are not sent as records: the run sends its input as it read it (a log's raw messages, the bytes as read),
or the process reads the input itself (a two-pass run's, ahead, while the first pass runs); the process decodes it as
the run does and decodes the wheel frames as the pipeline does (the decoder gives the same samples however the frames
are cut), and a call names only how many frames or samples, with the first frame's or the record's time, or the
samples' first and last frame and last revolutions, which the process checks against what it decoded. The sink gets
the same calls with the same records: the same log."""

from __future__ import annotations

import pickle
import queue
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from multiprocessing import get_context
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any, NoReturn

from slipdaq import compiled
from slipdaq.config import Config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.offline.decoder_tape import DecoderTape
from slipdaq.offline.first_pass_feed import FeedSender, received, sending
from slipdaq.offline.forked import send_error, sized_pipe, started
from slipdaq.offline.items import Decode, Item
from slipdaq.records import CanFrame, CanFrameBatch, RawRecord, WheelSampleBatch
from slipdaq.sinks import SINK_CALLS, Sink

RUN_CALLS = 256
"""Calls pickled and sent together."""
QUEUED_RUNS = 256
"""Runs pickled and not yet written to the pipe at most: past it the run waits for the process (memory stays bounded)."""
DECODE_FRAMES = 8192
"""The log's process decodes the wheel frames of this many frames (of whole batches) at once (numpy's cost per call
paid once for many, as Pipeline.process_all does)."""
FRAMES, SAMPLES, RAW = "frames", "samples", "raw"
"""The calls whose records the process takes from the input it decodes: on_can_batch, on_wheel_batch, on_raw."""
INPUT, INPUT_END = "input", "input_end"
"""The input's pieces (a log's raw messages) the run read for its next item, the process decoding the same; the end
of the input's pieces."""
BEGIN = "begin"
"""The first call: the log's sink made (make_sink(**its keyword arguments))."""
AHEAD_FRAMES = 3 << 20
"""A log's process that reads its input itself decodes up to this many frames before the run's first call (a
two-pass run's first pass): about 250 MB of frames and wheel samples, 13 minutes of 4 WPT messages at 1 kHz."""

class LogProcessError(RuntimeError):
    """The log's process read other records than the run's, or ended without saying why."""


class _Pieces:
    """The input's pieces as the run sends them, item by item: an iterator that never runs dry while an item is owed."""

    def __init__(self) -> None:
        self._pieces: deque[Any] = deque()
        self.items = 0
        """Items the run has read: the process may take as many."""
        self._ended = False

    def add(self, pieces: list[Any]) -> None:
        self._pieces.extend(pieces)
        self.items += 1

    def __iter__(self) -> Iterator[Any]:
        return self

    def end(self) -> None:
        self._ended = True

    def __next__(self) -> Any:
        if not self._pieces:
            if self._ended:
                raise StopIteration
            raise LogProcessError("the log's process decoded more of the input than the run had read")
        return self._pieces.popleft()


class _Input:
    """The input as the log's process decodes it: its CAN frames in the pieces and its other raw records in the order
    the run's calls take them, its wheel frames decoded DECODE_FRAMES at a time."""

    def __init__(self, decode: Decode, config: Config, read: Callable[[], Iterable[Any]] | None = None,
                 feed: FeedSender | None = None) -> None:
        """read: the input's pieces, read here (the run sends none); else the run sends them (pieces). feed: the items
        read, fed to the run's first pass (first_pass_feed), all of them read ahead."""
        self.pieces = _Pieces()
        self._items = iter(decode(self.pieces if read is None else read()))
        if feed is not None:
            self._items = feed.runs(self._items)
        self._feeds = feed is not None
        self._reads_itself = read is not None
        self._ended = False
        self._ahead = 0
        """Frames decoded and not yet taken."""
        self._taken = 0
        self._decoder = WheelDecoder(config)
        self._batches: deque[tuple[CanFrameBatch, WheelSampleBatch, int]] = deque()
        """Batches read, each with the samples of the frames decoded with it and its first frame's index there."""
        self._pos = 0
        """Frames of the first batch taken already."""
        self._raw: deque[RawRecord] = deque()
        self._samples = WheelSampleBatch.empty()
        """The samples of the frames taken last."""

    def _read(self, need: bool = True) -> None:
        """Items decoded until DECODE_FRAMES frames or the last item the run has read, their wheel frames decoded at
        once."""
        got: list[CanFrameBatch] = []
        frames, raw = 0, len(self._raw)
        while frames < DECODE_FRAMES and (self._reads_itself or self._taken < self.pieces.items):
            item = next(self._items, None)
            if item is None and self._reads_itself:
                self._ended = True
                break
            if item is None:
                raise LogProcessError("the log's process decoded fewer items of the input than the run read")
            self._taken += 1
            if isinstance(item, list):
                item = CanFrameBatch.from_frames(item)
            if not isinstance(item, CanFrameBatch):
                self._raw.append(item)
            elif len(item):  # as Pipeline.process_all: an empty batch is passed over
                got.append(item)
                frames += len(item)
        if not got:
            if len(self._raw) == raw and need:
                raise LogProcessError("the run's calls name more of the input than it has read")
            return
        samples = self._decoder.decode_batch(got[0] if len(got) == 1 else CanFrameBatch.concat(got))
        first = 0
        for batch in got:
            self._batches.append((batch, samples, first))
            first += len(batch)
        self._ahead += frames

    def read_ahead(self) -> bool:
        """Decode the next items (of an input read here) while fewer than AHEAD_FRAMES frames wait (all, feeding the
        run); False when no more is to be decoded ahead."""
        if not self._reads_itself or self._ended or (self._ahead >= AHEAD_FRAMES and not self._feeds):
            return False
        self._read(need=False)
        return True

    def frames(self, n: int, first_s: float) -> CanFrameBatch:
        """The next n frames (a piece of one input batch, as the pipeline cuts them); first_s: the first one's time."""
        while not self._batches:
            self._read()
        batch, samples, first = self._batches[0]
        a, b = self._pos, self._pos + n
        if b > len(batch) or float(batch.timestamp_s[a]) != first_s:
            raise LogProcessError(f"the log's process read other CAN frames than the run's ({n} frames at "
                                  f"{first_s!r} s)")
        piece = batch if (a, b) == (0, len(batch)) else batch.slice(a, b)
        self._samples = samples.of_frames(first + a, first + b)
        self._ahead -= n
        if b == len(batch):
            self._batches.popleft()
            self._pos = 0
        else:
            self._pos = b
        return piece

    def samples(self, mark: tuple[int, int, int, float]) -> WheelSampleBatch:
        """The wheel samples of the frames taken last; mark: the run's (_mark)."""
        if _mark(self._samples) != mark:
            raise LogProcessError(f"the log's process decoded other wheel samples than the run's "
                                  f"({_mark(self._samples)} against {mark})")
        return self._samples

    def record(self, time_s: float) -> RawRecord:
        """The next raw record other than a CAN frame (its time: time_s)."""
        while not self._raw:
            self._read()
        record = self._raw.popleft()
        if record.timestamp_s != time_s:
            raise LogProcessError(f"the log's process read another record than the run's (at {time_s!r} s)")
        return record


def _mark(samples: WheelSampleBatch) -> tuple[int, int, int, float]:
    """What the log's process checks of the samples of a run of frames: how many, the first and last one's frame (in
    the run) and the last one's revolutions."""
    n = len(samples)
    return (n, int(samples.frame[0]), int(samples.frame[n - 1]), float(samples.revolutions[n - 1])) if n else \
        (0, 0, 0, 0.0)


def _serve(make_sink: Callable[..., Sink], decode: Decode, config: Config, read: Callable[[], Iterable[Any]] | None,
           feed: tuple[Connection, Callable[[], Any] | None] | None, calls: Connection, done: Connection,
           parent_ends: tuple[Connection, ...]) -> None:
    """The log's process: the input read ahead (read given) until the run's first call (feed: all of it, fed to the
    run's first pass, FeedSender); then the calls, run by run, to the sink (made by the first, BEGIN), until told to
    stop (then it is closed) or the run's end of the pipe closes; None back when the log is closed, else the
    error."""
    started(parent_ends)
    sink: Sink | None = None
    try:
        try:
            source = _Input(decode, config, read, FeedSender(config, sending(feed[0]), feed[1]) if feed else None)
            while not calls.poll() and source.read_ahead():
                pass
            def unbegun(*_: Any) -> None:
                raise LogProcessError("the run called the log's sink before it was made (LogProcess.begin)")

            take: dict[str, Callable[..., None]] = dict.fromkeys((*SINK_CALLS, FRAMES, SAMPLES, RAW), unbegun)

            def begin(kwargs: dict[str, Any]) -> None:
                nonlocal sink
                sink = out = make_sink(**kwargs)
                take.update({name: getattr(out, name) for name in SINK_CALLS})
                take[FRAMES] = lambda n, t: out.on_can_batch(source.frames(n, t))
                take[SAMPLES] = lambda mark: out.on_wheel_batch(source.samples(mark))
                take[RAW] = lambda t: out.on_raw(source.record(t))

            take[BEGIN], take[INPUT], take[INPUT_END] = begin, source.pieces.add, source.pieces.end
            while True:
                try:
                    data = calls.recv_bytes()
                except EOFError:  # the run has gone
                    return
                if (run := pickle.loads(data)) is None:
                    break
                for name, args in run:
                    take[name](*args)
        finally:
            if sink is not None:
                sink.close()
    except BaseException as e:
        calls.close()  # the run's next write fails at once: it then reads this error
        send_error(done.send, e, "the log's process", LogProcessError)
        return
    done.send(None)


class LogProcess(Sink):
    """A sink in a forked process (make_sink()'s there, made by the first call: begin) whose raw records come from the
    run's input as input() reads it, or as the process reads it itself (read), decoded there by decode: its calls are
    pickled here, RUN_CALLS at a time, and written to the pipe by a thread. close() waits for the process to close the
    log and raises its error, if any; a run that fails calls terminate(). Fork it before any thread is started (the
    summaries' process after it)."""

    def __init__(self, make_sink: Callable[..., Sink], decode: Decode, config: Config,
                 read: Callable[[], Iterable[Any]] | None = None, *, feed: bool = False,
                 feed_end: Callable[[], Any] | None = None) -> None:
        """make_sink(**begin's keyword arguments): the log's sink, made there; decode: the input's items from its
        pieces, as the run has them (items_of); read: the input's pieces, read there, ahead of the run's first call
        (a two-pass run's first pass, whose second core is idle), the run then sending none; else the run sends
        them (input). feed (with read): the items read there fed to the run's first pass (fed), with its decoders'
        calls; feed_end: what the process sends at the feed's end (fed_end), called there."""
        compiled.prepare()  # the kernels loaded once, before the fork
        ctx = get_context("fork")
        calls_in, self._calls = sized_pipe()
        self._done, done_out = ctx.Pipe(duplex=False)
        self._feed: Connection | None = None
        feed_out: Connection | None = None
        if feed:
            self._feed, feed_out = sized_pipe()
        self._decode = decode
        self.reads_itself = read is not None
        self.fed_end: Any = None
        """What the process sent at the feed's end (feed_end's value there), once fed() has given every item."""
        ends = tuple(c for c in (self._calls, self._done, self._feed) if c is not None)
        feeding = (feed_out, feed_end) if feed_out is not None else None
        self.process = ctx.Process(target=_serve, args=(make_sink, decode, config, read, feeding, calls_in, done_out,
                                                        ends), name="slipdaq-log", daemon=True)
        self.process.start()
        for end in (calls_in, done_out, feed_out):
            if end is not None:
                end.close()
        self._run: list[tuple[str, tuple[Any, ...]]] = []
        self._outbox: queue.Queue[bytes | None] = queue.Queue(QUEUED_RUNS)
        self._sender: threading.Thread | None = None
        self._broken = False
        """The pipe broke: the process has ended (its error is on the done pipe)."""
        self._ended = False

    def input(self, pieces: Iterable[Any]) -> Iterator[Item]:
        """The run's input: decode(pieces), each item's pieces (those read for it) sent to the process before it."""
        read: list[Any] = []

        def tee() -> Iterator[Any]:
            for piece in pieces:
                read.append(piece)
                yield piece
            self._call(INPUT_END, ())  # before the last item's pieces: what decode reads past them is the end

        for item in self._decode(tee()):
            self._call(INPUT, (read[:],))
            read.clear()
            yield item

    def fed(self, tape: DecoderTape) -> Iterator[Item]:
        """The input's items as the process feeds them (feed), each run's decoder calls fed to tape before it (a fed
        DecoderTape: the first pass's); then fed_end is what it sent last."""
        assert self._feed is not None, "fed() of a log's process that feeds nothing"
        self.fed_end = yield from received(self._feed, tape, self._raise_ended)

    def begin(self, **kwargs: Any) -> None:
        """The first call: the log's sink made there, make_sink(**kwargs)."""
        self._call(BEGIN, (kwargs,))

    def _call(self, name: str, args: tuple[Any, ...]) -> None:
        self._run.append((name, args))
        if len(self._run) >= RUN_CALLS:
            self._send_run()

    def _send_run(self) -> None:
        if self._broken:
            self._raise_ended()
        if self._sender is None:
            self._sender = threading.Thread(target=self._send, name="slipdaq-log-calls", daemon=True)
            self._sender.start()
        run, self._run = self._run, []
        self._outbox.put(pickle.dumps(run, protocol=pickle.HIGHEST_PROTOCOL))

    def _send(self) -> None:
        """The runs, in turn, to the process; once the pipe breaks, the rest are dropped (the run raises)."""
        while (data := self._outbox.get()) is not None:
            if self._broken:
                continue
            try:
                self._calls.send_bytes(data)
            except OSError:
                self._broken = True

    def _outcome(self) -> BaseException | None:
        """What the process says at its end: None (the log closed) or its error; waits for it."""
        self._ended = True
        try:
            error: BaseException | None = self._done.recv()
        except EOFError:
            error = LogProcessError(f"the log's process ended (exit status {self.process.exitcode})")
        return error

    def _raise_ended(self) -> NoReturn:
        """The process's error (it has ended, or ends now)."""
        error = self._outcome()
        self.terminate()
        raise error or LogProcessError("the log's process ended before the run did")

    def on_can_batch(self, batch: CanFrameBatch) -> None:
        self._call(FRAMES, (len(batch), float(batch.timestamp_s[0])))

    def on_wheel_batch(self, samples: WheelSampleBatch) -> None:
        self._call(SAMPLES, (_mark(samples),))

    def on_raw(self, record: RawRecord) -> None:
        if isinstance(record, CanFrame):  # not from the input's batches: sent as it is
            self._call("on_raw", (record,))
        else:
            self._call(RAW, (record.timestamp_s,))

    def close(self) -> None:
        """The calls sent, the log closed there; its error raised here."""
        if self._ended:
            return
        self._send_run()
        self._outbox.put(pickle.dumps(None))
        self._outbox.put(None)
        assert self._sender is not None
        self._sender.join()
        error = self._outcome()
        self.process.join()
        for end in (self._calls, self._done, self._feed):
            if end is not None:
                end.close()
        if error is not None:
            raise error

    def terminate(self) -> None:
        """The process ended now (SIGTERM), the log left as it is."""
        self._ended = True
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()
        self._outbox.put(None)
        if self._sender is not None:
            self._sender.join()
        for end in (self._calls, self._done, self._feed):
            if end is not None:
                end.close()

    def __enter__(self) -> LogProcess:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        """A run that ended well closes the log; one that ended with an error or an interrupt terminates it."""
        if error is None:
            self.close()
        elif not self._ended:
            self.terminate()


def _forwarded(name: str) -> Callable[..., None]:
    def call(self: LogProcess, *args: Any) -> None:
        self._call(name, args)
    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"{name}, to the log's process."
    return call


for _name in SINK_CALLS:
    if _name not in vars(LogProcess):
        setattr(LogProcess, _name, _forwarded(_name))
