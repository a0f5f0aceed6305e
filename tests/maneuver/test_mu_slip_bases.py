"""The bootstrap's fits on the grid columns of all the maneuver's points, gathered per resample (mu_slip.Bases):
the same columns bit for bit as each resample's own, and the same intervals as fitting each resample from scratch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slipdaq.maneuver.mu_slip import (
    BOOTSTRAP_FOUND_SHARE,
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    C2_GRID,
    Bases,
    block_starts,
    c1_basis,
    fit_mu_slip,
    peak_interval,
    robust_interval,
)


def points(seed: int, n: int, sign: float) -> tuple[np.ndarray, np.ndarray]:
    """A braking (sign -1) or driving maneuver's (slip, mu) around a Burckhardt curve with its peak inside, noisy,
    with a few non-finite points."""
    rng = np.random.default_rng(seed)
    s = np.abs(np.sin(np.linspace(0.0, 6.0, n))) * 0.25 + rng.normal(0.0, 0.004, n)
    mu = 1.1 * (1 - np.exp(-25.0 * s)) - 0.5 * s + rng.normal(0.0, 0.02, n)
    s[rng.integers(0, n, 3)] = np.nan
    mu[rng.integers(0, n, 2)] = np.inf
    return sign * s, sign * mu


def from_scratch(s: np.ndarray, m: np.ndarray, block: int) -> tuple[float | None, ...]:
    """peak_interval as each resample fitted on its own (fit_mu_slip)."""
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    n = s.size
    block = max(1, min(block, n))
    peaks = []
    for _ in range(BOOTSTRAP_RESAMPLES):
        starts = block_starts(rng, n, block)
        idx = (starts[:, None] + np.arange(block)[None, :]).ravel()[:n]
        fit = fit_mu_slip(s[idx], m[idx])
        if fit is not None and fit.mu_peak is not None and fit.slip_at_mu_peak is not None:
            peaks.append((fit.mu_peak, fit.slip_at_mu_peak))
    if len(peaks) < BOOTSTRAP_FOUND_SHARE * BOOTSTRAP_RESAMPLES:
        return None, None, None, None
    arr = np.array(peaks)
    return (*robust_interval(arr[:, 0]), *robust_interval(arr[:, 1]))


@pytest.mark.parametrize("seed,n,sign,block", [(1, 400, -1.0, 20), (2, 900, 1.0, 20), (3, 250, -1.0, 7),
                                               (4, 60, 1.0, 20), (5, 1500, -1.0, 40)])
def test_peak_interval_as_from_scratch(seed: int, n: int, sign: float, block: int) -> None:
    s, m = points(seed, n, sign)
    got, want = peak_interval(s, m, block), from_scratch(s, m, block)
    assert [None if v is None else float(v).hex() for v in got] == \
        [None if v is None else float(v).hex() for v in want]


def test_found_intervals() -> None:
    """The cases above are not all 'no peak': the comparison covers found intervals."""
    s, m = points(1, 400, -1.0)
    assert all(v is not None and math.isfinite(v) for v in peak_interval(s, m, 20))


def test_gathered_columns_are_a_subsets_own() -> None:
    rng = np.random.default_rng(7)
    slip = rng.normal(0.0, 0.1, 500)
    slip[[3, 90]] = np.nan, np.inf
    bases = Bases(slip)
    fine = [np.geomspace(C2_GRID[k], C2_GRID[k + 2], 200) for k in range(Bases.MAX_GRIDS + 2)]
    for sign in (1.0, -1.0):
        for grid in [C2_GRID, *fine]:  # more grids than it keeps: the rest computed for the subset alone
            pos = rng.integers(0, 500, 300)
            pos = pos[np.isfinite(slip[pos])]
            got = bases.columns(sign, grid, pos)
            assert got.flags.c_contiguous  # as c1_basis gives it: numpy's sums over it take the same order
            assert np.array_equal(got.view(np.int64), c1_basis(grid, sign * slip[pos]).view(np.int64))
