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

import numpy as np


class StiffnessFit:
    def __init__(self, forgetting: float = 0.998, min_windows: int = 20) -> None:
        self.forgetting = forgetting
        self.min_windows = min_windows
        self._a = np.zeros((2, 2))
        self._b = np.zeros(2)
        self._yy = 0.0
        self._w = 0.0
        self.windows = 0
        self.cx_n: float | None = None
        self.confidence = 0.0
        self.radius_m: float | None = None

    def add(self, force_n: float, arc_per_metre: float, weight: float = 1.0) -> None:
        """One window: the tire's force and q = 2*pi*N / d_gps; weight from the GPS's stated accuracy."""
        x = np.array([force_n / 1000.0, 1.0])
        q = arc_per_metre
        lam = self.forgetting
        self._a = lam * self._a + weight * np.outer(x, x)
        self._b = lam * self._b + weight * x * q
        self._yy = lam * self._yy + weight * q * q
        self._w = lam * self._w + 1.0
        self.windows += 1
        if self.windows >= self.min_windows:
            self._solve()

    def _solve(self) -> None:
        det = self._a[0, 0] * self._a[1, 1] - self._a[0, 1] * self._a[1, 0]
        if det <= 1e-12 * max(self._a[0, 0] * self._a[1, 1], 1e-300):
            return  # no spread of force yet
        inv = np.array([[self._a[1, 1], -self._a[0, 1]], [-self._a[1, 0], self._a[0, 0]]]) / det
        theta = inv @ self._b
        beta, alpha = float(theta[0]), float(theta[1])
        resid = max(self._yy - float(theta @ self._b), 0.0)
        cov = inv * (resid / max(self._w - 2.0, 1.0))
        if beta <= 0 or alpha <= 0:
            self.cx_n, self.confidence = None, 0.0
            return
        # delta method for Cx = alpha/beta (per kN -> N below)
        rel_var = cov[1, 1] / alpha**2 + cov[0, 0] / beta**2 - 2.0 * cov[0, 1] / (alpha * beta)
        rel_se = math.sqrt(max(rel_var, 0.0))
        self.confidence = float(min(max(1.0 - 10.0 * rel_se, 0.0), 1.0))
        self.radius_m = 1.0 / alpha
        self.cx_n = 1000.0 * alpha / beta if self.confidence > 0 else None
