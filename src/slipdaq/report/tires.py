"""The tire files of a report or an export: one MF 6.1 `.tir` per tire and label group (tire_model/files.py), from
every accelerate and brake maneuver of the group's logs, with the vehicle and tire of its first log's config. Each
file is one TireJob, fitted here (in turn: fit_here; on threads: ThreadFits, `slipdaq report`'s) or, by `slipdaq
batch`, on its cluster (start_tires' `fit`)."""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from slipdaq import WHEELS
from slipdaq.config import Config, TireConfig, VehicleConfig
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.report.summary import LogSummary
from slipdaq.tire_model.files import TireResult, build_tire
from slipdaq.tire_model.tir_file import write_tir

TIRES_DIR = "tires"
"""The report's folder of tire files: tires/<group>/<wheel>.tir."""


@dataclass(frozen=True)
class GroupTires:
    group: str
    folder: str
    """The group's folder name (file-safe)."""
    results: list[TireResult]


def group_folder(group: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=-]+", "_", group).strip("._") or "group"


@dataclass(frozen=True)
class TireJob:
    """One tire file to fit: a wheel of a label group, from the group's maneuvers cut to what its fit reads (that
    wheel's points and loads; no rows): small to send to a worker."""

    wheel: str
    group: str
    maneuvers: tuple[tuple[str, ManeuverSummary], ...]
    """(log name, maneuver) pairs."""
    vehicle: VehicleConfig
    tire: TireConfig
    sample_period_s: float

    @property
    def points(self) -> int:
        """How many slip points it fits (the longest jobs go first)."""
        return sum(len(m.mu_points[self.wheel][0]) for _, m in self.maneuvers if self.wheel in m.mu_points)

    def fit(self) -> TireResult:
        return build_tire(self.wheel, self.maneuvers, self.vehicle, self.tire, group=self.group,
                          sample_period_s=self.sample_period_s)


TireFitter = Callable[[Sequence[TireJob]], Callable[[], Sequence[TireResult]]]
"""Starts fitting the jobs and returns what waits for their results (in the jobs' order)."""


def fit_here(jobs: Sequence[TireJob]) -> Callable[[], Sequence[TireResult]]:
    """TireFitter in this process (when its results are asked for)."""
    return lambda: [j.fit() for j in jobs]


class ThreadFits:
    """TireFitter on threads of this process, one per core (at most one per job), the longest jobs first: a fit is
    numpy's arithmetic over every point of its group (fit.py), which runs without the GIL, so the fits share the
    cores with each other and with what the process does meanwhile. The same results as fit_here (one core, or one
    job: fit_here). As a context: leaving it drops the fits not yet begun (a report that failed meanwhile)."""

    def __init__(self) -> None:
        self.futures: list[Future[TireResult]] = []

    def __call__(self, jobs: Sequence[TireJob]) -> Callable[[], Sequence[TireResult]]:
        cores = os.cpu_count() or 1
        if cores < 2 or len(jobs) < 2:
            return fit_here(jobs)
        pool = ThreadPoolExecutor(max_workers=min(cores, len(jobs)), thread_name_prefix="slipdaq-tire-fit")
        futures: dict[int, Future[TireResult]] = {}
        for i in sorted(range(len(jobs)), key=lambda i: -jobs[i].points):
            futures[i] = pool.submit(jobs[i].fit)
        pool.shutdown(wait=False)  # its threads end with its last job
        self.futures += futures.values()
        return lambda: [futures[i].result() for i in range(len(jobs))]

    def __enter__(self) -> ThreadFits:
        return self

    def __exit__(self, *exc: object) -> None:
        for f in self.futures:
            f.cancel()


def _cut(m: ManeuverSummary, wheel: str) -> ManeuverSummary:
    keep = {k: v for k, v in m.mu_points.items() if k == wheel}
    return dataclasses.replace(m, rows=(), mu_points=keep, mu_loads={k: v for k, v in m.mu_loads.items() if k == wheel},
                               speed_at=(m.speed_at[0][:0], m.speed_at[1][:0]))


def tire_jobs(logs: Sequence[LogSummary]) -> list[tuple[str, str, list[TireJob]]]:
    """Per label group (in the logs' order): the group, its folder and a job per wheel."""
    out = []
    taken: set[str] = set()
    for group in dict.fromkeys(log.group for log in logs):
        members = [log for log in logs if log.group == group]
        cfg = next((log.config for log in members if log.config is not None), None) or Config()
        period = 1.0 / cfg.estimator.fast_rate_hz if cfg.estimator.fast_rate_hz > 0 else 0.01
        pairs = [(log.name, m) for log in members for m in log.maneuvers]
        folder, n = group_folder(group), 2
        while folder in taken:
            folder, n = f"{group_folder(group)}-{n}", n + 1
        taken.add(folder)
        out.append((group, folder, [TireJob(w, group, tuple((name, _cut(m, w)) for name, m in pairs), cfg.vehicle,
                                            cfg.tire, period) for w in WHEELS]))
    return out


def tire_results(logs: Sequence[LogSummary]) -> list[GroupTires]:
    """Per label group (in the logs' order): each wheel's tire file, or why it has none."""
    return start_tires(logs, fit_here)()


def start_tires(logs: Sequence[LogSummary], fit: TireFitter) -> Callable[[], list[GroupTires]]:
    """tire_results with its fits started by `fit`: what waits for them."""
    groups = tire_jobs(logs)
    wait = fit([j for _, _, jobs in groups for j in jobs])

    def results() -> list[GroupTires]:
        done = iter(wait())
        return [GroupTires(group, folder, [next(done) for _ in jobs]) for group, folder, jobs in groups]
    return results


def write_tires(out_dir: Path, groups: Sequence[GroupTires], *, flat: bool = False) -> dict[str, dict[str, str]]:
    """The files under out_dir: <folder>/<wheel>.tir per group (flat: <wheel>.tir, one group); {group: {wheel: path
    relative to out_dir}}."""
    written: dict[str, dict[str, str]] = {}
    for g in groups:
        for r in g.results:
            if r.file is None:
                continue
            rel = f"{r.wheel}.tir" if flat else f"{g.folder}/{r.wheel}.tir"
            (out_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            write_tir(out_dir / rel, r.file)
            written.setdefault(g.group, {})[r.wheel] = rel
    return written
