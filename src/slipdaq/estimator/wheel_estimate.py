"""One wheel's slip, Re and Cx over a window, and the window into the wheel's stiffness fit (stiffness.py); or the
window into the fit alone (learn_wheel: a pass that keeps no estimate, the first of a two-pass run)."""

from __future__ import annotations

from collections.abc import Callable

from slipdaq.estimator.linear_region import enters_fit
from slipdaq.estimator.params import EstimatorParams
from slipdaq.estimator.stiffness import StiffnessFit
from slipdaq.estimator.wheel_revolutions import slip_from_distances
from slipdaq.records import WheelEstimate


def wheel_estimate(
    p: EstimatorParams, fit: StiffnessFit, arc: float | None, r0: tuple[float, str], d_gps: float | None,
    force: float | None, speed: float, weight: float = 1.0, slip_nd: float | None = None,
    stored_cx: tuple[float, float] | None = None, spread: Callable[[], float | None] = lambda: None,
) -> WheelEstimate:
    """One wheel's slip, Re, Cx over the window (arc: 2*pi*N; d_gps: the GPS distance); feeds its stiffness fit when
    the window is on the linear region (spread: the wheels' largest slip spread over it, linear_region.py). The fitted Cx
    reported is the run's own, else the stored one."""
    r0_m, r0_source = r0
    cx_fit: float | None
    cx_conf: float | None
    cx_fit, cx_conf = (fit.cx_n, fit.confidence) if fit.cx_n is not None or stored_cx is None else stored_cx
    if arc is None:
        return WheelEstimate(None, None, r0_m, None, force, None, r0_source, None, cx_fit, cx_conf)
    d_wpt = r0_m * arc
    wheel_speed = d_wpt / p.window_s
    slip = learn_wheel(p, fit, arc, r0_m, d_gps, force, speed, weight, spread)
    if slip is None:
        return WheelEstimate(None, None, r0_m, None, force, wheel_speed, r0_source, slip_nd, cx_fit, cx_conf)
    assert d_gps is not None
    re = d_gps / arc
    cx = None
    if force is not None and force != 0 and p.cx_slip_min <= abs(slip) <= p.cx_slip_max and force / slip > 0:
        cx = force / slip
    if fit.cx_n is not None or stored_cx is None:
        cx_fit, cx_conf = fit.cx_n, (fit.confidence if fit.cx_n is not None else None)
    return WheelEstimate(slip, re, r0_m, cx, force, wheel_speed, r0_source, slip_nd, cx_fit, cx_conf)


def learn_wheel(p: EstimatorParams, fit: StiffnessFit, arc: float | None, r0_m: float, d_gps: float | None,
                force: float | None, speed: float, weight: float = 1.0,
                spread: Callable[[], float | None] = lambda: None) -> float | None:
    """The wheel's slip over the window (None where it has none: no arc, too short a GPS distance); the window into
    its stiffness fit where it is on the linear region (linear_region.enters_fit)."""
    if arc is None or d_gps is None or d_gps < p.min_speed_mps * p.window_s or arc <= 0:
        return None
    slip = slip_from_distances(r0_m * arc, d_gps)
    if enters_fit(p, force, slip, speed, spread):
        assert force is not None
        fit.add(force, arc / d_gps, weight)
    return slip
