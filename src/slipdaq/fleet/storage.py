"""Where `slipdaq batch` reads its logs and writes its outputs: local paths, or fsspec URLs (`s3://bucket/day1/x.mcap`,
`gs://...`, `memory://...`: any protocol fsspec knows and whose package is installed; s3fs comes with the fleet extra).

A log given as a URL is expanded by fsspec when it has a glob (`s3://bucket/day1/*.mcap`), keyed by fsspec's `info`
(its size and its ETag, or its last-modified time where the store has no ETag), and copied by the worker that
processes it into a local temporary file (the readers read local files), removed when the task ends. An output given
as a URL (`-o s3://bucket/out`) is written through fsspec: each task writes its own Parquet and cache objects there
(an object appears whole or not at all; the cache object, written last, is what makes a log up to date), and the
client uploads the report, built in a local temporary directory, file by file, its tables and index.html last.
Credentials and endpoint come from the store's own environment (for S3: `AWS_ACCESS_KEY_ID`,
`AWS_SECRET_ACCESS_KEY`, `AWS_ENDPOINT_URL`, `AWS_PROFILE`, ...; for any protocol fsspec's `FSSPEC_<PROTOCOL>_<KWARG>`,
e.g. `FSSPEC_S3_ENDPOINT_URL`), read in every worker's process.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

GLOB = re.compile(r"[*?\[]")


class FleetError(Exception):
    """Dask missing, the cluster cannot be reached, a URL that cannot be used (one line)."""


def is_url(p: str | os.PathLike[str]) -> bool:
    """A log or an output given as a URL (`proto://...`); a Path never is."""
    return isinstance(p, str) and re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", p) is not None


def filesystem(url: str) -> tuple[Any, str]:
    """fsspec's filesystem of a URL and the path in it; FleetError when fsspec, or the protocol's package, is
    missing or the protocol is unknown."""
    try:
        from fsspec.core import url_to_fs
    except ImportError:
        raise FleetError(f"{url}: URLs need fsspec: pip install -e \".[fleet]\"") from None
    try:
        return url_to_fs(url)
    except (ImportError, ValueError) as e:
        raise FleetError(f"{url}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None


def expand_logs(logs: Sequence[str | Path]) -> list[str | Path]:
    """The logs with every URL that has a glob replaced by the URLs it matches (sorted); local paths as given (the
    shell expands their globs). FleetError when a glob matches nothing or its store cannot be listed."""
    out: list[str | Path] = []
    for log in logs:
        if not is_url(log) or not GLOB.search(str(log)):
            out.append(log)
            continue
        fs, path = filesystem(str(log))
        try:
            fs.invalidate_cache()
            matches = sorted(fs.glob(path))
        except Exception as e:  # no such bucket, no credentials, the endpoint unreachable, ...
            raise FleetError(f"{log}: cannot list: {_one_line(e)}") from None
        if not matches:
            raise FleetError(f"{log}: matches no file")
        out += [fs.unstrip_protocol(m) for m in matches]
    return out


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text and text[0] else type(e).__name__


def url_identity(url: str) -> dict[str, Any]:
    """What the key of a log at a URL hashes instead of its size and mtime: fsspec's info (size, ETag or
    last-modified). FileNotFoundError (with the URL) when there is no such file."""
    fs, path = filesystem(url)
    try:
        fs.invalidate_cache(path)
        info = fs.info(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{url}: no such file") from None
    except OSError as e:
        raise OSError(f"{url}: {_one_line(e)}") from None
    if info.get("type") == "directory":
        raise IsADirectoryError(f"{url}: is a directory")
    changed = next((info[k] for k in ("ETag", "etag", "md5Hash", "LastModified", "last_modified", "mtime", "updated",
                                      "created") if info.get(k) is not None), None)
    return {"url": url, "size": info.get("size"), "changed": str(changed)}


@contextlib.contextmanager
def local_copy(log: str) -> Iterator[str]:
    """A local path of the log: itself, or for a URL a temporary copy removed at the end."""
    if not is_url(log):
        yield log
        return
    fs, path = filesystem(log)
    with tempfile.TemporaryDirectory(prefix="slipdaq-log-") as tmp:
        local = os.path.join(tmp, os.path.basename(path.rstrip("/")) or "log.mcap")
        try:
            fs.get_file(path, local)
        except FileNotFoundError:
            raise FileNotFoundError(f"{log}: no such file") from None
        yield local


class UrlStore:
    """An output directory at a URL: objects by their path relative to it."""

    def __init__(self, url: str) -> None:
        self.url = url.rstrip("/")
        self.fs, path = filesystem(self.url)
        self.root = path.rstrip("/")
        self.fs.invalidate_cache()  # listings cached by an earlier run in this process are stale

    def where(self, rel: str) -> str:
        return f"{self.url}/{rel}"

    def _full(self, rel: str) -> str:
        return f"{self.root}/{rel}"

    def exists(self, rel: str) -> bool:
        return bool(self.fs.exists(self._full(rel)))

    def read(self, rel: str) -> bytes:
        data: bytes = self.fs.cat_file(self._full(rel))
        return data

    def write(self, rel: str, data: bytes) -> None:
        self.fs.pipe_file(self._full(rel), data)

    def put(self, local: str | Path, rel: str) -> None:
        self.fs.put_file(str(local), self._full(rel))

    def names(self, rel_dir: str) -> list[str]:
        """The file names directly in rel_dir (none when it does not exist)."""
        self.fs.invalidate_cache(self._full(rel_dir))
        try:
            return [os.path.basename(p.rstrip("/")) for p in self.fs.ls(self._full(rel_dir), detail=False)]
        except FileNotFoundError:
            return []

    def remove(self, rel: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.fs.rm_file(self._full(rel))

    def check_writable(self) -> None:
        """FleetError (one line) when nothing can be written there (no such bucket, no credentials, ...): a probe
        object written and removed."""
        probe = f"cache/.slipdaq-probe-{os.getpid()}"
        try:
            self.write(probe, b"")
            self.remove(probe)
        except Exception as e:
            raise FleetError(f"{self.url}: cannot write there: {_one_line(e)}") from None

    def put_tree(self, local_dir: Path, rel_dir: str, last: Sequence[str] = ()) -> None:
        """Every file under local_dir uploaded to rel_dir (the names in `last` last), then the objects under rel_dir
        that local_dir does not have removed."""
        files = sorted((p.relative_to(local_dir).as_posix() for p in local_dir.rglob("*") if p.is_file()),
                       key=lambda r: (r in last, last.index(r) if r in last else 0, r))
        for r in files:
            self.put(local_dir / r, f"{rel_dir}/{r}")
        self.fs.invalidate_cache()
        keep = {self._full(f"{rel_dir}/{r}") for r in files}
        try:
            found = self.fs.find(self._full(rel_dir))
        except FileNotFoundError:
            found = []
        stale = [p for p in found if p.rstrip("/") not in keep]
        if stale:
            self.fs.rm(stale)
