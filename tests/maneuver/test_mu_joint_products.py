"""The joint fit's bootstrap takes its products with the Magic Formula's grid a block of rows at a time for all the
resamples (mu_joint._mf_products): the same bits as each resample's own products (e2 @ w, e @ (w * y))."""

from __future__ import annotations

import numpy as np
import pytest

from slipdaq.maneuver.mu_joint import MF_B, MF_C, MF_ROWS_BLOCK, _mf_products


@pytest.mark.parametrize("rows,n", [(MF_C.size * MF_B.size, 1), (MF_C.size * MF_B.size, 523),
                                    (MF_C.size * MF_B.size, 1000), (MF_C.size * MF_B.size, 2049),
                                    (3 * MF_ROWS_BLOCK + 5, 700)])
def test_blocked_products_are_each_resamples_own(rows: int, n: int) -> None:
    rng = np.random.default_rng(rows + n)
    e = rng.normal(0.0, 3000.0, (rows, n))
    basis = (e, e * e)
    y = rng.normal(0.0, 5000.0, n)
    ws = [rng.integers(0, 4, n).astype(float) * rng.choice([0.0, 1.0], n, p=[0.1, 0.9]) for _ in range(40)]
    got = _mf_products(basis, y, ws)
    assert len(got) == len(ws)
    for w, (ee, ey) in zip(ws, got):
        assert np.array_equal((basis[1] @ w).view(np.int64), ee.view(np.int64))
        assert np.array_equal((basis[0] @ (w * y)).view(np.int64), ey.view(np.int64))
