"""The Magic Formula's pure longitudinal force Fx0 (MF-Tyre 6.1; Pacejka, Tire and Vehicle Dynamics, 3rd ed. 2012,
eqs. 4.E9-4.E18), at zero camber, the nominal inflation pressure (the pressure terms PPX* vanish) and without turn
slip (zeta = 1). Pure: numbers in, numbers out.

    Fz0' = FNOMIN·LFZO,   dfz = (Fz − Fz0')/Fz0'
    SHx = (PHX1 + PHX2·dfz)·LHX,   kx = k + SHx
    Cx = PCX1·LCX,   mux = (PDX1 + PDX2·dfz)·LMUX,   Dx = mux·Fz
    Ex = (PEX1 + PEX2·dfz + PEX3·dfz²)·(1 − PEX4·sgn(kx))·LEX   (<= 1)
    Kxk = Fz·(PKX1 + PKX2·dfz)·exp(PKX3·dfz)·LKX,   Bx = Kxk/(Cx·Dx + eps)
    SVx = Fz·(PVX1 + PVX2·dfz)·LVX·LMUX'   (LMUX' = 10·LMUX/(1 + 9·LMUX), 4.E8)
    Fx0 = Dx·sin(Cx·atan(Bx·kx − Ex·(Bx·kx − atan(Bx·kx)))) + SVx

k is the longitudinal slip (ISO: negative braking), Fz the normal load (N). Fx0Terms.jacobian: its derivatives by the
coefficients a fit moves (JACOBIAN_NAMES), in closed form.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

EPS_X = 1e-6
"""eps_x of 4.E16: keeps Bx finite at Fz = 0."""
LONGITUDINAL_NAMES = ("PCX1", "PDX1", "PDX2", "PDX3", "PEX1", "PEX2", "PEX3", "PEX4", "PKX1", "PKX2", "PKX3",
                      "PHX1", "PHX2", "PVX1", "PVX2")
"""The [LONGITUDINAL_COEFFICIENTS] of pure longitudinal slip, in the order a .tir lists them."""
SCALING_NAMES = ("LFZO", "LCX", "LMUX", "LEX", "LKX", "LHX", "LVX")


@dataclass(frozen=True)
class LongitudinalMF61:
    """A tire's pure longitudinal MF 6.1 coefficients (their .tir names, lower case) and nominal load."""

    fnomin: float
    pcx1: float
    pdx1: float
    pkx1: float
    pdx2: float = 0.0
    pdx3: float = 0.0
    pex1: float = 0.0
    pex2: float = 0.0
    pex3: float = 0.0
    pex4: float = 0.0
    pkx2: float = 0.0
    pkx3: float = 0.0
    phx1: float = 0.0
    phx2: float = 0.0
    pvx1: float = 0.0
    pvx2: float = 0.0
    lfzo: float = 1.0
    lcx: float = 1.0
    lmux: float = 1.0
    lex: float = 1.0
    lkx: float = 1.0
    lhx: float = 1.0
    lvx: float = 1.0

    @classmethod
    def from_values(cls, fnomin: float, values: dict[str, float]) -> LongitudinalMF61:
        """From .tir names (PCX1, ..., LVX); names it does not use are ignored, missing ones take their defaults
        (PCX1, PDX1, PKX1 are required)."""
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(fnomin=fnomin, **{k.lower(): float(v) for k, v in values.items() if k.lower() in fields
                                     and k.lower() != "fnomin"})

    def values(self) -> dict[str, float]:
        """The coefficients by their .tir names (LONGITUDINAL_NAMES)."""
        return {n: float(getattr(self, n.lower())) for n in LONGITUDINAL_NAMES}

    def dfz(self, fz: npt.ArrayLike) -> FloatArray:
        fz0 = self.fnomin * self.lfzo
        return np.asarray((np.asarray(fz, dtype=float) - fz0) / fz0, dtype=float)

    def slip_stiffness(self, fz: npt.ArrayLike) -> FloatArray:
        """Kxk = dFx0/dk at kx = 0 (N per unit slip), 4.E15."""
        fz_a = np.asarray(fz, dtype=float)
        d = self.dfz(fz_a)
        return np.asarray(fz_a * (self.pkx1 + self.pkx2 * d) * np.exp(self.pkx3 * d) * self.lkx, dtype=float)

    def friction(self, fz: npt.ArrayLike) -> FloatArray:
        """mux (4.E13, zero camber): the peak Dx over Fz."""
        return np.asarray((self.pdx1 + self.pdx2 * self.dfz(fz)) * self.lmux, dtype=float)

    def fx0(self, slip: npt.ArrayLike, fz: npt.ArrayLike) -> FloatArray:
        """Fx0 (N) at each (slip, Fz), broadcast (module docstring)."""
        return self.fx0_terms(self.point_terms(slip, fz)).fx0

    def _fixed(self) -> tuple[float, ...]:
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in JACOBIAN_NAMES)

    def point_terms(self, slip: npt.ArrayLike, fz: npt.ArrayLike) -> PointTerms:
        """The terms at each (slip, Fz) that the coefficients of JACOBIAN_NAMES do not enter (PointTerms)."""
        k = np.asarray(slip, dtype=float)
        fz_a = np.asarray(fz, dtype=float)
        d = self.dfz(fz_a)
        kx = k + (self.phx1 + self.phx2 * d) * self.lhx
        lmux_prime = 10.0 * self.lmux / (1.0 + 9.0 * self.lmux)
        return PointTerms(self._fixed(), k, fz_a, d, kx, np.sign(kx), self.pex2 * d, self.pex3 * d * d,
                          np.exp(self.pkx3 * d), fz_a * (self.pvx1 + self.pvx2 * d) * self.lvx * lmux_prime)

    def fx0_terms(self, points: PointTerms) -> Fx0Terms:
        """Fx0 at the points with the terms its derivatives need (Fx0Terms); points from a model that differs from
        this one at most in JACOBIAN_NAMES (a fit's points: their terms computed once)."""
        if points.fixed != self._fixed():
            raise ValueError("the points' terms are of a model with other coefficients than JACOBIAN_NAMES'")
        d, fz_a = points.dfz, points.fz
        cx = self.pcx1 * self.lcx
        dx = (self.pdx1 + self.pdx2 * d) * self.lmux * fz_a  # friction(fz)·Fz
        ex_shape = self.pex1 + points.pex2_dfz + points.pex3_dfz2
        ex_raw = ex_shape * (1.0 - self.pex4 * points.sign_kx) * self.lex
        ex = np.minimum(ex_raw, 1.0)
        cd = cx * dx + EPS_X
        bx = fz_a * (self.pkx1 + self.pkx2 * d) * points.exp_pkx3 * self.lkx / cd  # slip_stiffness / cd
        bk = bx * points.kx
        atan_bk = np.arctan(bk)
        phi = bk - ex * (bk - atan_bk)
        atan_phi = np.arctan(phi)
        sin_c = np.sin(cx * atan_phi)
        fx0 = np.asarray(dx * sin_c + points.svx, dtype=float)
        return Fx0Terms(self, points, ex_shape, ex_raw < 1.0, ex, dx, cd, bx, bk, atan_bk, phi, atan_phi, sin_c, fx0)

    def peak(self, fz: float, sign: float = -1.0, slip_max: float = 1.0) -> tuple[float, float]:
        """(|Fx0| at its peak, |slip| there) on the side `sign` (−1 braking), searched over |slip| <= slip_max (a
        grid of 0.0005, then a parabola through the best three)."""
        x = np.arange(0.0, slip_max + 1e-12, 0.0005)
        f = np.abs(self.fx0(sign * x, fz))
        i = int(np.argmax(f))
        if 0 < i < x.size - 1:
            den = f[i - 1] - 2.0 * f[i] + f[i + 1]
            frac = 0.5 * (f[i - 1] - f[i + 1]) / den if den < 0 else 0.0
            xs = float(x[i] + frac * 0.0005)
            return float(abs(self.fx0(sign * xs, fz))), xs
        return float(f[i]), float(x[i])


