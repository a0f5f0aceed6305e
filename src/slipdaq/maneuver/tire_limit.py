"""Each tire's mu–slip curve over one maneuver, by the method that explains the force: the hydraulic split or the joint
fit over every wheel at once (mu_joint.py), and the flags that keep an implausible or undetermined peak from being
given as a result. Pure: arrays in, dataclasses out.

Method
    1. Hydraulic split: each tire's force is M·a split as the estimator splits it (the driven wheels; braking,
       brake_front_share), mu = Fx/Fz, one Burckhardt curve per wheel (mu_slip.fit_mu_slip). Right while every tire
       stays on the stable branch (the split is the brake's), wrong when a tire at its limit carries mu(s)·Fz
       whatever the hydraulics ask.
    2. Joint fit (mu_joint.fit_joint) over the samples where every wheel's slip is defined, when some tire may be at
       its limit (LIMIT_SLIP).
    3. Each explains the total force over those samples: the hydraulic curves by Σ_w mu_w(s_w)·Fz_w (a wheel without
       a curve: its split force), the joint one by its own model. The one with the smaller sum of squared force
       residuals is taken (`method`). A joint fit without an observed peak is not taken (its curve then says no more
       than the split does), nor one whose every peak is not determined where the split gives one.
    The joint fit's per-wheel points for the plot: the total force split in proportion to each tire's fitted
    mu(s_w)·Fz_w, over Fz_w.
Flags (`flag`, mu_flag in the tables): a peak above mu_max ('mu above 1.5'), or hydraulic points above mu_max in more
than SPLIT_EXCESS_SHARE of them ('split exceeds the load'), or a 95 % interval wider than the value, or none (most
bootstrap resamples find no peak: mu_slip.peak_interval, mu_joint's) ('not determined'): mu_peak and slip_at_mu_peak
are then None; a curve whose points never passed its peak: 'peak not
passed'.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import VehicleConfig
from slipdaq.estimator.force import tire_forces
from slipdaq.maneuver.mu_joint import JointFit, fit_joint, force_lag_s
from slipdaq.maneuver.mu_slip import (
    MuSlipFit,
    block_samples,
    fit_mu_slip,
    mu_from_force,
    normal_loads_n,
    peak_interval,
)

MU_MIN_SPEED_MPS = 3.0
"""The mu-slip fits take high-rate rows from this speed on: below it a count's quantisation is a large slip, and
ABS hands over to locked wheels (2 m/s) before the stop."""
SPLIT_EXCESS_SHARE = 0.05
LIMIT_SLIP = 0.08
"""The joint fit is tried only when some wheel's |slip| exceeds this in 20 samples or more, or the split's curves
see a peak or exceed mu_max: a maneuver whose tires all stay well inside their linear region keeps the split."""


@dataclasses.dataclass(frozen=True)
class TireCurves:
    fits: dict[str, MuSlipFit | None]
    points: dict[str, tuple[np.ndarray, np.ndarray]]
    """Per wheel: (slip, mu) of the points behind its curve."""
    method: str
    joint: JointFit | None = None
    lag_s: float = 0.0
    """How far the force was found to lag the slips (mu_joint.force_lag_s); the curves take it aligned."""
    loads: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    """Per wheel: the normal load Fz (N) of each of its points."""


def _interval_too_wide(value: float | None, lo: float | None, hi: float | None) -> bool:
    return value is not None and lo is not None and hi is not None and hi - lo > abs(value)


def flagged(fit: MuSlipFit, mu_max: float, split_excess: bool = False) -> MuSlipFit:
    """The fit with its flag set and, where flagged, its peak taken away (module docstring)."""
    flag = None
    if fit.mu_peak is not None and fit.mu_peak > mu_max:
        flag = f"mu above {mu_max:g}"
    elif split_excess:
        flag = "split exceeds the load"
    elif _interval_too_wide(fit.mu_peak, fit.mu_peak_lo, fit.mu_peak_hi) or \
            _interval_too_wide(fit.slip_at_mu_peak, fit.slip_at_mu_peak_lo, fit.slip_at_mu_peak_hi) or \
            (fit.mu_peak is not None and fit.mu_peak_lo is None):  # most resamples found no peak
        flag = "not determined"
    elif fit.mu_peak is None:
        flag = "peak not passed"
    if flag is None:
        return fit
    gone = flag != "peak not passed"
    return dataclasses.replace(fit, flag=flag, mu_peak=None if gone else fit.mu_peak,
                               slip_at_mu_peak=None if gone else fit.slip_at_mu_peak)


def _usable(v: np.ndarray, a: np.ndarray, slips: Mapping[str, np.ndarray], sign: float) -> np.ndarray:
    """The samples where the maneuver's force acts, above MU_MIN_SPEED_MPS, every wheel's slip defined."""
    return (a * sign > 0) & (v >= MU_MIN_SPEED_MPS) & np.logical_and.reduce([np.isfinite(slips[w]) for w in WHEELS])


def _near_limit(every: np.ndarray, slips: Mapping[str, np.ndarray]) -> int:
    """How many of those samples have some wheel's |slip| above LIMIT_SLIP."""
    return int(np.count_nonzero(np.max(np.abs(np.array([slips[w][every] for w in WHEELS])), axis=0) > LIMIT_SLIP))


