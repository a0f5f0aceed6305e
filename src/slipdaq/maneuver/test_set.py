"""Test sets: the decided maneuvers collected into the runs of the test's procedures ([[test.procedure]]). Pure: the
one rule for live, replay and the report; its state is bounded (a set keeps at most its required runs and the last
MAX_EXCLUDED exclusions).

Membership: a maneuver of a procedure's kind belongs to the procedure whose target speed is nearest to its run speed
(braking: the speed at the brake onset, else its start; coasting: its start; accelerating: the highest target it
reached within the tolerance, else the nearest to its top speed). It is a run of the set when it is valid and its
speed lies within the tolerance (accelerating: its top speed, coasting: its start speed, at most the tolerance below
the target), and the set does not have its runs yet; else it is excluded, with why. A coast is valid once it is
paired with one in the opposite direction: each valid coast is a pair's road loads.

Per figure over the runs (stats.mean_interval): n, mean, sd, CV and the mean's 95 % Student-t interval. The set is
complete with `runs` valid runs, ok when complete and its main figure's CV is within max_cv_percent.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from slipdaq import WHEELS
from slipdaq.config import PROCEDURE_KINDS, ProcedureConfig, TestConfig
from slipdaq.maneuver.stats import mean_interval
from slipdaq.records.columns import Column, ColumnGroup, column_names

if TYPE_CHECKING:
    from slipdaq.maneuver.record import Maneuver

MAX_EXCLUDED = 100
"""A set lists at most this many excluded runs (the latest)."""
KIND_FIGURES: dict[str, tuple[str, ...]] = {
    "brake": ("stopping_distance_corrected_m", "mfdd_mps2", "brake_speed_kmh"),
    "accelerate": ("time_to_speed_s",),
    "coast": ("road_load_f0_n", "road_load_f1_n_per_mps", "road_load_f2_n_per_mps2"),
}
"""The maneuver's own figures a set of each kind gives statistics of."""
WHEEL_FIGURES = ("mean_slip", "cx_line_n", "mu_peak")
"""... and, per wheel W, these (`mean_slip_W`, ...)."""
MAIN_FIGURE = {"brake": "stopping_distance_corrected_m", "accelerate": "time_to_speed_s", "coast": "road_load_f0_n"}
"""The figure max_cv_percent judges."""
STATS = ("n", "mean", "sd", "cv_percent", "ci_lo", "ci_hi")
ALL_FIGURES = tuple(dict.fromkeys(f for fs in KIND_FIGURES.values() for f in fs))


def run_speed_kmh(kind: str, brake_speed_kmh: float | None, speed_from_kmh: float, speed_to_kmh: float) -> float:
    """The speed a maneuver is matched by (module docstring)."""
    if kind == "brake":
        return brake_speed_kmh if brake_speed_kmh is not None else speed_from_kmh
    return speed_to_kmh if kind == "accelerate" else speed_from_kmh


def procedure_for(test: TestConfig, kind: str, speed_kmh: float) -> ProcedureConfig | None:
    """The procedure a maneuver of this kind and run speed belongs to (module docstring); None: none of its kind."""
    procs = [p for p in test.procedure if p.kind == kind]
    if not procs:
        return None
    if kind == "accelerate":
        reached = [p for p in procs if speed_kmh >= p.target_speed_kmh - test.tolerance_kmh(p)]
        if reached:
            return max(reached, key=lambda p: p.target_speed_kmh)
    return min(procs, key=lambda p: abs(p.target_speed_kmh - speed_kmh))


def mfdd_window_mps(procedure: ProcedureConfig | None) -> tuple[float, float] | None:
    """The procedure's MFDD window (from, to) in m/s; None: ECE R13-H's 0.8·v0 to 0.1·v0."""
    if procedure is None or procedure.mfdd_window_kmh is None:
        return None
    return procedure.mfdd_window_kmh[0] / 3.6, procedure.mfdd_window_kmh[1] / 3.6


def _fmt(v: float) -> str:
    return f"{v:.0f}" if v == round(v) else f"{v:.1f}"


