"""The tire property file (`.tir`, MF-Tyre 6.1, as MFeval, Adams and CarMaker read it): written from a fitted tire,
read back into sections. The layout: `[SECTION]` headers, `NAME = value $comment` lines, `$` and `!` comment lines,
strings in single quotes.

What a written file holds: [MDI_HEADER], [UNITS] (SI), [MODEL] (FITTYP = 61), [DIMENSION] (UNLOADED_RADIUS: the
calibrated r0; WIDTH, ASPECT_RATIO, RIM_RADIUS from the tire size), [OPERATING_CONDITIONS] (INFLPRES = NOMPRES: the
pressure terms vanish), [VERTICAL] (FNOMIN: the static wheel load), [LONG_SLIP_RANGE] (KPUMIN/KPUMAX: the slip the
data covered), [SCALING_COEFFICIENTS] (all 1), [LONGITUDINAL_COEFFICIENTS] (fitted), every other MF 6.1 section and
coefficient at neutral or typical values (neutral.py: no lateral force, moment or rolling resistance; combined slip
without interaction), and a `$ [SLIPDAQ]` comment block that says where the numbers came from.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from slipdaq.tire_model.mf61 import LONGITUDINAL_NAMES, SCALING_NAMES, LongitudinalMF61
from slipdaq.tire_model.neutral import (
    COEFFICIENT_SECTIONS,
    COMBINED_LONGITUDINAL,
    PRESSURE_LONGITUDINAL,
    RANGES_OTHER,
    SCALING_OTHERS,
    SECTIONS_AFTER_VERTICAL,
    SECTIONS_BEFORE,
    VERTICAL_OTHERS,
)

Value = float | str

FZMAX_PER_FNOMIN = 2.5
"""[VERTICAL_FORCE_RANGE] FZMAX = this·FNOMIN (FZMIN 0): an evaluator clamps the load there; the load terms hold only
over the loads the data saw (the [SLIPDAQ] block)."""


@dataclass(frozen=True)
class TireFile:
    """What a written .tir holds (module docstring)."""

    model: LongitudinalMF61
    unloaded_radius_m: float
    width_m: float | None
    aspect_ratio: float | None
    rim_radius_m: float | None
    slip_min: float
    slip_max: float
    longvl_mps: float = 16.7
    pressure_pa: float = 220000.0
    notes: dict[str, str] = field(default_factory=dict)
    """Per coefficient name: a comment on its line (why it is 0)."""
    slipdaq: Sequence[str] = ()
    """The [SLIPDAQ] block's lines (without the leading '$ ')."""
    tyreside: str = "LEFT"


def _line(name: str, value: Value, comment: str = "") -> str:
    text = f"'{value}'" if isinstance(value, str) else f"{value:.10g}"
    return f"{name:<25}= {text:<20}" + (f" ${comment}" if comment else "")


def _section(name: str) -> list[str]:
    return [f"${'-' * 60}{name.lower()}", f"[{name}]"]


def tir_text(tire: TireFile) -> str:
    """The .tir text of a tire (module docstring)."""
    m = tire.model
    lines = ["$ Magic Formula tire property file (MF-Tyre 6.1): pure longitudinal slip measured on the road by slipdaq",
             "$ [SLIPDAQ]"]
    lines += [f"$   {s}" for s in tire.slipdaq]
    lines += ["$ [SLIPDAQ] end", "[MDI_HEADER]", _line("FILE_TYPE", "tir"), _line("FILE_VERSION", 3.0),
              _line("FILE_FORMAT", "ASCII")]
    lines += _section("UNITS") + [_line("LENGTH", "meter"), _line("FORCE", "newton"), _line("ANGLE", "radians"),
                                  _line("MASS", "kg"), _line("TIME", "second")]
    lines += _section("MODEL") + [
        _line("FITTYP", 61, "Magic Formula version number"), _line("TYRESIDE", tire.tyreside),
        _line("LONGVL", tire.longvl_mps, "Nominal speed"), _line("VXLOW", 1.0, "Lower boundary of slip calculation"),
        _line("ROAD_INCREMENT", 0.01, "Increment in road sampling"),
        _line("ROAD_DIRECTION", 1, "Direction of travelled distance")]
    lines += _section("DIMENSION") + [_line("UNLOADED_RADIUS", tire.unloaded_radius_m, "Free tyre radius (calibrated r0)")]
    if tire.width_m is not None:
        lines.append(_line("WIDTH", tire.width_m, "Nominal section width of the tyre (tire size)"))
    if tire.aspect_ratio is not None:
        lines.append(_line("ASPECT_RATIO", tire.aspect_ratio, "Nominal aspect ratio (tire size)"))
    if tire.rim_radius_m is not None:
        lines.append(_line("RIM_RADIUS", tire.rim_radius_m, "Nominal rim radius (tire size)"))
    lines += _section("OPERATING_CONDITIONS") + [
        _line("INFLPRES", tire.pressure_pa, "Tyre inflation pressure (not measured: equal to NOMPRES)"),
        _line("NOMPRES", tire.pressure_pa, "Nominal tyre inflation pressure")]
    lines += _sections(SECTIONS_BEFORE)
    lines += _section("VERTICAL") + [_line("FNOMIN", m.fnomin, "Nominal wheel load (the static wheel load)")]
    lines += [_line(n, v, c) for n, (v, c) in VERTICAL_OTHERS.items()]
    lines += _sections(SECTIONS_AFTER_VERTICAL)
    lines += _section("INFLATION_PRESSURE_RANGE") + [
        _line("PRESMIN", 0.5 * tire.pressure_pa, "pressure not measured"),
        _line("PRESMAX", 2.0 * tire.pressure_pa, "pressure not measured")]
    lines += _section("VERTICAL_FORCE_RANGE") + [
        _line("FZMIN", 0.0, "Minimum allowed wheel load"),
        _line("FZMAX", FZMAX_PER_FNOMIN * m.fnomin, "Maximum allowed wheel load (2.5 FNOMIN)")]
    lines += _section("LONG_SLIP_RANGE") + [
        _line("KPUMIN", tire.slip_min, "Minimum valid wheel slip (the least the data covered)"),
        _line("KPUMAX", tire.slip_max, "Maximum valid wheel slip (the most the data covered)")]
    lines += _sections(RANGES_OTHER)
    lines += _section("SCALING_COEFFICIENTS") + [_line(n, float(getattr(m, n.lower())), "Scale factor")
                                                 for n in SCALING_NAMES]
    lines += [_line(n, 1.0, "Scale factor") for n in SCALING_OTHERS]
    lines += _section("LONGITUDINAL_COEFFICIENTS")
    lines += [_line(n, v, tire.notes.get(n, "")) for n, v in m.values().items()]
    lines += [_line(n, v, "pressure: neutral, not measured") for n, v in PRESSURE_LONGITUDINAL.items()]
    lines += [_line(n, v, "combined slip: neutral, not measured") for n, v in COMBINED_LONGITUDINAL.items()]
    lines += _sections(COEFFICIENT_SECTIONS)
    return "\n".join(lines) + "\n"