def tire_curves(v: np.ndarray, a: np.ndarray, slips: Mapping[str, np.ndarray], vehicle: VehicleConfig,
                sign: float, mu_max: float, time_s: np.ndarray | None = None) -> TireCurves:
    """Each wheel's curve over a maneuver's high-rate samples (v, a, slips per wheel; sign −1 braking). Where some
    tire nears its limit, the acceleration is first aligned with the slips by the force's delay behind them
    (mu_joint.force_lag_s), `lag_s` in the result."""
    lag = 0.0
    every = _usable(v, a, slips, sign)
    if time_s is not None and every.sum() >= 20 and _near_limit(every, slips) >= 20:
        fz = {w: normal_loads_n(w, a[every], vehicle.mass_kg, vehicle.front_axle_load_share, vehicle.cg_height_m,
                                vehicle.wheelbase_m) for w in WHEELS}
        lag = force_lag_s(time_s[every], {w: slips[w][every] for w in WHEELS}, fz, vehicle.mass_kg * a[every], sign)
        if lag:
            a = np.interp(time_s + lag, time_s, a)
    return dataclasses.replace(_curves(v, a, slips, vehicle, sign, mu_max, time_s), lag_s=lag)


def _curves(v: np.ndarray, a: np.ndarray, slips: Mapping[str, np.ndarray], vehicle: VehicleConfig,
            sign: float, mu_max: float, time_s: np.ndarray | None) -> TireCurves:
    mass = vehicle.mass_kg
    block = block_samples(time_s)
    split = [tire_forces(mass * x, vehicle.driven_axle, vehicle.brake_front_share) for x in a]
    fz = {w: normal_loads_n(w, a, mass, vehicle.front_axle_load_share, vehicle.cg_height_m, vehicle.wheelbase_m)
          for w in WHEELS}
    moving = (a * sign > 0) & (v >= MU_MIN_SPEED_MPS)
    hyd: dict[str, MuSlipFit | None] = {}
    points: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    loads: dict[str, np.ndarray] = {}
    split_fx: dict[str, np.ndarray] = {}
    excess: dict[str, bool] = {}
    for w in WHEELS:
        fx = split_fx[w] = np.array([f[w] for f in split])
        mu = mu_from_force(fx, fz[w])
        use = np.isfinite(slips[w]) & np.isfinite(mu) & moving
        points[w] = (slips[w][use], mu[use])
        loads[w] = fz[w][use]
        fit = fit_mu_slip(slips[w][use], mu[use]) if use.sum() else None
        if fit is not None and fit.mu_peak is not None:  # its 95 % interval (mu_slip.peak_interval)
            lo_hi = peak_interval(slips[w][use], mu[use], block)
            fit = dataclasses.replace(fit, mu_peak_lo=lo_hi[0], mu_peak_hi=lo_hi[1], slip_at_mu_peak_lo=lo_hi[2],
                                      slip_at_mu_peak_hi=lo_hi[3])
        hyd[w] = fit
        excess[w] = bool(use.sum()) and float(np.mean(np.abs(mu[use]) > mu_max)) > SPLIT_EXCESS_SHARE
    hydraulic = TireCurves({w: None if f is None else flagged(f, mu_max, excess[w]) for w, f in hyd.items()},
                           points, "hydraulic split", loads=loads)
    every = _usable(v, a, slips, sign)
    if int(every.sum()) < 20:
        return hydraulic
    observed = any(f is not None and f.peak_observed for f in hyd.values())
    if _near_limit(every, slips) < 20 and not any(excess.values()) and not observed:
        return hydraulic  # every tire far from its limit: the split is the brake's, no joint fit needed
    t = time_s[every] if time_s is not None else np.arange(int(every.sum())) * 0.01
    s_e = {w: slips[w][every] for w in WHEELS}
    fz_e = {w: fz[w][every] for w in WHEELS}
    force = mass * a[every]
    joint = fit_joint(t, s_e, fz_e, force, sign)
    if joint is None or not any(c.peak_observed for c in joint.curves.values()):
        return hydraulic
    pred_h = np.zeros_like(force)
    pred_j = np.zeros_like(force)
    share = {}
    for w in WHEELS:
        f = hyd[w]
        pred_h += f.mu(s_e[w]) * fz_e[w] if f is not None else split_fx[w][every]
        c = joint.curves.get(w)
        share[w] = np.sign(s_e[w]) * c.mu(np.abs(s_e[w])) * fz_e[w] if c is not None else np.zeros_like(force)
        pred_j += share[w]
    if float(np.sum((force - pred_j) ** 2)) >= float(np.sum((force - pred_h) ** 2)):
        return dataclasses.replace(hydraulic, joint=joint)
    fits: dict[str, MuSlipFit | None] = {}
    joint_points: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    with np.errstate(all="ignore"):
        ratio = np.where(pred_j != 0, force / pred_j, np.nan)
    for w in WHEELS:
        c = joint.curves.get(w)
        if c is None:
            fits[w], joint_points[w] = None, (s_e[w], np.zeros_like(force))
            continue
        joint_points[w] = (s_e[w], share[w] * ratio / fz_e[w])
        b, cc, d = c.params
        fit = MuSlipFit(c1=b, c2=cc, c3=d, mu_peak=c.mu_peak, slip_at_mu_peak=c.slip_at_mu_peak,
                        rms_residual=joint.rms_residual, n_points=joint.n_points, peak_observed=c.peak_observed,
                        slip_sign=sign, max_abs_slip=float(np.max(np.abs(s_e[w]))), model=c.model,
                        method=joint.method, mu_peak_lo=c.mu_peak_lo, mu_peak_hi=c.mu_peak_hi,
                        slip_at_mu_peak_lo=c.slip_at_mu_peak_lo, slip_at_mu_peak_hi=c.slip_at_mu_peak_hi)
        fits[w] = flagged(fit, mu_max)
    undetermined = all(f is None or f.flag == "not determined" for f in fits.values())
    if undetermined and any(f is not None and f.mu_peak is not None for f in hydraulic.fits.values()):
        return dataclasses.replace(hydraulic, joint=joint)  # the split determines a peak the joint fit leaves open
    return TireCurves(fits, joint_points, joint.method, joint, loads=fz_e)