def off_target(kind: str, speed_kmh: float, target_kmh: float, tolerance_kmh: float) -> str | None:
    """Why a run's speed does not count for its procedure; None: it does."""
    if kind in ("accelerate", "coast"):
        if speed_kmh >= target_kmh - tolerance_kmh:
            return None
        what = "top speed" if kind == "accelerate" else "start speed"
        return f"{what} {speed_kmh:.1f} km/h more than {_fmt(tolerance_kmh)} km/h below {_fmt(target_kmh)} km/h"
    if abs(speed_kmh - target_kmh) <= tolerance_kmh:
        return None
    what = "brake speed" if kind == "brake" else "speed"
    return f"{what} {speed_kmh:.1f} km/h not within {_fmt(tolerance_kmh)} km/h of {_fmt(target_kmh)} km/h"


def run_figures(m: Maneuver) -> dict[str, float | None]:
    """A run's figures by their set names (stopping_distance_corrected_m, ..., mean_slip_FL, ...)."""
    out: dict[str, float | None] = {f: getattr(m, f) for f in KIND_FIGURES.get(m.kind, ())}
    for w in WHEELS:
        mw = m.wheels.get(w)
        for f in WHEEL_FIGURES:
            out[f"{f}_{w}"] = getattr(mw, f) if mw is not None else None
    return out


@dataclass
class TestSet:
    """One procedure's set: its runs' figures and its exclusions."""

    procedure: ProcedureConfig
    tolerance_kmh: float
    runs: list[tuple[int, dict[str, float | None]]] = field(default_factory=list)
    excluded: deque[tuple[int, str]] = field(default_factory=lambda: deque(maxlen=MAX_EXCLUDED))

    @property
    def complete(self) -> bool:
        return len(self.runs) >= self.procedure.runs

    def add(self, m: Maneuver) -> None:
        """The maneuver as a run, or excluded with its reasons."""
        p = self.procedure
        speed = run_speed_kmh(m.kind, m.brake_speed_kmh, m.speed_from_kmh, m.speed_to_kmh)
        reasons = [r for r in (off_target(m.kind, speed, p.target_speed_kmh, self.tolerance_kmh),) if r]
        if not m.valid:
            reasons.append("invalid (" + ", ".join(m.invalid_reasons) + ")")
        if not reasons and self.complete:
            reasons.append(f"the set has its {p.runs} runs")
        if reasons:
            self.excluded.append((m.index, ", ".join(reasons)))
        else:
            self.runs.append((m.index, run_figures(m)))

    def record(self) -> dict[str, Any]:
        """The /test_set record (TEST_SET_COLUMNS)."""
        p = self.procedure
        rec: dict[str, Any] = {
            "procedure": p.name, "kind": p.kind, "target_speed_kmh": p.target_speed_kmh,
            "runs_valid": len(self.runs), "runs_required": p.runs, "complete": self.complete, "ok": False,
            "reasons": [], "runs": [i for i, _ in self.runs],
            "excluded": [{"index": i, "reason": r} for i, r in self.excluded],
        }
        names = set(KIND_FIGURES[p.kind]) | {f"{f}_{w}" for f in WHEEL_FIGURES for w in WHEELS}
        for f in ALL_FIGURES + tuple(f"{f}_{w}" for f in WHEEL_FIGURES for w in WHEELS):
            s = mean_interval([v for _, figs in self.runs if (v := figs.get(f)) is not None]) if f in names \
                else None
            for k in STATS:
                rec[f"{f}_{k}"] = (0 if k == "n" else None) if s is None else getattr(s, k)
        reasons: list[str] = []
        if not self.complete:
            reasons.append(f"{len(self.runs)} of {p.runs} valid runs")
        main = MAIN_FIGURE[p.kind]
        cv = rec.get(f"{main}_cv_percent")
        if p.max_cv_percent is not None and self.complete and p.runs > 1 and main in names:
            if cv is None:
                reasons.append(f"CV of {main} not determined")
            elif cv > p.max_cv_percent:
                reasons.append(f"CV of {main} {cv:.1f} % above {_fmt(p.max_cv_percent)} %")
        rec["reasons"], rec["ok"] = reasons, not reasons
        return {c: rec[c] for c in TEST_SET_CSV_COLUMNS}


