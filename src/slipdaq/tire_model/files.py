"""One tire's `.tir` from the maneuvers of one or more logs (a label group): its points (slip, Fx = mu·Fz, Fz) from
every accelerate and brake maneuver's mu-slip fit (maneuver/tire_limit.py; a point where the tire carries no force,
a free-rolling wheel under the hydraulic split, left out), the MF 6.1 fit (fit.py), the file's
dimensions (UNLOADED_RADIUS: the calibrated r0 the maneuvers' estimates carried, else the free radius of the tire
config; WIDTH, ASPECT_RATIO, RIM_RADIUS from tire.size) and FNOMIN (the static wheel load, vehicle config), and the
[SLIPDAQ] block. Pure: summaries in, TireFile out.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from slipdaq.config import TireConfig, VehicleConfig
from slipdaq.config.tire_size import parse_tire_size
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.maneuver.mu_slip import normal_loads_n
from slipdaq.maneuver.record import Z95
from slipdaq.tire_model.fit import C_UNSEEN, MF61Fit, fit_mf61
from slipdaq.tire_model.tir_file import TireFile

NOT_FROM_THE_ROAD = {
    "PDX3": "0: camber not measured", "PEX2": "0: not identified from road data",
    "PEX3": "0: not identified from road data", "PKX3": "0: not identified from road data",
    "PHX1": "0: slip offsets are calibrated out (r0)", "PHX2": "0: slip offsets are calibrated out (r0)",
    "PVX1": "0: no force at zero slip by construction (Fx = M·a)", "PVX2": "0: not identified from road data",
}


@dataclass(frozen=True)
class TireResult:
    wheel: str
    file: TireFile | None
    fit: MF61Fit | None
    reason: str = ""
    """Why there is no file (file None)."""


def _fmt_interval(value: float | None, lo: float | None, hi: float | None, scale: float = 1.0, digits: int = 3) -> str:
    if value is None:
        return "none"
    text = f"{value * scale:.{digits}f}"
    return text + (f" [{lo * scale:.{digits}f}, {hi * scale:.{digits}f}]" if lo is not None and hi is not None else "")


def _maneuver_line(log: str, m: ManeuverSummary, wheel: str) -> str:
    f = m.wheels[wheel].mu_slip
    line = m.wheels[wheel].linearity.line
    parts = [f"{log}: {m.title} ({m.t_start_s:.1f}-{m.t_end_s:.1f} s)"]
    if f is not None:
        parts.append(f"{f.method}, mu peak {_fmt_interval(f.mu_peak, f.mu_peak_lo, f.mu_peak_hi)} at slip "
                     f"{_fmt_interval(f.slip_at_mu_peak, f.slip_at_mu_peak_lo, f.slip_at_mu_peak_hi, 100, 1)} %"
                     + (f" ({f.flag})" if f.flag else ""))
    if line is not None:
        parts.append(f"force-slip line Cx {line.cx_n:.0f} N [{line.cx_n - Z95 * line.stderr_n:.0f}, "
                     f"{line.cx_n + Z95 * line.stderr_n:.0f}]")
    return "; ".join(parts)


def static_load_n(wheel: str, vehicle: VehicleConfig) -> float:
    """The wheel's share of M·g at rest (mu_slip.normal_loads_n at a = 0)."""
    return float(normal_loads_n(wheel, 0.0, vehicle.mass_kg, vehicle.front_axle_load_share, vehicle.cg_height_m,
                                vehicle.wheelbase_m))


