"""What the benchmarks share to report: the machine in one line, and a table put into a doc between its markers."""

from __future__ import annotations

import os
import platform
import re
from pathlib import Path

_REVISION = re.compile(r"(?<![\w-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w-])")
"""A commit's hash, as git prints it (7 to 40 hex digits, letters and digits both)."""


def without_revisions(text: str) -> str:
    """text with every commit hash in it replaced by 'REV': a page says what is and how to check it (the command
    with `--base REV`), not which commit it was measured at."""
    return _REVISION.sub("REV", text)


def machine(*extra: str) -> str:
    """'cpu: ...; cores: N; python X.Y.Z', then `extra` (e.g. library versions)."""
    info = Path("/proc/cpuinfo")
    cpu = next((line.split(":", 1)[1].strip() for line in info.read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if info.exists() else ""
    return "; ".join([f"cpu: {cpu}", f"cores: {os.cpu_count()}", f"python {platform.python_version()}", *extra])


def write_block(doc: Path, begin: str, end: str, heading: str, block: str) -> None:
    """block between the begin and end markers of doc, in place of what was there; without the markers, appended
    under a new section `heading`."""
    text = doc.read_text()
    block = without_revisions(block)
    if begin in text:
        head, rest = text.split(begin, 1)
        text = head + begin + "\n" + block + "\n" + end + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + f"\n\n## {heading}\n\n" + begin + "\n" + block + "\n" + end + "\n"
    doc.write_text(text)