class TestSets:
    """The test's sets, fed each decided maneuver in order (add)."""

    def __init__(self, test: TestConfig) -> None:
        self.sets = {p.name: TestSet(p, test.tolerance_kmh(p)) for p in test.procedure}
        self.touched: list[str] = []
        """The sets that took a maneuver, in the order they first did."""

    def add(self, m: Maneuver) -> dict[str, Any] | None:
        """Take a maneuver; its set's /test_set record after it, or None (no procedure of its kind)."""
        s = self.sets.get(m.procedure) if m.procedure is not None else None
        if s is None:
            return None
        s.add(m)
        if s.procedure.name not in self.touched:
            self.touched.append(s.procedure.name)
        return s.record()

    def records(self) -> list[dict[str, Any]]:
        """The last record of each set that took a maneuver."""
        return [self.sets[n].record() for n in self.touched]


def sets_of(test: TestConfig, maneuvers: Sequence[Maneuver]) -> list[dict[str, Any]]:
    """The last /test_set record of each set the maneuvers (in order) fill."""
    sets = TestSets(test)
    for m in maneuvers:
        sets.add(m)
    return sets.records()


def excluded_text(excluded: Sequence[dict[str, Any]]) -> list[str]:
    """`3: brake speed 92.0 km/h not within 2 km/h of 100 km/h` for each (joined by '; ' in CSV)."""
    return [f"{e['index']}: {e['reason']}" for e in excluded]


def csv_row(record: dict[str, Any]) -> dict[str, Any]:
    """A /test_set record as its CSV row (`export --sets-csv`): the excluded runs as texts."""
    return record | {"excluded": excluded_text(record.get("excluded") or [])}


def _stats_group(figure: str, per_wheel: bool) -> ColumnGroup:
    name = f"{figure}_{{w}}" if per_wheel else figure
    what = f"{figure} of the {{w}} wheel" if per_wheel else figure
    return ColumnGroup((
        Column(f"{name}_n", f"{name}_n", "integer", description=f"runs with {what} defined"),
        Column(f"{name}_mean", f"{name}_mean", "number?", description=f"mean of {what} over the runs"),
        Column(f"{name}_sd", f"{name}_sd", "number?", description="its sample standard deviation (n - 1)"),
        Column(f"{name}_cv_percent", f"{name}_cv_percent", "number?", description="coefficient of variation, %"),
        Column(f"{name}_ci_lo", f"{name}_ci_lo", "number?", description="the mean's 95 % interval (Student t), "
                                                                        "low end"),
        Column(f"{name}_ci_hi", f"{name}_ci_hi", "number?", description="... high end"),
    ), per_wheel=per_wheel, csv="contract")


TEST_SET_COLUMNS: tuple[ColumnGroup, ...] = (
    ColumnGroup((
        Column("procedure", "procedure", "text", description="the procedure's name ([[test.procedure]] name)"),
        Column("kind", "kind", "enum", PROCEDURE_KINDS, "brake, accelerate or coast"),
        Column("target_speed_kmh", "target_speed_kmh", "number", description="the procedure's target speed"),
        Column("runs_valid", "runs_valid", "integer", description="runs counted"),
        Column("runs_required", "runs_required", "integer", description="runs the set needs"),
        Column("complete", "complete", "bool", description="runs_valid reached runs_required"),
        Column("ok", "ok", "bool", description="complete and the main figure's CV within max_cv_percent"),
        Column("reasons", "reasons", "texts", description="why it is not ok"),
        Column("runs", "runs", "integers", description="the maneuver indices counted"),
        Column("excluded", "excluded", "excluded", description="each run not counted: its index and why (CSV: "
                                                               "'3: reason; 5: reason')"),
    ), per_wheel=False, csv="contract"),
    *(_stats_group(f, False) for f in ALL_FIGURES),
    *(_stats_group(f, True) for f in WHEEL_FIGURES),
)
"""The /test_set record's fields, in the order of its JSON and of `export --sets-csv`."""
TEST_SET_CSV_COLUMNS = column_names(TEST_SET_COLUMNS, WHEELS)
