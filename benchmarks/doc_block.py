"""What the benchmarks share to report: the machine in one line, and a table put into a doc between its markers."""

from __future__ import annotations

import os
import platform
from pathlib import Path


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
    if begin in text:
        head, rest = text.split(begin, 1)
        text = head + begin + "\n" + block + "\n" + end + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + f"\n\n## {heading}\n\n" + begin + "\n" + block + "\n" + end + "\n"
    doc.write_text(text)
