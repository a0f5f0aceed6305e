"""Stand-ins for estimate fields that newer logs carry themselves; remove them when every log has the fields.

- `phase` per estimate ("standstill", "accelerate", "cruise", "brake"): when no row of a log has it,
  `derive_phases` classifies each row from its speed and acceleration (the report then debounces either).
- `cx_fit_W_n` / `cx_fit_W_conf` per estimate (an online fitted stiffness and its confidence): when a maneuver's
  rows have none, the report's own least-squares line through the origin over the linear region stands in
  (`summary.analyse_linearity`'s line, confidence as defined there); see `fitted_cx`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from slipdaq.estimator.phase import STANDSTILL_SPEED_MPS, phase_of


def derive_phases(rows: Sequence[dict[str, Any]]) -> list[str | None]:
    """Phase of each row from speed_mps and accel_mps2 by the estimator's rule (`phase_of`); None where neither
    tells (no speed, or no a while moving)."""
    out: list[str | None] = []
    for r in rows:
        v, a = r.get("speed_mps"), r.get("accel_mps2")
        if v is None or (a is None and v >= STANDSTILL_SPEED_MPS):
            out.append(None)
        else:
            out.append(phase_of(v, a))
    return out


def fitted_cx(
    rows: Sequence[dict[str, Any]], wheel: str, line_cx_n: float | None, line_conf: float | None,
) -> tuple[float | None, float | None, str]:
    """(Cx, confidence 0..1, source): the online `cx_fit_<W>_n` of the rows with the highest `cx_fit_<W>_conf`
    (the latest of equals; the latest value when no confidence is given) as "online", else the report's
    linear-region line as "report"."""
    best: tuple[float, float | None] | None = None
    for r in rows:
        cx = r.get(f"cx_fit_{wheel}_n")
        if cx is None:
            continue
        conf = r.get(f"cx_fit_{wheel}_conf")
        if best is None or (conf if conf is not None else -1.0) >= (best[1] if best[1] is not None else -1.0):
            best = (float(cx), conf)
    if best is not None:
        return best[0], best[1], "online"
    return line_cx_n, line_conf, "report"
