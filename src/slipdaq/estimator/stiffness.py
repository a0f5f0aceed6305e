"""Longitudinal stiffness Cx per tire, fitted so that noise in the slip does not bias it.

Over the linear region, omega*r0/V = 1 + s = 1 + F/Cx. With q = 2*pi*N/d_gps (wheel arc per metre of GPS
distance, which needs no radius): q = (1 + F/Cx)/r0 = alpha + beta*F, so r0 = 1/alpha and Cx = alpha/beta.
Fitted by least squares with exponential forgetting (recursive least squares in normal-equation form). q, the
noisy one (GPS noise, count quantisation), is the regressand: its noise adds variance but no bias; the force
F = M*a share is the regressor (its noise, about 0.2 m/s^2 of acceleration, is small against the range of F, so
its attenuation bias is well under 1 %). The radius is fitted jointly, so neither a radius error nor a change of
the radius used for slip biases Cx, as it biases a per-window Fx/s. F in kN inside, for conditioning.
Cx is the slope of the force-slip relation over the slips visited: on a tire whose curve bends within the linear
region it is below the initial slope dF/ds(0).
Confidence = clip(1 - 10 * relative standard error of Cx, 0, 1): 0.5 at 5 %; Cx is None while it is 0.
"""

from __future__ import annotations

import math


class StiffnessFit:
    """Normal equations A theta = b kept as Python floats (A = [[a00, a01], [a01, a11]]): a window costs a few float
    operations, and so does the solve: each product and sum rounded once, in the order written, the same bits on
    every machine (BLAS, numpy's matrix product, fuses some of them by the CPU it finds)."""

    def __init__(self, forgetting: float = 0.998, min_windows: int = 20) -> None:
        self.forgetting = forgetting
        self.min_windows = min_windows
        self._a00 = self._a01 = self._a10 = self._a11 = 0.0
        self._b0 = self._b1 = 0.0
        self._yy = 0.0
        self._w = 0.0
        self.windows = 0
        self.cx_n: float | None = None
        self.confidence = 0.0
        self.radius_m: float | None = None

    def add(self, force_n: float, arc_per_metre: float, weight: float = 1.0) -> None:
        """One window: the tire's force and q = 2*pi*N / d_gps; weight from the GPS's stated accuracy."""
        x0 = float(force_n / 1000.0)  # regressors x = (F in kN, 1)
        q = float(arc_per_metre)
        weight = float(weight)
        lam = self.forgetting
        self._a00 = lam * self._a00 + weight * (x0 * x0)
        self._a01 = lam * self._a01 + weight * (x0 * 1.0)
        self._a10 = lam * self._a10 + weight * (1.0 * x0)
        self._a11 = lam * self._a11 + weight * 1.0
        self._b0 = lam * self._b0 + weight * x0 * q
        self._b1 = lam * self._b1 + weight * 1.0 * q
        self._yy = lam * self._yy + weight * q * q
        self._w = lam * self._w + 1.0
        self.windows += 1
        if self.windows >= self.min_windows:
            self._solve()

    def _solve(self) -> None:
        a00, a01, a10, a11 = self._a00, self._a01, self._a10, self._a11
        det = a00 * a11 - a01 * a10
        if det <= 1e-12 * max(a00 * a11, 1e-300):
            return  # no spread of force yet
        i00, i01, i10, i11 = a11 / det, -a01 / det, -a10 / det, a00 / det
        b0, b1 = self._b0, self._b1
        beta, alpha = i00 * b0 + i01 * b1, i10 * b0 + i11 * b1  # theta = A^-1 b
        resid = max(self._yy - (beta * b0 + alpha * b1), 0.0)
        scale = resid / max(self._w - 2.0, 1.0)
        c00, c01, c11 = i00 * scale, i01 * scale, i11 * scale
        if beta <= 0 or alpha <= 0:
            self.cx_n, self.confidence = None, 0.0
            return
        # delta method for Cx = alpha/beta (per kN -> N below)
        rel_var = c11 / alpha**2 + c00 / beta**2 - 2.0 * c01 / (alpha * beta)
        rel_se = math.sqrt(max(rel_var, 0.0))
        self.confidence = float(min(max(1.0 - 10.0 * rel_se, 0.0), 1.0))
        self.radius_m = 1.0 / alpha
        self.cx_n = 1000.0 * alpha / beta if self.confidence > 0 else None
