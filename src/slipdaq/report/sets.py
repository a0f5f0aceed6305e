"""The report's test sets per label group and the differences between groups. Pure: log summaries in, records out.

A group's sets: its logs' /maneuver records, log after log, fed to one TestSets (maneuver.test_set) with the
procedures of its logs' configs (the first log that names a procedure defines it): a test day of several runs of
`slipdaq run` is one set.

Differences (each pair of groups, in the order the groups come): for each figure of a set (its counted runs) and
for each per-maneuver figure of every valid maneuver of a kind (per tire: cx_line_n, mu_peak, mean_slip; brake:
mfdd_mps2, stopping_distance_corrected_m), each group's mean with its 95 % Student-t interval and the difference of
the means with its 95 % Welch interval (stats.welch_difference).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from slipdaq import WHEELS
from slipdaq.config import TestConfig
from slipdaq.maneuver.record import Maneuver
from slipdaq.maneuver.stats import mean_interval, welch_difference
from slipdaq.maneuver.test_set import KIND_FIGURES, WHEEL_FIGURES, TestSets
from slipdaq.report.summary import LogSummary

MANEUVER_FIGURES: dict[str, tuple[str, ...]] = {"brake": ("mfdd_mps2", "stopping_distance_corrected_m"),
                                                "accelerate": ()}
"""The per-maneuver figures compared besides the tires' (WHEEL_FIGURES)."""
DIFFERENCE_KEYS = ("figure", "wheel", "kind", "label", "group_a", "group_b", "n_a", "n_b", "mean_a", "mean_b",
                   "difference", "ci_lo", "ci_hi")
"""summary.json's `differences`: these keys first, then procedure (the set's name; null: the maneuvers of the
kind), mean_a_ci, mean_b_ci ([lo, hi]: each group's 95 % interval) and excludes_zero."""


@dataclass(frozen=True)
class GroupSets:
    group: str
    logs: tuple[str, ...]
    sets: TestSets
    records: tuple[Maneuver, ...]


def group_sets(logs: Sequence[LogSummary]) -> list[GroupSets]:
    """Per label group (in the order they come), its test sets over its logs and its maneuver records."""
    out: list[GroupSets] = []
    for g in dict.fromkeys(log.group for log in logs):
        members = [log for log in logs if log.group == g]
        procs = {p.name: p for log in reversed(members) for p in log.test.procedure}
        first = members[0].test
        sets = TestSets(TestConfig(target_speeds_kmh=first.target_speeds_kmh,
                                   speed_tolerance_kmh=first.speed_tolerance_kmh, procedure=list(procs.values())))
        records = tuple(r for log in members for r in log.records)
        for r in records:
            sets.add(r)
        out.append(GroupSets(g, tuple(log.name for log in members), sets, records))
    return out


def _label(group_a: str, group_b: str) -> str:
    keys = [p.split("=", 1)[0] for p in f"{group_a}, {group_b}".split(", ") if "=" in p]
    return ", ".join(dict.fromkeys(keys))


def _values(gs: GroupSets, procedure: str | None, kind: str, figure: str, wheel: str | None) -> list[float]:
    name = f"{figure}_{wheel}" if wheel else figure
    if procedure is not None:
        s = gs.sets.sets.get(procedure)
        return [v for _, figs in (s.runs if s else []) if (v := figs.get(name)) is not None]
    out = []
    for r in gs.records:
        if r.kind != kind or not r.valid:
            continue
        v = getattr(r.wheels[wheel], figure) if wheel and wheel in r.wheels else None if wheel else getattr(r, figure)
        if v is not None:
            out.append(float(v))
    return out


def _figures(groups: Sequence[GroupSets]) -> list[tuple[str | None, str, str, str | None]]:
    """(procedure or None, kind, figure, wheel) to compare."""
    out: list[tuple[str | None, str, str, str | None]] = []
    names = dict.fromkeys(n for gs in groups for n in gs.sets.touched)
    for name in names:
        kind = next(gs.sets.sets[name].procedure.kind for gs in groups if name in gs.sets.sets)
        out += [(name, kind, f, None) for f in KIND_FIGURES[kind]]
        out += [(name, kind, f, w) for f in WHEEL_FIGURES for w in WHEELS]
    for k, figs in MANEUVER_FIGURES.items():
        out += [(None, k, f, None) for f in figs]
        out += [(None, k, f, w) for f in WHEEL_FIGURES for w in WHEELS]
    return out


def differences(groups: Sequence[GroupSets]) -> list[dict[str, Any]]:
    """summary.json's `differences` (DIFFERENCE_KEYS): every figure both groups of a pair have."""
    out: list[dict[str, Any]] = []
    figures = _figures(groups)
    for i, a in enumerate(groups):
        for b in groups[i + 1:]:
            for proc, kind, fig, wheel in figures:
                va, vb = _values(a, proc, kind, fig, wheel), _values(b, proc, kind, fig, wheel)
                d = welch_difference(va, vb)
                if d is None:
                    continue
                ia, ib = mean_interval(va), mean_interval(vb)
                out.append({
                    "figure": fig, "wheel": wheel, "kind": kind, "label": _label(a.group, b.group),
                    "group_a": a.group, "group_b": b.group, "n_a": d.n_a, "n_b": d.n_b, "mean_a": d.mean_a,
                    "mean_b": d.mean_b, "difference": d.difference, "ci_lo": d.ci_lo, "ci_hi": d.ci_hi,
                    "procedure": proc, "mean_a_ci": [ia.ci_lo, ia.ci_hi], "mean_b_ci": [ib.ci_lo, ib.ci_hi],
                    "excludes_zero": d.excludes_zero,
                })
    return out
