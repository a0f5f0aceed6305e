"""Log rotation: when a run's log is cut into segments, and what the segments are called.

A long run can be split into segment files by size or by duration (`RotationPolicy`). The cut is made between two
messages, on the thread that writes them: the segment in progress is finished (summary and footer), the next one is
opened with the same metadata (config, DBC, labels) plus its `segment` number and the `previous_segment` file name,
and the message that was due goes into it, so no message is lost or written twice at a boundary.

Every segment is a complete slipdaq log. Replaying a later segment alone starts the estimator afresh; to replay a
rotated run as one, join its segments first: `slipdaq recover SEG1 SEG2 ... -o RUN.mcap`.

Segments: `NAME.mcap`, then `NAME_002.mcap`, `NAME_003.mcap`, ... (they sort in order after the first). A log that
could not be written for a while (disk full) goes on in the next segment once space is free again.
"""

from __future__ import annotations

import glob
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RotationPolicy:
    max_bytes: int | None = None
    """Start a new segment once the current one has this many bytes on disk (None: no limit)."""
    max_s: float | None = None
    """Start a new segment once the current one has been open this long, monotonic seconds (None: no limit)."""

    def __post_init__(self) -> None:
        if self.max_bytes is not None and self.max_bytes <= 0:
            raise ValueError("max_bytes must be positive")
        if self.max_s is not None and self.max_s <= 0:
            raise ValueError("max_s must be positive")

    @property
    def enabled(self) -> bool:
        return self.max_bytes is not None or self.max_s is not None

    def due(self, size_bytes: int, age_s: float) -> bool:
        return (self.max_bytes is not None and size_bytes >= self.max_bytes) or (
            self.max_s is not None and age_s >= self.max_s
        )


def segment_path(first: Path, number: int) -> Path:
    """The path of segment `number` (1-based) of the run whose first segment is `first`."""
    if number <= 1:
        return first
    return first.with_name(f"{first.stem}_{number:03d}{first.suffix}")


def later_segments_glob(first: Path) -> str:
    """A glob pattern (in first's directory) for every segment after the first of the run that starts at `first`."""
    return f"{glob.escape(first.stem)}_[0-9][0-9][0-9]*{glob.escape(first.suffix)}"


def run_segments(first: Path) -> list[Path]:
    """The segments of the run that starts at `first` that exist on disk, in order (stops at the first gap)."""
    out = [first] if first.exists() else []
    n = 2
    while (p := segment_path(first, n)).exists():
        out.append(p)
        n += 1
    return out
