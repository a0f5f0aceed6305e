"""Where a maneuver begins and ends: the phase of each estimate row, debounced, and its runs joined into events.
Pure (sequences in, row indices out); the one rule for live (`detector`), replay and the report.

Each estimate row has a phase: its own `phase` field when the log has one, else `fallback.derive_phases` (speed
< 0.5 m/s standstill, |a| < 0.3 m/s² cruise, else accelerate or brake). A run of fewer than MIN_RUN_ROWS consecutive
rows of one phase between two runs of one other phase (noise on a) takes that phase. A maneuver is one event: a run
of rows of one phase; two runs of accelerate (or brake) with nothing but cruise between them, for less than
MERGE_GAP_S (a gear change, an ABS cycle), are one event. Standstill, and events of fewer than MIN_MANEUVER_ROWS
rows or without any defined slip, make none. Its title gives the speed range in km/h rounded to 5 (e.g.
"accelerate 0–60 km/h").

Online, an event is closed (`closed_events`) once no later row can change its rows: a run of at least MIN_RUN_ROWS
rows of another phase follows it, and, when that phase is cruise, MERGE_GAP_S have passed since its last row with
nothing but cruise, or another event follows that cruise (no run of its own phase can join it any more: a noise
row of the other phase inside a short cruise must not keep it open, and every later one, for the rest of the run).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

PHASES: tuple[str, ...] = ("accelerate", "cruise", "brake")
"""Phases that make a maneuver, in report order (standstill has no slip)."""
MIN_RUN_ROWS = 3
"""A run of fewer consecutive rows of one phase between two runs of another phase (noise on a) takes that phase."""
MIN_MANEUVER_ROWS = 5
"""An event with fewer rows (after debouncing) makes no maneuver."""
MERGE_GAP_S = 2.0
"""Two runs of one phase with only cruise between them, for less than this, are one event."""


def events(phases: Sequence[str | None], times_s: Sequence[float]) -> list[tuple[str | None, list[int]]]:
    """The rows (indices) of each event in time order: runs of one phase, two runs of a phase with only a short
    cruise between them joined (the cruise rows between belong to neither)."""
    runs: list[tuple[str | None, list[int]]] = []
    for i, p in enumerate(phases):
        if runs and runs[-1][0] == p:
            runs[-1][1].append(i)
        else:
            runs.append((p, [i]))
    out: list[tuple[str | None, list[int]]] = []
    for p, rows in runs:
        if p in ("accelerate", "brake") and len(out) >= 2 and out[-2][0] == p and out[-1][0] == "cruise" \
                and times_s[rows[0]] - times_s[out[-2][1][-1]] < MERGE_GAP_S:
            out.pop()
            out[-1][1].extend(rows)
            continue
        out.append((p, list(rows)))
    return out


def debounce(phases: Sequence[str | None], min_run: int = MIN_RUN_ROWS) -> list[str | None]:
    """A run of fewer than min_run rows between two runs of one same phase takes that phase (a spike of noise)."""
    runs: list[list[Any]] = []  # [phase, length]
    for p in phases:
        if runs and runs[-1][0] == p:
            runs[-1][1] += 1
        else:
            runs.append([p, 1])
    for i in range(1, len(runs) - 1):
        if runs[i][1] < min_run and runs[i - 1][0] == runs[i + 1][0] and runs[i - 1][0] is not None:
            runs[i][0] = runs[i - 1][0]
    return [p for p, n in runs for _ in range(n)]


def close_events(phases: Sequence[str | None], times_s: Sequence[float], final: bool = False
                 ) -> tuple[list[tuple[str | None, list[int]]], int]:
    """The events of the rows so far (debounced), and how many of the first of them no later row can change
    (module docstring); final: no row comes after these (every event is closed)."""
    found = events(debounce(phases), times_s)
    if final:
        return found, len(found)
    closed = 0
    for k in range(len(found) - 1):
        p, rows = found[k]
        sealed = False
        for j in range(k + 1, len(found)):
            q, rq = found[j]
            if len(rq) < MIN_RUN_ROWS:
                continue
            if q != "cruise" or p not in ("accelerate", "brake"):
                sealed = True
            elif times_s[rq[-1]] - times_s[rows[-1]] >= MERGE_GAP_S:
                sealed = True
            else:  # a short cruise: sealed once an event that no row can change follows it (it joined none)
                sealed = _final(found, j + 1)
            break
        if not sealed:
            break
        closed = k + 1
    return found, closed


def _final(found: Sequence[tuple[str | None, list[int]]], k: int) -> bool:
    """Event k exists and no later row changes its phase: only the last run can still be debounced, and a run of
    MIN_RUN_ROWS rows never is."""
    return k < len(found) - 1 or (k == len(found) - 1 and len(found[k][1]) >= MIN_RUN_ROWS)


def _round5(v_mps: float) -> int:
    return int(5 * round(v_mps * 3.6 / 5))


def maneuver_title(phase: str, speeds_mps: Sequence[float]) -> tuple[str, float, float]:
    """('accelerate 0–60 km/h', from, to) with from/to in km/h (rounded to 5 in the title)."""
    lo, hi = min(speeds_mps), max(speeds_mps)
    if phase == "accelerate":
        a, b = lo, hi
    elif phase == "brake":
        a, b = hi, lo
    else:
        m = statistics.median(speeds_mps)
        return f"{phase} {_round5(m)} km/h", lo * 3.6, hi * 3.6
    return f"{phase} {_round5(a)}–{_round5(b)} km/h", a * 3.6, b * 3.6
