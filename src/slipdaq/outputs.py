"""Output files of the offline verbs: never one of the inputs, and in place only once complete.

Each output is written under a temporary name beside it (`.NAME.XXXXXXXX.part`) and renamed over NAME after an
fsync, when the whole output is written; on any error, Ctrl-C included, the temporary file is removed and NAME is
left as it was. A report's directory gets its files the same way, one by one, its index last.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

PathLike = str | os.PathLike[str]
MOVERS = 8
"""Threads that move a report's files into place (atomic_tree): their fsyncs overlap."""


class OutputError(Exception):
    """An output path that cannot be used (one of the inputs, a directory); the message names it. Bad usage."""


def same_file(a: PathLike, b: PathLike) -> bool:
    """a and b name one file: the same path once resolved (symlinks, `./`, `..`) or the same inode (a hard link)."""
    if Path(a).resolve() == Path(b).resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist
        return False


def refuse_inputs(outputs: Iterable[PathLike], inputs: Iterable[PathLike]) -> None:
    """OutputError when an output is one of the inputs: writing it would destroy that input."""
    inputs = list(inputs)
    for out in outputs:
        for inp in inputs:
            if same_file(out, inp):
                raise OutputError(f"{out}: the output would overwrite the input {inp}; choose another output path")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _rmdir(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.rmdir()


@contextlib.contextmanager
def _directory(d: Path) -> Iterator[None]:
    """d made (with its parents); the ones made here are removed again when the block fails and they are empty."""
    made = [p for p in (d, *d.parents) if not p.exists()]
    d.mkdir(parents=True, exist_ok=True)
    try:
        yield
    except BaseException:
        for p in made:  # innermost first
            with contextlib.suppress(OSError):
                p.rmdir()
        raise


@contextlib.contextmanager
def atomic_output(path: PathLike, *, inputs: Iterable[PathLike] = ()) -> Iterator[Path]:
    """A temporary path beside `path` for the caller to write the output to, renamed to `path` when the block ends
    without an exception; removed otherwise. Refuses a `path` that is one of `inputs` before anything is written.
    A `path` that is a symlink keeps pointing to the new file."""
    refuse_inputs([path], inputs)
    final = Path(path).resolve()
    if final.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name")
    tmp = final.with_name(f".{final.name}.{secrets.token_hex(4)}.part")
    with _directory(final.parent):
        try:
            yield tmp
            _fsync(tmp)
            os.replace(tmp, final)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    _fsync(final.parent)


@contextlib.contextmanager
def atomic_tree(directory: PathLike, *, inputs: Iterable[PathLike] = (), last: Sequence[str] = ()) -> Iterator[Path]:
    """A temporary directory inside `directory` for the caller to build its files in. When the block ends without an
    exception each file is moved to the same place under `directory` (fsync, rename: each one complete, an older one
    replaced; several at a time), the files named in `last` (relative paths) last, one by one in that order; nothing
    is moved when one of them would be one of `inputs`. On any error the temporary directory is removed, and
    `directory` too when it was made here."""
    inputs = list(inputs)
    refuse_inputs([directory], inputs)
    out = Path(directory)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: is a file, not a directory")
    with _directory(out):
        build = Path(tempfile.mkdtemp(prefix=".slipdaq-", suffix=".part", dir=out))
        try:
            yield build
            files = sorted((p.relative_to(build).as_posix() for p in build.rglob("*") if p.is_file()),
                           key=lambda rel: (rel in last, last.index(rel) if rel in last else 0, rel))
            refuse_inputs((out / rel for rel in files), inputs)
            for d in dict.fromkeys((out / rel).parent for rel in files):
                d.mkdir(parents=True, exist_ok=True)

            def move(rel: str) -> None:
                _fsync(build / rel)
                os.replace(build / rel, out / rel)

            ordinary = [rel for rel in files if rel not in last]
            with ThreadPoolExecutor(MOVERS) as pool:  # fsync and rename wait on the disk, not on Python
                list(pool.map(move, ordinary))
                for rel in files[len(ordinary):]:
                    move(rel)
                list(pool.map(_fsync, {(out / rel).parent for rel in files}))
                for level in sorted({len(p.parts) for p in build.rglob("*")}, reverse=True):  # the emptied folders
                    list(pool.map(_rmdir, [p for p in build.rglob("*") if len(p.parts) == level]))
        finally:
            shutil.rmtree(build, ignore_errors=True)
