#!/usr/bin/env python3
"""The largest change of each logged field between two logs of the same run (a base revision's output against this
tree's, where their values differ in the last bits on purpose): per topic and field, the largest absolute change,
the largest change relative to the field's largest magnitude in the base, and how many values differ.

The messages are paired as replay_check's --values pairs them (same topic, log time and order; /slip/fast row by
row); nested fields are named by their path (`wheels.FL.slip`). A field that is a number on one side and absent or
null on the other, or messages that do not pair, count as a structural difference and are listed.

    python -m benchmarks.value_changes BASE.mcap NEW.mcap [BASE2.mcap NEW2.mcap ...]
    python -m benchmarks.value_changes --work /tmp/replay-check   # its out2-*-base.mcap / out2-*-new.mcap pairs
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from benchmarks.replay_check import _flat, _values


def _number(x: Any) -> float | None:
    return float.fromhex(x[1]) if isinstance(x, tuple) and x[:1] == ("float",) else \
        float(x) if isinstance(x, int) and not isinstance(x, bool) else None


def changes(a: Path, b: Path) -> tuple[dict[str, list[float]], list[str]]:
    """{topic field: [largest |change|, largest |base value|, values differing, values]} and the structural
    differences."""
    va, vb = _values(a), _values(b)
    out: dict[str, list[float]] = {}
    structural: list[str] = []
    if len(va) != len(vb):
        structural.append(f"message counts differ: {len(va)} != {len(vb)}")
    for (ta, la, xa), (tb, lb, xb) in zip(va, vb):
        if (ta, la) != (tb, lb):
            structural.append(f"messages do not pair: {ta} at {la} / {tb} at {lb}")
            break
        if xa == xb:
            continue
        fa, fb = _flat(xa) if isinstance(xa, dict) else {"": xa}, _flat(xb) if isinstance(xb, dict) else {"": xb}
        for key in fa.keys() | fb.keys():
            p, q = fa.get(key), fb.get(key)
            if p == q:
                continue
            na, nb = _number(p), _number(q)
            if na is None or nb is None or math.isnan(na) != math.isnan(nb):
                structural.append(f"{ta} {key} at {la}: {p} / {q}")
                continue
            row = out.setdefault(f"{ta} {key}", [0.0, 0.0, 0, 0])
            if not math.isnan(na):
                row[0] = max(row[0], abs(nb - na))
                row[1] = max(row[1], abs(na))
            row[2] += 1
    for ta, _, xa in va:  # each changed field's count of values and largest magnitude over all messages
        for key, p in (_flat(xa) if isinstance(xa, dict) else {"": xa}).items():
            row = out.get(f"{ta} {key}")
            if row is not None and (n := _number(p)) is not None:
                row[3] += 1
                if math.isfinite(n):
                    row[1] = max(row[1], abs(n))
    return out, structural


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="*", type=Path, help="pairs of logs: base, new")
    ap.add_argument("--work", type=Path, help="a replay_check --two-pass work directory: its out2-* pairs")
    a = ap.parse_args()
    pairs = list(zip(a.logs[0::2], a.logs[1::2]))
    if a.work is not None:
        pairs += [(p, p.with_name(p.name.replace("-base.mcap", "-new.mcap"))) for p in sorted(a.work.glob("out2-*-base.mcap"))]
    total: dict[str, list[float]] = {}
    for base, new in pairs:
        got, structural = changes(base, new)
        print(f"{base.name} / {new.name}: {len(got)} fields changed" + "".join(f"\n  {s}" for s in structural[:10]))
        for key, (d, m, n, k) in got.items():
            row = total.setdefault(key, [0.0, 0.0, 0, 0])
            row[0], row[1] = max(row[0], d), max(row[1], m)
            row[2] += n
            row[3] += k
    print("\n| topic field | largest change | largest value | relative | values changed |\n|---|---:|---:|---:|---:|")
    for key, (d, m, n, k) in sorted(total.items()):
        print(f"| {key} | {d:.3g} | {m:.3g} | {d / m if m else math.nan:.2g} | {n:,} of {k:,} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
