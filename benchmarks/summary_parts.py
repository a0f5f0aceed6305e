#!/usr/bin/env python3
"""What each part of the maneuver summaries costs over a log's maneuvers: the log replayed in process (imports and
kernels warm, nothing written) with every summary computed at once on the main thread, a CPU timer
(`time.thread_time`) around each part's calls. With --base REV the same in a process of that revision's slipdaq,
the two sides in turns; the least of the rounds per part.

    python -m benchmarks.summary_parts RAW [--rounds 3] [--base REV]

RAW: a raw log (`python -m benchmarks.replay_process --work DIR` writes one into DIR).
"""

from __future__ import annotations

import argparse
import importlib
import io
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchmarks.base_revision import add_base_argument, in_turns, side_json, unpack

PARTS = (
    ("slipdaq.maneuver.figures", "summarize_maneuver", "a maneuver's whole summary"),
    ("slipdaq.maneuver.tire_limit", "tire_curves", "the tire curves (μ–slip, joint fit, peak interval)"),
    ("slipdaq.maneuver.mu_joint", "fit_joint", "the joint tire fit (near the limit)"),
    ("slipdaq.maneuver.mu_slip", "fit_mu_slip", "the per-wheel μ–slip fits"),
    ("slipdaq.maneuver.mu_slip", "peak_interval", "the peak's bootstrap interval"),
    ("slipdaq.maneuver.figures", "summarize_wheel", "a wheel's figures"),
    ("slipdaq.maneuver.linearity", "analyse_linearity", "the linear region"),
    ("slipdaq.maneuver.brake_noise", "brake_intervals", "the brake intervals"),
)
"""(module, function, what it is): each timed where it is defined and wherever a part module imported it by name."""
USERS = ("slipdaq.maneuver.figures", "slipdaq.maneuver.tire_limit", "slipdaq.maneuver.detector",
         "slipdaq.maneuver.mu_slip", "slipdaq.maneuver.mu_joint", "slipdaq.maneuver.brake_test")


def _timed(spent: dict[str, list[float]]) -> None:
    """Every part wrapped in a CPU timer, in its module and in the modules that imported it by name."""
    wrapped: dict[tuple[str, str], Callable[..., Any]] = {}
    for mod, name, _ in PARTS:
        module = importlib.import_module(mod)
        f = getattr(module, name)

        def timer(*args: Any, _f: Callable[..., Any] = f, _name: str = name, **kw: Any) -> Any:
            t = time.thread_time()
            try:
                return _f(*args, **kw)
            finally:
                got = spent.setdefault(_name, [0, 0.0])
                got[0] += 1
                got[1] += time.thread_time() - t

        setattr(module, name, timer)
        wrapped[(mod, name)] = timer
    for user in USERS:
        module = importlib.import_module(user)
        for (mod, name), timer in wrapped.items():
            if mod != user and hasattr(module, name):
                setattr(module, name, timer)


def _one(raw: Path) -> dict[str, list[float]]:
    """This slipdaq's parts over one in-process replay of raw (the first one warms imports and kernels)."""
    from slipdaq import compiled
    from slipdaq.logformat.reader import config_from_log, iter_raw_batches
    from slipdaq.offline.run import process

    spent: dict[str, list[float]] = {}
    _timed(spent)
    compiled.prepare()
    config = config_from_log(raw)
    process(config, iter_raw_batches(raw), [], stream=io.StringIO())
    return spent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    add_base_argument(ap)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a side's single round, as JSON
    a = ap.parse_args()
    if a.one:
        print(json.dumps(_one(a.raw)))
        return 0
    sides = {"this tree": Path(__file__).resolve().parents[1] / "src"}
    if a.base:
        sides[f"base {a.base}"] = unpack(a.base, Path(tempfile.gettempdir()) / f"slipdaq-base-{a.base}")
    least: dict[str, dict[str, list[float]]] = {side: {} for side in sides}
    for r, side in in_turns(sides, a.rounds):
        got = side_json(sides[side], __file__, str(a.raw), "--one")
        for name, (calls, cpu) in got.items():
            old = least[side].get(name)
            least[side][name] = [calls, cpu if old is None else min(old[1], cpu)]
        print(f"  round {r + 1} {side}: " + ", ".join(f"{n} {v[1]:.3f} s" for n, v in got.items()),
              file=sys.stderr)
    print(f"\nThe maneuver summaries of {a.raw.name} replayed in process, a CPU timer around each part; the least of "
          f"{a.rounds} rounds (`python -m benchmarks.summary_parts RAW --rounds {a.rounds}"
          f"{' --base ' + a.base if a.base else ''}`)\n")
    names = list(sides)
    print("| part | calls | " + " | ".join(f"{n}, CPU s" for n in names) + " |")
    print("|---|---:|" + "---:|" * len(names))
    for _, name, what in PARTS:
        row = [least[n].get(name) for n in names]
        calls = next((r[0] for r in row if r is not None), 0)
        print(f"| {what} (`{name}`) | {calls} | " + " | ".join(f"{r[1]:.3f}" if r else "—" for r in row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