def build_tire(wheel: str, maneuvers: Sequence[tuple[str, ManeuverSummary]], vehicle: VehicleConfig, tire: TireConfig,
               *, group: str = "", sample_period_s: float = 0.01) -> TireResult:
    """The wheel's tire file from (log name, maneuver) pairs (module docstring); no file without mu-slip points."""
    used = [(log, m) for log, m in maneuvers if m.phase in ("accelerate", "brake") and wheel in m.mu_points
            and wheel in m.mu_loads and len(m.mu_points[wheel][0]) > 0]
    if not used:
        return TireResult(wheel, None, None, "no accelerate or brake maneuver with high-rate slip points")
    slip = np.concatenate([m.mu_points[wheel][0] for _, m in used])
    mu = np.concatenate([m.mu_points[wheel][1] for _, m in used])
    fz = np.concatenate([m.mu_loads[wheel] for _, m in used])
    carries = mu != 0.0  # a wheel the split gives no force (free rolling under drive) says nothing of its curve
    slip, mu, fz = slip[carries], mu[carries], fz[carries]
    peaks = [m.wheels[wheel].mu_slip for _, m in used]
    seen = [f for f in peaks if f is not None and f.mu_peak is not None and f.slip_at_mu_peak is not None]
    fnomin = static_load_n(wheel, vehicle)
    line_fits = [(m.wheels[wheel].linearity.line, float(np.mean(m.mu_loads[wheel]))) for _, m in used]
    weights = [1.0 / max(ln.stderr_n / f, 1e-9) ** 2 for ln, f in line_fits if ln is not None and ln.cx_n > 0]
    slopes = [ln.cx_n / f for ln, f in line_fits if ln is not None and ln.cx_n > 0]
    cx_per_fz = float(np.average(slopes, weights=weights)) if slopes else None
    fit = fit_mf61(slip, mu * fz, fz, fnomin, sample_period_s=sample_period_s,
                   mu_peak=seen[0].mu_peak if seen else None, slip_at_mu_peak=seen[0].slip_at_mu_peak if seen else None,
                   cx_per_fz=cx_per_fz)
    if fit is None:
        return TireResult(wheel, None, None, f"too few points ({slip.size})")
    r0s = [r for r in (m.wheels[wheel].r0_m for _, m in used) if r is not None]
    r0 = float(statistics.median(r0s)) if r0s else tire.radius_m
    width = aspect = rim = None
    if tire.size:
        w_mm, a_pct, rim_in = parse_tire_size(tire.size)
        width, aspect, rim = w_mm / 1000.0, a_pct / 100.0, rim_in * 25.4 / 2.0 / 1000.0
    notes = dict(NOT_FROM_THE_ROAD)
    if not fit.load_terms:
        notes |= {"PDX2": "0: load dependence not identified (see [SLIPDAQ])",
                  "PKX2": "0: load dependence not identified (see [SLIPDAQ])"}
    if not fit.asymmetry:
        notes["PEX4"] = "0: braking and driving beyond 5 % slip not both measured"
    if "PEX1" not in fit.stderr and fit.peak_passed:
        notes["PEX1"] = "0: the curvature explains the points no better"
    if not fit.peak_passed:
        notes |= {"PCX1": f"held at {C_UNSEEN}: the peak was not passed",
                  "PDX1": "a lower bound: the peak was not passed", "PEX1": "0: the peak was not passed"}
    logs = list(dict.fromkeys(log for log, _ in used))
    lines = [f"tire {wheel}" + (f", label group {group}" if group else "") + f": logs {', '.join(logs)}",
             f"maneuvers used ({len(used)}):"] + [f"  {_maneuver_line(log, m, wheel)}" for log, m in used]
    lines += [f"points: {fit.n_points} (effective {fit.n_effective:.0f}, {0.1:g} s apart), RMS mu residual "
              f"{fit.rms_mu:.3f}",
              f"slip covered: {fit.slip_min:.3f} to {fit.slip_max:.3f} (KPUMIN, KPUMAX: the file holds only there)",
              f"FNOMIN {fnomin:.0f} N: the static wheel load; UNLOADED_RADIUS "
              + ("the calibrated r0 (median of the maneuvers' estimates)" if r0s else "the tire config's free radius "
                 "(no calibrated r0 in the estimates)")]
    if fit.peak_passed:
        mu_pk, s_pk = fit.model.peak(fnomin, -1.0 if fit.slip_min < -fit.slip_max else 1.0)
        lines.append(f"peak passed: Fx0 peak mu {mu_pk / fnomin:.3f} at slip {100 * s_pk:.1f} % (at FNOMIN)")
    else:
        lines.append(f"peak NOT passed: PCX1 held at {C_UNSEEN}, PDX1 a lower bound; outside KPUMIN..KPUMAX the "
                     "curve is an extrapolation")
    lines.append(f"slip stiffness PKX1 from {fit.stiffness_from}"
                 + (f" ({cx_per_fz:.2f} per unit load, the lines' inverse-variance mean)"
                    if fit.stiffness_from != "the points" and cx_per_fz is not None else ""))
    lines.append("fitted coefficients with 95 % intervals: " + "; ".join(
        f"{n} {fit.model.values()[n]:.4g} +- {Z95 * se:.2g}" for n, se in fit.stderr.items()))
    lines.append(fit.load_note)
    lines.append("lateral, aligning, overturning, rolling and combined-slip sections: neutral values, not measured")
    return TireResult(wheel, TireFile(fit.model, unloaded_radius_m=r0, width_m=width, aspect_ratio=aspect,
                                      rim_radius_m=rim, slip_min=math.floor(fit.slip_min * 1e4) / 1e4,
                                      slip_max=math.ceil(fit.slip_max * 1e4) / 1e4,
                                      notes=notes, slipdaq=lines, tyreside="LEFT" if wheel.endswith("L") else "RIGHT"),
                      fit)
