"""The report's numbers: estimate rows of a log in, dataclasses out. Pure (no I/O, no plotting).

Maneuvers are decided by the same detector as live (maneuver.detector) over the log's rows, so the report lists
the maneuvers the log's /maneuver records gave, with the same figures (maneuver/: events, figures, linearity,
mu_slip, brake_test); the report adds cruise maneuvers, numbers them per phase ("#1", "#2", ... in time order when a
log has several of one phase; `key`: the phase, or "accelerate-2", ..., names its plots), and takes the lost frames
(per wheel) and bad sentences from the last `/diagnostics`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from slipdaq import WHEELS
from slipdaq.config import Config, ConfigError, TestConfig, parse_logged_config
from slipdaq.maneuver import fallback
from slipdaq.maneuver.brake_test import BrakeFigures
from slipdaq.maneuver.detector import ManeuverDetector, TimeOrderFeed
from slipdaq.maneuver.events import PHASES
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.maneuver.linearity import LinearityRule
from slipdaq.maneuver.record import Z95, Maneuver, determined, maneuver_record
from slipdaq.maneuver.test_set import sets_of
from slipdaq.records.fast_rows import FastRows, FastSlipBatch
from slipdaq.report.labels import format_labels


@dataclass(frozen=True)
class LogSummary:
    path: str
    name: str
    labels: dict[str, str]
    group: str
    mode: str
    estimates: int
    t0_s: float | None
    """Time of the first estimate (the log's clock); plot times are relative to it."""
    lost_frames: dict[str, int]
    bad_sentences: int | None
    maneuvers: list[ManeuverSummary]
    """In report order: by phase (PHASES), then time."""
    records: list[Maneuver] = dataclasses.field(default_factory=list)
    """The accelerate and brake maneuvers as their /maneuver records, in time order."""
    config: Config | None = None
    """The config the log was recorded with (None: none this version reads)."""
    test: TestConfig = dataclasses.field(default_factory=TestConfig)
    """The log's [test]: its procedures."""
    test_sets: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    """The last /test_set record of each of its procedures' sets (maneuver.test_set)."""

    @property
    def title(self) -> str:
        lab = format_labels(self.labels)
        return f"{self.name} ({lab})" if lab else self.name


def group_of(labels: dict[str, str], group_by: Sequence[str] | None = None) -> str:
    """The comparison group of a log: its labels on the group_by keys (default: every key but `maneuver`)."""
    keys = list(group_by) if group_by else [k for k in labels if k != "maneuver"]
    parts = [f"{k}={labels.get(k, '–')}" for k in keys if group_by or k in labels]
    return ", ".join(parts) if parts else "(no labels)"


def log_config(metadata: dict[str, str]) -> Config | None:
    """The config a log was recorded with (config.py's models and defaults); None without one or with one this
    version cannot read."""
    text = metadata.get("config_toml")
    if not text:
        return None
    try:
        return parse_logged_config(text)
    except ConfigError:
        return None


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def detect_maneuvers(
    rows: Sequence[dict[str, Any]], cfg: Config | None, *, phases: Sequence[str | None] | None = None,
    fast: Sequence[dict[str, Any]] = (), sensors: Sequence[dict[str, Any]] = (),
    rule: LinearityRule | None = None, lost_frames: dict[str, int] | None = None,
) -> list[ManeuverSummary]:
    """The log's maneuvers (every phase of PHASES) in the order the detector decides them: its rows, high-rate
    rows and brake samples fed as the pipeline feeds them, in time order."""
    det = ManeuverDetector(cfg, phases=PHASES, rule=rule, lost_frames=lost_frames)
    for d in sensors:
        det.add_sensor_row(d)
    feed = TimeOrderFeed(det)
    chunks = _fast_chunks(fast)
    fast_to_s = -math.inf
    out: list[ManeuverSummary] = []
    for i, row in enumerate(rows):  # each maneuver summarized as it is decided, its data let go
        while fast_to_s <= row["time_s"] and (chunk := next(chunks, None)) is not None:
            feed.fast(chunk)  # the high-rate rows up to past this row: those before it go first
            fast_to_s = chunk.time_s[-1]
        out += [job() for job in feed.take(row["time_s"])]
        feed.estimate(row, None if phases is None else phases[i])
    for chunk in chunks:
        feed.fast(chunk)
    return out + [job() for job in feed.take(final=True)] + [job() for job in det.finish()]


def _fast_chunks(fast: Sequence[dict[str, Any]]) -> Iterator[FastSlipBatch]:
    """High-rate rows (a run's columns, or a log's rows as dicts) as batches of FastRows.CHUNK rows."""
    step = FastRows.CHUNK
    if isinstance(fast, FastRows):
        columns = fast.columns()
        for start in range(0, len(columns), step):
            yield columns.batch(start, start + step)
    else:
        for start in range(0, len(fast), step):
            yield FastSlipBatch.of_dicts(fast[start:start + step])


def summarize_log(
    rows: Sequence[dict[str, Any]],
    metadata: dict[str, str],
    diagnostics: dict[str, Any] | None,
    *,
    path: str,
    name: str,
    labels: dict[str, str],
    group_by: Sequence[str] | None = None,
    rule: LinearityRule | None = None,
    fast: Sequence[dict[str, Any]] = (),
    sensors: Sequence[dict[str, Any]] = (),
    found: Sequence[ManeuverSummary] | None = None,
) -> LogSummary:
    """Every maneuver of one log, per wheel; fast: its /slip/fast rows, sensors: its /can/sensors samples (the
    brake signal), both in time order; found: its maneuvers as detect_maneuvers gives them, decided already (beside
    the replay that made the rows, offline.summaries.DetectorFeed: the lost frames filled in here)."""
    cfg = log_config(metadata)
    diag = diagnostics or {}
    lost = {w: int(v) for w, v in (diag.get("lost_frames") or {}).items()}
    have_phase = any(r.get("phase") is not None for r in rows)
    if found is not None and have_phase and rule is None:
        found = [dataclasses.replace(m, wheels={w: dataclasses.replace(s, lost_frames=lost.get(w))
                                                for w, s in m.wheels.items()}) for m in found]
    else:
        found = detect_maneuvers(rows, cfg, phases=None if have_phase else fallback.derive_phases(rows), fast=fast,
                                 sensors=sensors, rule=rule, lost_frames=lost)
    test = cfg.test if cfg is not None else TestConfig()
    records = [maneuver_record(m, k, test, WHEELS)
               for k, m in enumerate((m for m in found if m.phase != "cruise"), start=1)]
    maneuvers: list[ManeuverSummary] = []
    for phase in PHASES:
        kept = [m for m in found if m.phase == phase]
        for k, m in enumerate(kept, start=1):
            maneuvers.append(dataclasses.replace(m, title=f"{m.title} #{k}", key=f"{phase}-{k}") if len(kept) > 1
                             else m)
    return LogSummary(
        path=path, name=name, labels=dict(labels), group=group_of(labels, group_by),
        mode=metadata.get("mode", ""), estimates=len(rows), t0_s=rows[0]["time_s"] if rows else None,
        lost_frames=lost, bad_sentences=diag.get("bad_sentences"), maneuvers=maneuvers, records=records, config=cfg,
        test=test, test_sets=sets_of(test, records),
    )


# ---- the table (summary.csv / summary.json) ----------------------------------------------------------------

COLUMNS: tuple[str, ...] = (
    "log", "labels", "group", "maneuver", "phase", "wheel", "t_start_s", "t_end_s", "speed_from_kmh",
    "speed_to_kmh", "slip_samples", "mean_slip", "max_abs_slip", "linearity", "linear_end_slip",
    "linear_end_fx_n", "peak_linear_fx_n", "peak_linear_fx_slip", "cx_line_n", "cx_line_points", "cx_line_method",
    "cx_line_slip_offset", "mean_re_m",
    "r0_m", "peak_cx_n", "peak_cx_slip", "cx_fit_n", "cx_fit_conf", "cx_fit_source", "gps_latency_s",
    "gps_latency_source", "lost_frames", "bad_sentences", "mu_peak", "slip_at_mu_peak", "mu_slip_model",
    "brake_speed_kmh", "stopping_distance_m", "stopping_distance_corrected_m", "mfdd_mps2", "abs_cycles",
    "abs_frequency_hz", "mu_slip_method", "mu_flag", "mu_peak_lo", "mu_peak_hi", "slip_at_mu_peak_lo",
    "slip_at_mu_peak_hi", "cx_line_n_lo", "cx_line_n_hi", "stopping_distance_m_lo", "stopping_distance_m_hi",
    "mfdd_mps2_lo", "mfdd_mps2_hi",
)
"""One row per log, maneuver and wheel. Slips are fractions, forces N, radii m, stiffness N per unit slip."""


BRAKE_COLUMNS = ("brake_speed_kmh", "stopping_distance_m", "stopping_distance_corrected_m", "mfdd_mps2", "abs_cycles",
                 "abs_frequency_hz", "stopping_distance_m_lo", "stopping_distance_m_hi", "mfdd_mps2_lo", "mfdd_mps2_hi")


def brake_columns(b: BrakeFigures | None) -> dict[str, Any]:
    """The brake-test figures of a maneuver by their column names (None each without; a figure whose interval is
    wider than itself: None, not determined)."""
    out = {c: getattr(b, c) if b is not None else None for c in BRAKE_COLUMNS}
    if b is not None:
        out["stopping_distance_m"] = determined(b.stopping_distance_m, b.stopping_distance_m_lo,
                                                b.stopping_distance_m_hi)
        out["mfdd_mps2"] = determined(b.mfdd_mps2, b.mfdd_mps2_lo, b.mfdd_mps2_hi)
    return out


def table_rows(logs: Sequence[LogSummary]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for log in logs:
        for m in log.maneuvers:
            for w, ws in m.wheels.items():
                lin = ws.linearity
                out.append({
                    "log": log.name, "labels": format_labels(log.labels), "group": log.group,
                    "maneuver": m.title, "phase": m.phase, "wheel": w,
                    "t_start_s": m.t_start_s, "t_end_s": m.t_end_s,
                    "speed_from_kmh": m.speed_from_kmh, "speed_to_kmh": m.speed_to_kmh,
                    "slip_samples": ws.slip_samples, "mean_slip": ws.mean_slip, "max_abs_slip": ws.max_abs_slip,
                    "linearity": lin.verdict, "linear_end_slip": lin.end_slip, "linear_end_fx_n": lin.end_force_n,
                    "peak_linear_fx_n": lin.peak_fx_n, "peak_linear_fx_slip": lin.peak_fx_slip,
                    "cx_line_n": determined(lin.line.cx_n, lin.line.cx_n - Z95 * lin.line.stderr_n,
                                            lin.line.cx_n + Z95 * lin.line.stderr_n) if lin.line else None,
                    "cx_line_n_lo": lin.line.cx_n - Z95 * lin.line.stderr_n if lin.line else None,
                    "cx_line_n_hi": lin.line.cx_n + Z95 * lin.line.stderr_n if lin.line else None,
                    "cx_line_points": lin.line.points if lin.line else 0,
                    "cx_line_method": lin.line.method if lin.line else None,
                    "cx_line_slip_offset": lin.line.slip_offset if lin.line else None,
                    "mean_re_m": ws.mean_re_m, "r0_m": ws.r0_m,
                    "peak_cx_n": ws.peak_cx_n, "peak_cx_slip": ws.peak_cx_slip,
                    "cx_fit_n": ws.cx_fit_n, "cx_fit_conf": ws.cx_fit_conf, "cx_fit_source": ws.cx_fit_source,
                    "gps_latency_s": m.gps_latency_s, "gps_latency_source": m.gps_latency_source,
                    "lost_frames": ws.lost_frames, "bad_sentences": log.bad_sentences,
                    "mu_peak": ws.mu_slip.mu_peak if ws.mu_slip else None,
                    "slip_at_mu_peak": ws.mu_slip.slip_at_mu_peak if ws.mu_slip else None,
                    "mu_slip_model": ws.mu_slip.model if ws.mu_slip else None,
                    "mu_slip_method": ws.mu_slip.method if ws.mu_slip else None,
                    "mu_flag": ws.mu_slip.flag if ws.mu_slip else None,
                    "mu_peak_lo": ws.mu_slip.mu_peak_lo if ws.mu_slip else None,
                    "mu_peak_hi": ws.mu_slip.mu_peak_hi if ws.mu_slip else None,
                    "slip_at_mu_peak_lo": ws.mu_slip.slip_at_mu_peak_lo if ws.mu_slip else None,
                    "slip_at_mu_peak_hi": ws.mu_slip.slip_at_mu_peak_hi if ws.mu_slip else None,
                } | brake_columns(m.brake))
    return out


# ---- comparison across logs, grouped by labels -------------------------------------------------------------

@dataclass(frozen=True)
class GroupWheel:
    cx_fit_n: float | None
    """Mean over the group's logs."""
    peak_linear_fx_n: float | None
    """Of largest |Fx| over the group's logs."""
    peak_linear_fx_slip: float | None
    linear_end_slip: float | None
    """Smallest |end| over the logs; None: linear throughout in every log."""
    mean_re_m: float | None


@dataclass(frozen=True)
class GroupSummary:
    group: str
    logs: tuple[str, ...]
    titles: tuple[str, ...]
    wheels: dict[str, GroupWheel]


@dataclass(frozen=True)
class Comparison:
    phase: str
    groups: list[GroupSummary]


def compare(logs: Sequence[LogSummary]) -> list[Comparison]:
    """Per phase, the groups (by label) side by side, each aggregated over its logs."""
    out: list[Comparison] = []
    groups = list(dict.fromkeys(log.group for log in logs))
    for phase in PHASES:
        gs: list[GroupSummary] = []
        for g in groups:
            ms = [(log, m) for log in logs if log.group == g for m in log.maneuvers if m.phase == phase]
            if not ms:
                continue
            wheels: dict[str, GroupWheel] = {}
            for w in WHEELS:
                ws = [m.wheels[w] for _, m in ms]
                peaks = [x.linearity for x in ws if x.linearity.peak_fx_n is not None]
                peak = max(peaks, key=lambda lin: abs(lin.peak_fx_n or 0.0), default=None)
                ends = [x.linearity.end_slip for x in ws if x.linearity.end_slip is not None]
                wheels[w] = GroupWheel(
                    cx_fit_n=_mean([x.cx_fit_n for x in ws if x.cx_fit_n is not None]),
                    peak_linear_fx_n=peak.peak_fx_n if peak else None,
                    peak_linear_fx_slip=peak.peak_fx_slip if peak else None,
                    linear_end_slip=min(ends, key=abs) if ends else None,
                    mean_re_m=_mean([x.mean_re_m for x in ws if x.mean_re_m is not None]),
                )
            gs.append(GroupSummary(g, tuple(log.name for log, _ in ms), tuple(m.title for _, m in ms), wheels))
        if gs:
            out.append(Comparison(phase, gs))
    return out