JACOBIAN_NAMES = ("pcx1", "pdx1", "pdx2", "pex1", "pex4", "pkx1", "pkx2")
"""The coefficients Fx0Terms.jacobian differentiates by: those the road fits (tire_model/fit.py)."""


@dataclass(frozen=True)
class PointTerms:
    """The terms of 4.E9-4.E18 at points (slip, Fz) that the coefficients of JACOBIAN_NAMES do not enter."""

    fixed: tuple[float, ...]
    """The model's other coefficients (those the terms are of)."""
    slip: FloatArray
    fz: FloatArray
    dfz: FloatArray
    kx: FloatArray
    sign_kx: FloatArray
    pex2_dfz: FloatArray
    pex3_dfz2: FloatArray
    exp_pkx3: FloatArray
    """exp(PKX3·dfz)."""
    svx: FloatArray


@dataclass(frozen=True)
class Fx0Terms:
    """Fx0 of a model at points and the terms of 4.E9-4.E18 there that its derivatives reuse:
    phi = Bx·kx − Ex·(Bx·kx − atan(Bx·kx)), Fx0 = Dx·sin(Cx·atan(phi)) + SVx."""

    model: LongitudinalMF61
    points: PointTerms
    ex_shape: FloatArray
    """PEX1 + PEX2·dfz + PEX3·dfz²."""
    ex_free: npt.NDArray[np.bool_]
    """Where Ex is below its limit 1 (elsewhere it does not move with the coefficients)."""
    ex: FloatArray
    dx: FloatArray
    cd: FloatArray
    """Cx·Dx + eps_x."""
    bx: FloatArray
    bk: FloatArray
    atan_bk: FloatArray
    phi: FloatArray
    atan_phi: FloatArray
    sin_c: FloatArray
    """sin(Cx·atan phi)."""
    fx0: FloatArray

    def jacobian(self, names: Sequence[str]) -> FloatArray:
        """dFx0/dc for each coefficient c of names (of JACOBIAN_NAMES), one row each, by the chain rule:
            dFx0/dphi = Dx·Cx·cos(Cx·atan phi)/(1 + phi²),   dphi/d(Bx·kx) = 1 − Ex·(Bx·kx)²/(1 + (Bx·kx)²),
            dphi/dEx = atan(Bx·kx) − Bx·kx,   dBx/dKxk = 1/(Cx·Dx + eps),   dBx/dCx = −Bx·Dx/(Cx·Dx + eps),
            dBx/dDx = −Bx·Cx/(Cx·Dx + eps),   dFx0/dCx = Dx·cos(Cx·atan phi)·atan phi + (via Bx),
            dFx0/dDx = sin(Cx·atan phi) + (via Bx); Cx, Dx, Ex, Kxk linear in their coefficients (4.E11-4.E15)."""
        m, pt = self.model, self.points
        cx = m.pcx1 * m.lcx
        cos_c = np.cos(cx * self.atan_phi)
        bk2 = self.bk * self.bk
        by_phi = self.dx * cx * cos_c / (1.0 + self.phi * self.phi)
        by_bx = by_phi * (1.0 - self.ex * bk2 / (1.0 + bk2)) * pt.kx
        by_kxk = by_bx / self.cd
        cols: list[FloatArray] = []
        for name in names:
            if name == "pcx1":
                col = (self.dx * cos_c * self.atan_phi - by_bx * self.bx * self.dx / self.cd) * m.lcx
            elif name in ("pdx1", "pdx2"):
                col = (self.sin_c - by_bx * self.bx * cx / self.cd) * (m.lmux * pt.fz)
                col = col * pt.dfz if name == "pdx2" else col
            elif name in ("pkx1", "pkx2"):
                col = by_kxk * pt.fz * pt.exp_pkx3 * m.lkx
                col = col * pt.dfz if name == "pkx2" else col
            elif name in ("pex1", "pex4"):
                by_ex = np.where(self.ex_free, by_phi * (self.atan_bk - self.bk) * m.lex, 0.0)
                col = by_ex * (1.0 - m.pex4 * pt.sign_kx) if name == "pex1" else -by_ex * self.ex_shape * pt.sign_kx
            else:
                raise KeyError(f"{name}: not one of {JACOBIAN_NAMES}")
            cols.append(np.asarray(col, dtype=float))
        return np.stack(cols)
