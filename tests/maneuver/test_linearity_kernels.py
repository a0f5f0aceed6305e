"""The linear region's sums (maneuver/linearity.py), compiled and as Python, against the rule written with Python's
sums over lists of tuples: the same Linearity, every float bit for bit."""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq.maneuver.linearity import (
    Linearity,
    LinearityRule,
    LineFit,
    _variance,
    analyse_linearity,
    fit_through_origin,
)
from support.paths import kernels

# The rule written with Python's sums over lists of tuples: the reference the kernels are held to.


def _origin_py(points: Sequence[tuple[float, float]]) -> LineFit | None:
    if len(points) < 2:
        return None
    sss = sum(s * s for s, _ in points)
    if sss <= 0:
        return None
    cx = sum(s * f for s, f in points) / sss
    resid = sum((f - cx * s) ** 2 for s, f in points)
    return LineFit(cx, math.sqrt(resid / (len(points) - 1) / sss), len(points))


def _slip_on_force_py(points: Sequence[tuple[float, float]], noise: tuple[float, float] | None,
                      w: Sequence[float]) -> LineFit | None:
    n = len(points)
    if n < 3:
        return None
    sw = sum(w)
    f_mean = sum(wi * f for wi, (_, f) in zip(w, points)) / sw
    s_mean = sum(wi * s for wi, (s, _) in zip(w, points)) / sw
    sff = sum(wi * (f - f_mean) ** 2 for wi, (_, f) in zip(w, points))
    if sff <= 0:
        return None
    sfs = sum(wi * (f - f_mean) * (s - s_mean) for wi, (s, f) in zip(w, points))
    b = sfs / sff
    method = "slip on force"
    if noise is not None and noise[0] > 0 and noise[1] > 0 and sfs > 0:
        lam = noise[0] / noise[1]
        sss = sum(wi * (s - s_mean) ** 2 for wi, (s, _) in zip(w, points))
        d = sss - lam * sff
        b = (d + math.sqrt(d * d + 4.0 * lam * sfs * sfs)) / (2.0 * sfs)
        method = "errors-in-variables"
    a = s_mean - b * f_mean
    resid = sum(wi * (s - a - b * f) ** 2 for wi, (s, f) in zip(w, points))
    se_b = math.sqrt(resid / (n - 2) / sff)
    if b <= 3.0 * se_b:
        return None
    return LineFit(1.0 / b, se_b / (b * b), n, a, method)


def _noise_py(anchors: Sequence[tuple[float, float]], w: Sequence[float]) -> tuple[float, float] | None:
    n = len(anchors)
    if n < 10:
        return None
    s_mean = sum(wi * s for wi, (s, _) in zip(w, anchors)) / sum(w)
    var_s = sum(wi * (s - s_mean) ** 2 for wi, (s, _) in zip(w, anchors)) / (n - 1)
    return var_s, statistics.variance([f for _, f in anchors])


def _weights_py(speeds: Sequence[float], reference_mps: float) -> list[float]:
    return [(max(v, 0.5) / max(reference_mps, 0.5)) ** 2 for v in speeds]


def linearity_py(slips: Sequence[float | None], forces: Sequence[float | None], rule: LinearityRule,
                 anchors: Sequence[tuple[float | None, float | None]], speeds: Sequence[float | None],
                 anchor_speeds: Sequence[float | None]) -> Linearity:
    weighted = all(v is not None for s, f, v in zip(slips, forces, speeds) if s is not None and f is not None) and \
        all(v is not None for (s, f), v in zip(anchors, anchor_speeds) if s is not None and f is not None)
    both = [(s, f, float(v) if weighted and v is not None else 1.0) for s, f, v in zip(slips, forces, speeds)
            if s is not None and f is not None]
    sign = 1.0 if sum(f for _, f, _ in both) >= 0 else -1.0
    anchor = [(s, f, float(v) if weighted and v is not None else 1.0) for (s, f), v in zip(anchors, anchor_speeds)
              if s is not None and f is not None]
    pts = sorted(((s, f) for s, f in zip(slips, forces)
                  if s is not None and f is not None and abs(s) >= rule.slip_min and s * f > 0),
                 key=lambda p: abs(p[0]))
    if not pts:
        return Linearity(0, None)
    bins: dict[int, list[tuple[float, float]]] = {}
    for p in pts:
        bins.setdefault(math.floor(abs(p[0]) / rule.bin_width), []).append(p)
    kept = [(j, b) for j, b in sorted(bins.items()) if len(b) >= rule.min_bin_points]
    fit_max = rule.slip_max
    line: LineFit | None = None
    end: tuple[int, list[tuple[float, float]]] | None = None
    for _ in range(rule.max_refits):
        fit_pts = [p for p in pts if abs(p[0]) <= fit_max]
        if len(fit_pts) < rule.min_fit_points:
            break
        kept_anchors = [p for p in anchor if abs(p[0]) <= fit_max]
        fit_both = [p for p in both if p[1] * sign > 0 and abs(p[0]) <= fit_max] + kept_anchors
        v_ref = statistics.median(p[2] for p in kept_anchors) if kept_anchors else 1.0
        line = (_slip_on_force_py([(s, f) for s, f, _ in fit_both],
                                  _noise_py([(s, f) for s, f, _ in kept_anchors],
                                            _weights_py([p[2] for p in kept_anchors], v_ref)),
                                  _weights_py([p[2] for p in fit_both], v_ref)) if anchor else None) \
            or _origin_py(fit_pts)
        if line is None:
            break
        below = [statistics.median(abs(f) for _, f in b)
                 < (1.0 - rule.tolerance) * abs(line.force_n(sign * statistics.median(abs(s) for s, _ in b)))
                 for _, b in kept]
        end = None
        for i in range(len(kept) - rule.min_end_bins + 1):
            if all(below[i:]):
                end = kept[i]
                break
        if end is None:
            break
        edge = end[0] * rule.bin_width
        if edge > fit_max:
            break
        if sum(abs(p[0]) < edge for p in pts) < rule.min_fit_points:
            break
        fit_max = math.nextafter(edge, 0.0)
    if line is None:
        return Linearity(len(pts), None)
    if end is None:
        linear = pts
        end_slip = end_force = None
    else:
        edge = end[0] * rule.bin_width
        linear = [p for p in pts if abs(p[0]) < edge]
        sign = 1.0 if sum(s for s, _ in end[1]) > 0 else -1.0
        end_slip = sign * statistics.median(abs(s) for s, _ in end[1])
        end_force = sign * statistics.median(abs(f) for _, f in end[1])
    peak = max(linear, key=lambda p: abs(p[1]), default=None)
    return Linearity(len(pts), line, end_slip, end_force, peak[1] if peak else None, peak[0] if peak else None)


