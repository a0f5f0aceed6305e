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

k is the longitudinal slip (ISO: negative braking), Fz the normal load (N).
"""

from __future__ import annotations

import dataclasses
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
        k = np.asarray(slip, dtype=float)
        fz_a = np.asarray(fz, dtype=float)
        d = self.dfz(fz_a)
        kx = k + (self.phx1 + self.phx2 * d) * self.lhx
        cx = self.pcx1 * self.lcx
        dx = self.friction(fz_a) * fz_a
        ex = np.minimum((self.pex1 + self.pex2 * d + self.pex3 * d * d) * (1.0 - self.pex4 * np.sign(kx)) * self.lex,
                        1.0)
        bx = self.slip_stiffness(fz_a) / (cx * dx + EPS_X)
        lmux_prime = 10.0 * self.lmux / (1.0 + 9.0 * self.lmux)
        svx = fz_a * (self.pvx1 + self.pvx2 * d) * self.lvx * lmux_prime
        bk = bx * kx
        return np.asarray(dx * np.sin(cx * np.arctan(bk - ex * (bk - np.arctan(bk)))) + svx, dtype=float)

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
