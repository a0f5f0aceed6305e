"""Tire geometry: the free radius from the tire size designation.

R = (2*(A/100)*W + Rd*25.4) / 2  [mm]   (study eq. 3.4-3.5)
with W the section width in mm, A the aspect ratio in percent and Rd the rim diameter in inches:
195/60 R15 -> (2*0.60*195 + 15*25.4)/2 = 307.5 mm. (The study's example, 0.3045 m, takes 25.0 mm per inch;
set `tire.free_radius_m` to use a measured or quoted value instead.)
"""

from __future__ import annotations

import re

_SIZE = re.compile(
    r"^\s*(?:P|LT)?(?P<w>\d{3})\s*/\s*(?P<a>\d{2,3})\s*Z?R\s*(?P<rd>\d{2}(?:\.\d)?)(?:\s+\d{2,3}[A-Z])?\s*$", re.I
)
"""W/A Rd with an optional P/LT prefix, ZR, and a trailing load index and speed symbol (195/60 R15 88H)."""


class TireSizeError(ValueError):
    """A tire size that is not of the form 'W/A Rd' (for example '195/60 R15')."""


def parse_tire_size(size: str) -> tuple[float, float, float]:
    """'195/60 R15' -> (section width mm, aspect ratio %, rim diameter inch)."""
    m = _SIZE.match(size)
    if m is None:
        raise TireSizeError(f"tire size {size!r} is not of the form 'W/A Rd', for example '195/60 R15'")
    return float(m["w"]), float(m["a"]), float(m["rd"])


def free_radius_m(size: str) -> float:
    """Free (unloaded) tire radius from its size: R = (2*(A/100)*W + Rd*25.4)/2 mm, returned in metres."""
    width_mm, aspect_pct, rim_in = parse_tire_size(size)
    return (2.0 * (aspect_pct / 100.0) * width_mm + rim_in * 25.4) / 2.0 / 1000.0