def _bits(x: object) -> object:
    """A value with each float as its bits (so that -0.0 and 0.0, or NaNs, are told apart)."""
    if isinstance(x, float):
        return ("float", x.hex())
    if isinstance(x, Linearity | LineFit):
        return type(x).__name__, tuple(_bits(getattr(x, k.name)) for k in dataclasses.fields(x))
    return (type(x).__name__, x)


def _maneuver(seed: int) -> tuple[list[float | None], list[float | None], list[tuple[float | None, float | None]],
                                   list[float | None], list[float | None]]:
    """One wheel's windows of a maneuver along a force–slip curve that bends (or not), with the cruise windows
    as anchors; some values missing, some speeds below 0.5 m/s, some speeds missing (then unweighted)."""
    rng = np.random.default_rng(seed)
    sign = 1.0 if rng.random() < 0.5 else -1.0
    cx = rng.uniform(3e4, 1.2e5)
    bend = rng.uniform(0.0, 12.0)
    n = int(rng.integers(0, 160))
    s = sign * rng.uniform(0.0, rng.uniform(0.01, 0.3), n) + rng.normal(0.0, rng.uniform(1e-4, 4e-3), n)
    f = cx * s / (1.0 + bend * np.abs(s)) + rng.normal(0.0, rng.uniform(10.0, 400.0), n)
    m = int(rng.choice([0, 5, 12, int(rng.integers(0, 1100))]))
    a_s = rng.normal(rng.normal(0.0, 0.002), rng.uniform(1e-4, 3e-3), m)
    a_f = rng.normal(rng.normal(0.0, 300.0), rng.uniform(5.0, 300.0), m)
    speeds = rng.uniform(0.1, 35.0, n)
    a_speeds = rng.uniform(0.1, 35.0, m)

    def holes(x: np.ndarray, p: float) -> list[float | None]:
        return [None if rng.random() < p else float(v) for v in x]

    p_none = float(rng.choice([0.0, 0.05, 0.3]))
    slips, forces = holes(s, p_none), holes(f, p_none)
    if n and rng.random() < 0.2:
        forces[int(rng.integers(0, n))] = 0.0
        slips[int(rng.integers(0, n))] = -0.0
    anchors = list(zip(holes(a_s, p_none), holes(a_f, p_none)))
    p_speed = 0.02 if rng.random() < 0.2 else 0.0
    return slips, forces, anchors, holes(speeds, p_speed), holes(a_speeds, p_speed)


@pytest.mark.parametrize("compiled_", [True, False])
def test_linearity_is_the_python_sums(compiled_: bool) -> None:
    """300 simulated maneuvers: the same Linearity as the rule in Python's sums, every float bit for bit (with the
    residuals squared by libm's pow, as Python's ** squares them: by a multiplication, about 1 in 1,200 differ)."""
    rule = LinearityRule()
    ends = lines = 0
    with kernels(compiled_):
        for seed in range(300):
            slips, forces, anchors, speeds, a_speeds = _maneuver(seed)
            want = linearity_py(slips, forces, rule, anchors, speeds, a_speeds)
            got = analyse_linearity(slips, forces, rule, anchors, speeds, a_speeds)
            assert _bits(got) == _bits(want), seed
            ends += want.end_slip is not None
            lines += want.line is not None and want.line.method == "errors-in-variables"
    assert ends > 30 and lines > 30  # the data bend, and the anchors give the noise


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                          st.floats(-1e4, 1e4), st.sampled_from([0.0, -0.0, 5e-324, 1.0])), min_size=2, max_size=60))
def test_variance_is_statistics_variance(values: list[float]) -> None:
    try:
        want: float | str = statistics.variance(values)
    except OverflowError:
        want = "overflow"
    try:
        got: float | str = _variance(np.array(values))
    except OverflowError:
        got = "overflow"
    assert (got.hex() if isinstance(got, float) else got) == (want.hex() if isinstance(want, float) else want)


def test_variance_of_non_finite_values_is_statistics_variance() -> None:
    for values in ([1.0, math.inf, 2.0], [math.nan, 1.0], [-math.inf, math.inf, 0.0]):
        want, got = statistics.variance(values), _variance(np.array(values))
        assert math.isnan(want) == math.isnan(got) and (math.isnan(want) or want == got)


def test_fit_through_origin() -> None:
    pts = [(0.01, 800.0), (0.02, 1700.0), (-0.01, -900.0), (0.03, 2400.0)]
    assert _bits(fit_through_origin(pts)) == _bits(_origin_py(pts))
    assert fit_through_origin(pts[:1]) is None and fit_through_origin([(0.0, 1.0), (0.0, 2.0)]) is None
