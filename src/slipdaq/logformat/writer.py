"""The log file as written: segments of MCAP (zstd chunks) with every topic registered, committed so that the file on
disk is a complete MCAP file after every commit (logformat.durable), cut into segments by a RotationPolicy
(logformat.rotation), and a failed write (disk full) survived: the segment is kept as it was at its last commit,
messages are counted as dropped, and a new segment is tried every RETRY_AFTER_FAILURE_S."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType

import slipdaq
from slipdaq.logformat.durable import CommitFile, LogWriteError, describe
from slipdaq.logformat.mcap_writer import McapWriter
from slipdaq.logformat.registry import TOPIC_FORMATS
from slipdaq.logformat.rotation import RotationPolicy, segment_path
from slipdaq.logformat.topics import METADATA_NAME, PROFILE, log_time_ns

log = logging.getLogger(__name__)

RETRY_AFTER_FAILURE_S = 5.0
"""After a failed write (disk full), how often a new segment is tried."""

EventCallback = Callable[["LogWriter", str, str, "float | None"], None]
"""(writer, event, detail, gap_s): write_failed, resumed, rotated."""


class LogWriter:
    """Messages in, MCAP segments out. `survive_failures` (live runs): a failed write is reported through `on_event`
    and `error` and writing resumes later; otherwise (replay, import) it raises, as their output would be
    incomplete."""

    def __init__(
        self,
        first_path: Path,
        metadata: dict[str, str],
        *,
        chunk_size_bytes: int,
        fsync: bool,
        survive_failures: bool,
        new_files_only: bool = False,
        rotation: RotationPolicy | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        on_event: EventCallback | None = None,
        can_channels: Sequence[str | None] = (),
    ) -> None:
        self.first_path = first_path
        self.path = first_path
        self._meta = dict(metadata)
        self._chunk_size = chunk_size_bytes
        self._fsync = fsync
        self._survive = survive_failures
        self._new_files_only = new_files_only
        self.rotation = rotation if rotation is not None and rotation.enabled else None
        self._mono = monotonic
        self._on_event = on_event
        self.can_channels: list[str | None] = []
        """The log's CAN channel names: a /can/raw frame's `channel` is an index into it (metadata can_channels)."""
        self.channel_names: tuple[str | None, ...] = ()
        self.segments: list[Path] = []
        self.messages = 0
        self.dropped_messages = 0
        """Messages not written because the log could not be written (disk full)."""
        self.write_failures = 0
        self.error: str | None = None
        """While the log cannot be written: what failed (one line); None when writing."""
        self.closed = False
        self._file: CommitFile | None = None
        self._writer: McapWriter | None = None
        self._channels: dict[str, int] = {}
        self._seq = 0
        self._last_ns = 0
        """Log time of the last message written: no message is written with an earlier one."""
        self.last_commit = self._mono()
        self.unflushed = 0
        self._opened_at = self.last_commit
        self._failed_since: float | None = None
        self.last_try = 0.0
        self.add_channels(can_channels)
        try:
            self._open_segment(1)
        except LogWriteError as e:
            if not e.disk_full:
                raise
            self._fail(e)  # a full disk at the start: estimate anyway, retry, and say so

    @property
    def writing(self) -> bool:
        return self._writer is not None

    @property
    def size_bytes(self) -> int:
        """Bytes of the segment being written (committed and buffered)."""
        return self._file.tell() if self._file is not None else 0

    @property
    def commits(self) -> int:
        return self._file.commits if self._file is not None else 0

    def counters(self) -> dict[str, int]:
        return {"segments": len(self.segments), "write_failures": self.write_failures,
                "dropped_messages": self.dropped_messages}

    # ---- segments ----
    def _segment_meta(self, number: int) -> dict[str, str]:
        """The `slipdaq` metadata record of segment `number`."""
        meta = dict(self._meta)
        if number > 1 or self.rotation is not None:
            meta["segment"] = str(number)
            meta["first_segment"] = self.first_path.name
        if number > 1:
            meta["previous_segment"] = segment_path(self.first_path, number - 1).name
        return meta

    def add_channels(self, names: Sequence[str | None]) -> None:
        """CAN channel names into can_channels (new ones at its end). When it grows while a segment is open, a copy
        of the `slipdaq` metadata record with the longer list is written at once: before any frame that uses it
        (readers take the last record)."""
        new = [n for n in dict.fromkeys(names) if n not in self.channel_names]
        if not new:
            return
        self.can_channels += new
        self.channel_names = tuple(self.can_channels)
        self._meta["can_channels"] = json.dumps(self.can_channels)
        if self._writer is not None:
            try:
                self._writer.add_metadata(METADATA_NAME, self._segment_meta(len(self.segments)))
            except LogWriteError as e:
                self._fail(e)

    def _open_segment(self, number: int) -> None:
        path = segment_path(self.first_path, number)
        file = CommitFile(path, fsync=self._fsync, new_file=self._new_files_only)
        try:
            writer = McapWriter(file, chunk_size=self._chunk_size)
            writer.start(profile=PROFILE, library=f"slipdaq {slipdaq.__version__}")
            channels: dict[str, int] = {}
            for fmt in TOPIC_FORMATS.values():
                sid = writer.register_schema(fmt.schema_name, fmt.schema_encoding, fmt.schema_data)
                channels[fmt.topic] = writer.register_channel(fmt.topic, fmt.message_encoding, sid)
            writer.add_metadata(METADATA_NAME, self._segment_meta(number))
            file.commit()  # header and metadata on disk: a valid (empty) log from the start
        except BaseException:
            file.abandon()
            if not file.commits:
                path.unlink(missing_ok=True)
            raise
        self._file, self._writer, self._channels = file, writer, channels
        self.path = path
        self.segments.append(path)
        self._opened_at = self._mono()
        self.last_commit = self._opened_at

    def _finish_segment(self) -> None:
        writer, file = self._writer, self._file
        self._writer = self._file = None
        if writer is None or file is None:
            return
        try:
            writer.finish()
            file.close()
        except OSError as e:
            writer.close_pool()
            file.abandon()
            self._fail(e if isinstance(e, LogWriteError) else LogWriteError(e.errno, describe(e), str(file.path)))

    def _fail(self, e: LogWriteError) -> None:
        """Writing failed: keep the file as it was at its last commit, drop this segment, retry later (or raise)."""
        if self._writer is not None:
            self._writer.close_pool()
        if not self._survive:
            if self._file is not None:
                self._file.abandon()
            self._writer = self._file = None
            raise e
        if self._file is not None:
            self._file.abandon()
        self._writer = self._file = None
        self.write_failures += 1
        self._failed_since = self._mono()
        self.last_try = self._failed_since
        self.error = f"log write failed: {e.strerror} ({e.filename or self.path})"
        log.error("%s; estimating goes on, logging resumes in a new file when it can be written", self.error)
        self._event("write_failed", f"{self.error}; the file is readable up to its last second before that")

    def try_resume(self) -> None:
        now = self._mono()
        if now - self.last_try < RETRY_AFTER_FAILURE_S:
            return
        self.last_try = now
        try:
            self._open_segment(len(self.segments) + 1)
        except OSError as e:
            log.debug("log still not writable: %s", e)
            return
        gap = now - (self._failed_since or now)
        text = f"logging again in {self.path.name} after {gap:.1f} s; {self.dropped_messages} messages dropped"
        self.error = None
        self._failed_since = None
        log.error("%s", text)
        self._event("resumed", text, gap)

    def rotation_due(self, now: float) -> bool:
        return (self.rotation is not None and self._file is not None
                and self.rotation.due(self._file.tell(), now - self._opened_at))

    def rotate(self) -> None:
        old = self.path
        self._finish_segment()
        if self._writer is None and self.error is None:
            try:
                self._open_segment(len(self.segments) + 1)
            except OSError as e:
                self._fail(e if isinstance(e, LogWriteError) else LogWriteError(e.errno, describe(e), str(old)))
                return
            self._event("rotated", f"{old.name} finished, continuing in {self.path.name}")

    def _event(self, event: str, detail: str, gap_s: float | None = None) -> None:
        if self._on_event is not None:
            self._on_event(self, event, detail, gap_s)

    # ---- messages ----
    def write(self, topic: str, log_time_s: float, data: bytes, now: float) -> bool:
        """One message, its log time no earlier than the last message's (the file is in log-time order); False when
        it was dropped (the log cannot be written). now: the monotonic clock."""
        if self._writer is None:
            if self.closed:
                return False
            self.dropped_messages += 1
            self.try_resume()
            if self._writer is None:
                return False
        if self.rotation is not None and self.rotation_due(now):
            self.rotate()
            if self._writer is None:
                self.dropped_messages += 1
                return False
        self._seq += 1
        ns = log_time_ns(log_time_s)
        if ns < self._last_ns:
            ns = self._last_ns
        self._last_ns = ns
        try:
            self._writer.add_message(self._channels[topic], log_time=ns, data=data, publish_time=ns,
                                     sequence=self._seq & 0xFFFFFFFF)
        except LogWriteError as e:
            self._fail(e)
            return False
        self.messages += 1
        self.unflushed += 1
        return True

    def commit(self) -> None:
        """Close the chunk in progress and commit the file (it is then complete up to here on disk)."""
        if self._writer is None:
            return
        try:
            self._writer.flush()
        except LogWriteError as e:
            self._fail(e)
            return
        self.unflushed = 0
        self.last_commit = self._mono()

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._finish_segment()