def _sections(sections: dict[str, dict[str, tuple[float, str]]]) -> list[str]:
    return [line for sec, values in sections.items()
            for line in _section(sec) + [_line(n, v, c) for n, (v, c) in values.items()]]


ASCII = str.maketrans({"→": "->", "–": "-", "—": "-", "·": "*", "±": "+-", "²": "^2", "μ": "mu"})
"""A .tir is ASCII: the few other characters slipdaq's titles and notes use, spelled out."""


def write_tir(path: str | Path, tire: TireFile) -> Path:
    p = Path(path)
    p.write_text(tir_text(tire).translate(ASCII), encoding="ascii", errors="replace")
    return p


_ASSIGN = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(.*?)\s*$")


def parse_tir(text: str) -> dict[str, dict[str, Value]]:
    """Sections of a .tir: {SECTION: {NAME: float or str}} (comment lines and `$` comments left out)."""
    out: dict[str, dict[str, Value]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line[0] in "$!":
            continue
        if line.startswith("[") and "]" in line:
            section = line[1:line.index("]")].strip().upper()
            out.setdefault(section, {})
            continue
        quoted = re.match(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*=\s*'([^']*)'", line)
        if quoted:
            out.setdefault(section, {})[quoted[1].upper()] = quoted[2]
            continue
        m = _ASSIGN.match(line.split("$", 1)[0])
        if m is None:
            continue
        value = m[2].strip()
        try:
            out.setdefault(section, {})[m[1].upper()] = float(value)
        except ValueError:
            out.setdefault(section, {})[m[1].upper()] = value
    return out


def read_tir(path: str | Path) -> dict[str, dict[str, Value]]:
    return parse_tir(Path(path).read_text(encoding="ascii", errors="replace"))


def longitudinal_model(sections: dict[str, dict[str, Value]]) -> LongitudinalMF61:
    """The pure longitudinal MF 6.1 model of a parsed .tir (FNOMIN from [VERTICAL], the coefficients from
    [LONGITUDINAL_COEFFICIENTS], the scaling factors from [SCALING_COEFFICIENTS], 1 where absent)."""
    values: dict[str, float] = {n: 1.0 for n in SCALING_NAMES}
    for sec in ("SCALING_COEFFICIENTS", "LONGITUDINAL_COEFFICIENTS"):
        values |= {k: float(v) for k, v in sections.get(sec, {}).items() if isinstance(v, float)}
    for required in ("PCX1", "PDX1", "PKX1"):
        if required not in values:
            raise ValueError(f"the .tir has no {required} in [LONGITUDINAL_COEFFICIENTS]")
    fnomin = sections.get("VERTICAL", {}).get("FNOMIN")
    if not isinstance(fnomin, float):
        raise ValueError("the .tir has no FNOMIN in [VERTICAL]")
    return LongitudinalMF61.from_values(fnomin, {k: v for k, v in values.items()
                                                 if k in LONGITUDINAL_NAMES or k in SCALING_NAMES})
