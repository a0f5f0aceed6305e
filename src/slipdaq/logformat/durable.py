"""A file for the log's MCAP writer that is a complete MCAP file after every commit: what a killed daemon leaves is
readable.

The writer (logformat.mcap_writer, which writes mcap.Writer's file) writes whole records (header, metadata, a
finished chunk and its message indexes) to its stream and only writes the summary and footer in finish(). CommitFile
keeps those writes in memory and, on commit() (the writer's flush(), at least once a second in live runs), appends
them to the file followed by a provisional trailer (DataEnd, a Footer without summary, the closing magic) in one
write; the next commit overwrites that trailer. So at any moment outside that one write() the file on disk is a
valid MCAP file without a summary section, which the standard MCAP readers read linearly (mcap's SeekingReader falls
back to its NonSeekingReader when the footer says there is no summary). A process killed inside the write, or a
power loss before the data reached the disk, leaves a torn tail: `slipdaq recover` (logformat.salvage,
slipdaq.offline.recover) keeps everything before it.

After each commit the file is fsynced in a background thread (with fsync=True), so that a power loss costs at most
the data of the last second or two, without blocking the event loop on a slow disk.
"""

from __future__ import annotations

import errno
import os
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer

MAGIC = b"\x89MCAP0\r\n"


def _trailer() -> bytes:
    b = RecordBuilder()
    DataEnd(data_section_crc=0).write(b)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
    return b.end() + MAGIC


TRAILER = _trailer()
"""DataEnd + Footer (no summary) + magic: what makes the committed part a complete MCAP file."""
FIRST_BUFFER_BYTES = 64 * 1024
"""The commit buffer's first size; it doubles (at least) when a write does not fit."""


class LogWriteError(OSError):
    """Writing the log failed (disk full, I/O error); the file is valid up to its last commit."""

    def __str__(self) -> str:
        return f"log write failed: {self.strerror}: {self.filename}"

    @property
    def disk_full(self) -> bool:
        return self.errno in (errno.ENOSPC, errno.EDQUOT)


def describe(e: OSError) -> str:
    """'disk full (No space left on device)' for ENOSPC/EDQUOT, else the system's message."""
    text = e.strerror or str(e)
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full ({text})"
    return text


class CommitFile:
    """Write-only binary stream: write() buffers, commit() makes it durable and leaves a readable file."""

    def __init__(self, path: str | Path, *, fsync: bool = False, auto_commit_bytes: int = 1 << 20,
                 new_file: bool = False) -> None:
        """auto_commit_bytes: commit as soon as this much is buffered (the writer writes whole records only, so
        any write boundary is a valid place to commit), so that long offline runs do not pile up in memory.
        new_file: FileExistsError rather than overwrite a file that is there."""
        self.path = Path(path)
        keep = os.O_EXCL if new_file else os.O_TRUNC
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | keep | os.O_CLOEXEC, 0o644)
        self._pending = bytearray(FIRST_BUFFER_BYTES)
        """What is buffered: its first self._pending_bytes bytes (the buffer is kept from commit to commit, grown to
        the most ever buffered: a live run commits every second)."""
        self._pending_bytes = 0
        self._committed = 0
        """Bytes of the file that are committed (the provisional trailer after them is not counted)."""
        self._fsync = fsync
        self._auto_commit_bytes = auto_commit_bytes
        self._pool: ThreadPoolExecutor | None = None
        self._sync: Future[None] | None = None
        self._sync_error: OSError | None = None
        self.commits = 0
        self.closed = False

    # ---- the stream interface the MCAP writer uses ----
    def write(self, data: bytes | bytearray | memoryview) -> int:
        self._buffer(data)
        if self._pending_bytes >= self._auto_commit_bytes:
            self.commit()
        return len(data)

    def _buffer(self, data: bytes | bytearray | memoryview) -> None:
        n = self._pending_bytes
        end = n + len(data)
        if end > len(self._pending):
            grown = bytearray(max(end, 2 * len(self._pending)))
            grown[:n] = memoryview(self._pending)[:n]
            self._pending = grown
        self._pending[n:end] = data
        self._pending_bytes = end

    def tell(self) -> int:
        return self._committed + self._pending_bytes

    def flush(self) -> None:
        self.commit()

    # ---- durability ----
    def commit(self, *, final: bool = False) -> None:
        """Write what is buffered and (unless final) the provisional trailer, in one write at the committed end.

        Raises LogWriteError when the write fails; the file is then cut back to its last commit (with its trailer,
        if that still fits), so it stays readable, and the buffered data is dropped."""
        if self.closed or (not final and not self._pending_bytes and self.commits):
            return
        self._raise_sync_error()
        n = self._pending_bytes
        if not final:
            self._buffer(TRAILER)  # written from the buffer itself: no copy of up to auto_commit_bytes
        try:
            self._write_at(self._committed, memoryview(self._pending)[:self._pending_bytes])
            if final:
                os.ftruncate(self._fd, self._committed + n)
        except OSError as e:
            self._pending_bytes = 0
            self._restore()
            raise LogWriteError(e.errno, describe(e), str(self.path)) from None
        self._committed += n
        self._pending_bytes = 0
        self.commits += 1
        if self._fsync:
            self._start_sync()

    def _write_at(self, offset: int, data: bytes | bytearray | memoryview) -> None:
        view = memoryview(data)
        while view:
            n = os.pwrite(self._fd, view, offset)
            if n <= 0:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            offset += n
            view = view[n:]

    def _restore(self) -> None:
        """After a failed write: cut the torn data off and put the trailer back (best effort)."""
        try:
            os.ftruncate(self._fd, self._committed)
            self._write_at(self._committed, TRAILER)
        except OSError:
            pass

    def _start_sync(self) -> None:
        if self._sync is not None and not self._sync.done():
            return  # the previous fsync is still running; the next commit syncs this data too
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="slipdaq-fsync")
        self._sync = self._pool.submit(self._fsync_now)

    def _fsync_now(self) -> None:
        try:
            os.fsync(self._fd)
        except OSError as e:  # reported at the next commit
            self._sync_error = e

    def _raise_sync_error(self) -> None:
        e, self._sync_error = self._sync_error, None
        if e is not None:
            self._restore()
            raise LogWriteError(e.errno, describe(e), str(self.path))

    def close(self) -> None:
        """Commit what is left as the end of the file (the caller wrote the real footer), sync and close."""
        if self.closed:
            return
        try:
            self.commit(final=True)
        finally:
            self.abandon()

    def abandon(self) -> None:
        """Close without writing what is buffered: the file stays as it was at its last commit."""
        if self.closed:
            return
        self.closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=True)
        try:
            if self._fsync:
                os.fsync(self._fd)
        except OSError:
            pass
        finally:
            os.close(self._fd)
