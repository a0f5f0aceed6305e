"""Statistics of repeated runs: the mean with its Student-t interval, and Welch's difference of two means. Pure
(math only).

Student t quantile: the t distribution's CDF through the regularized incomplete beta function,
F(t; ν) = 1 − ½·I_{ν/(ν+t²)}(ν/2, ½) for t ≥ 0 (Abramowitz & Stegun 26.7.1), I by its continued fraction (Numerical
Recipes 6.4, modified Lentz), inverted by bisection; ν need not be an integer (Welch–Satterthwaite).

Mean of n runs: x̄ ± t_{0.975, n−1}·s/√n, s the sample standard deviation (n − 1), CV = 100·s/|x̄|.
Welch: Δ = x̄_a − x̄_b ± t_{0.975, ν}·√(s_a²/n_a + s_b²/n_b), ν = (s_a²/n_a + s_b²/n_b)² /
((s_a²/n_a)²/(n_a − 1) + (s_b²/n_b)²/(n_b − 1)) (Welch 1947, Satterthwaite 1946).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

CONFIDENCE = 0.95
_EPS = 1e-15
_TINY = 1e-300


def _beta_cf(a: float, b: float, x: float) -> float:
    """The continued fraction of the incomplete beta function (modified Lentz)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, 500):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + aa / c
            c = c if abs(c) > _TINY else _TINY
            h *= d * c
        if abs(d * c - 1.0) < _EPS:
            break
    return h


def betainc(a: float, b: float, x: float) -> float:
    """The regularized incomplete beta function I_x(a, b), 0 <= x <= 1."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    ln = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(ln) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(ln) * _beta_cf(b, a, 1.0 - x) / b


def t_cdf(t: float, df: float) -> float:
    """P(T <= t) for Student's t with df degrees of freedom (df > 0, not necessarily whole)."""
    tail = 0.5 * betainc(0.5 * df, 0.5, df / (df + t * t))
    return 1.0 - tail if t >= 0 else tail


def t_quantile(p: float, df: float) -> float:
    """The t such that P(T <= t) = p (0 < p < 1), by bisection on t_cdf to 1e-12."""
    if not 0.0 < p < 1.0 or not df > 0:
        raise ValueError("t_quantile: expected 0 < p < 1 and df > 0")
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    lo, hi = 0.0, 1.0
    while t_cdf(hi, df) < p:
        lo, hi = hi, 2.0 * hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)


@dataclass(frozen=True, slots=True)
class MeanInterval:
    """A figure over n runs: mean, sample standard deviation, CV (%) and the mean's 95 % interval (None: too few)."""

    n: int
    mean: float | None
    sd: float | None
    cv_percent: float | None
    ci_lo: float | None
    ci_hi: float | None


def mean_interval(values: Sequence[float], confidence: float = CONFIDENCE) -> MeanInterval:
    """The figure's statistics over its runs (module docstring); sd, CV and interval need two runs."""
    n = len(values)
    if n == 0:
        return MeanInterval(0, None, None, None, None, None)
    mean = math.fsum(values) / n
    if n < 2:
        return MeanInterval(1, mean, None, None, None, None)
    sd = math.sqrt(math.fsum((x - mean) ** 2 for x in values) / (n - 1))
    half = t_quantile(0.5 + 0.5 * confidence, n - 1) * sd / math.sqrt(n)
    cv = 100.0 * sd / abs(mean) if mean != 0 else None
    return MeanInterval(n, mean, sd, cv, mean - half, mean + half)


@dataclass(frozen=True, slots=True)
class Difference:
    """mean_a − mean_b with its Welch interval (ci None: fewer than two runs on a side, or no spread at all)."""

    n_a: int
    n_b: int
    mean_a: float
    mean_b: float
    difference: float
    ci_lo: float | None
    ci_hi: float | None
    df: float | None

    @property
    def excludes_zero(self) -> bool:
        return self.ci_lo is not None and self.ci_hi is not None and (self.ci_lo > 0 or self.ci_hi < 0)


def welch_difference(a: Sequence[float], b: Sequence[float], confidence: float = CONFIDENCE) -> Difference | None:
    """Welch's difference of the means of a and b (module docstring); None when a side has no value."""
    na, nb = len(a), len(b)
    if na == 0 or nb == 0:
        return None
    ma, mb = math.fsum(a) / na, math.fsum(b) / nb
    if na < 2 or nb < 2:
        return Difference(na, nb, ma, mb, ma - mb, None, None, None)
    va = math.fsum((x - ma) ** 2 for x in a) / (na - 1) / na
    vb = math.fsum((x - mb) ** 2 for x in b) / (nb - 1) / nb
    se2 = va + vb
    if se2 <= 0:
        return Difference(na, nb, ma, mb, ma - mb, None, None, None)
    df = se2 * se2 / (va * va / (na - 1) + vb * vb / (nb - 1))
    half = t_quantile(0.5 + 0.5 * confidence, df) * math.sqrt(se2)
    return Difference(na, nb, ma, mb, ma - mb, ma - mb - half, ma - mb + half, df)
