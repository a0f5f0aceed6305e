"""The tire files of a report or an export: one MF 6.1 `.tir` per tire and label group (tire_model/files.py), from
every accelerate and brake maneuver of the group's logs, with the vehicle and tire of its first log's config."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from slipdaq import WHEELS
from slipdaq.config import Config
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


def tire_results(logs: Sequence[LogSummary]) -> list[GroupTires]:
    """Per label group (in the logs' order): each wheel's tire file, or why it has none."""
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
        out.append(GroupTires(group, folder, [build_tire(w, pairs, cfg.vehicle, cfg.tire, group=group,
                                                         sample_period_s=period) for w in WHEELS]))
    return out


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
