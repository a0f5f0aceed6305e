"""The page's test-set tables (per log, per label group) and the differences between groups (HTML)."""

from __future__ import annotations

from collections.abc import Sequence
from html import escape
from typing import Any

from slipdaq.maneuver.test_set import MAIN_FIGURE, excluded_text
from slipdaq.report.page_tables import fmt
from slipdaq.sinks.maneuver_text import MAIN_UNIT

_SCALE = {"cx_line_n": (1e-3, 1, "kN"), "mean_slip": (100.0, 2, "%"), "mu_peak": (1.0, 3, ""),
          "mfdd_mps2": (1.0, 2, "m/s²"), "stopping_distance_corrected_m": (1.0, 2, "m"),
          "brake_speed_kmh": (1.0, 1, "km/h"), "time_to_speed_s": (1.0, 2, "s")}


def _interval(lo: Any, hi: Any, scale: float, digits: int) -> str:
    return "–" if lo is None or hi is None else f"[{fmt(lo, scale, digits)}, {fmt(hi, scale, digits)}]"


def sets_table(records: Sequence[dict[str, Any]], scope: str = "") -> str:
    """One row per set: runs, ok or why not, its main figure's mean, 95 % interval and CV, the MFDD, the runs
    excluded and why."""
    if not records:
        return ""
    out = [f'<table class="sets"><caption>Test sets{escape(scope)}</caption><thead><tr><th class=l>set</th>'
           "<th>runs</th><th class=l>ok</th><th class=l>main figure</th><th>mean</th><th>95 % interval</th>"
           "<th>CV %</th><th>MFDD m/s²</th><th class=l>excluded</th></tr></thead><tbody>"]
    for r in records:
        main = MAIN_FIGURE[r["kind"]]
        verdict = "ok" if r["ok"] else "not ok: " + "; ".join(r["reasons"])
        out.append(
            f"<tr><td class=l>{escape(r['procedure'])}</td><td>{r['runs_valid']} of {r['runs_required']}</td>"
            f"<td class=l>{escape(verdict)}</td><td class=l>{escape(main)} [{MAIN_UNIT[r['kind']]}]</td>"
            f"<td>{fmt(r.get(main + '_mean'), digits=2)}</td>"
            f"<td>{_interval(r.get(main + '_ci_lo'), r.get(main + '_ci_hi'), 1.0, 2)}</td>"
            f"<td>{fmt(r.get(main + '_cv_percent'), digits=1)}</td><td>{fmt(r.get('mfdd_mps2_mean'), digits=2)}</td>"
            f"<td class=l>{escape('; '.join(excluded_text(r['excluded'])))}</td></tr>")
    out.append("</tbody></table>")
    return "\n".join(out)


def differences_table(rows: Sequence[dict[str, Any]]) -> str:
    """Per figure and pair of groups: each group's mean [95 %], the difference [95 %, Welch]; bold where the
    difference's interval excludes zero."""
    if not rows:
        return ""
    out = ['<table class="differences"><thead><tr><th class=l>of</th><th class=l>figure</th><th>wheel</th>'
           "<th class=l>group A</th><th>n</th><th>mean A [95 %]</th><th class=l>group B</th><th>n</th>"
           "<th>mean B [95 %]</th><th>A − B [95 %]</th></tr></thead><tbody>"]
    for d in rows:
        scale, digits, unit = _SCALE.get(d["figure"], (1.0, 3, ""))
        of = d["procedure"] or f"every valid {d['kind']}"
        diff = f"{fmt(d['difference'], scale, digits)} {_interval(d['ci_lo'], d['ci_hi'], scale, digits)}"
        out.append(
            f"<tr><td class=l>{escape(of)}</td><td class=l>{escape(d['figure'])}{' [' + unit + ']' if unit else ''}"
            f"</td><td>{escape(d['wheel'] or '')}</td><td class=l>{escape(d['group_a'])}</td><td>{d['n_a']}</td>"
            f"<td>{fmt(d['mean_a'], scale, digits)} {_interval(d['mean_a_ci'][0], d['mean_a_ci'][1], scale, digits)}</td>"
            f"<td class=l>{escape(d['group_b'])}</td><td>{d['n_b']}</td>"
            f"<td>{fmt(d['mean_b'], scale, digits)} {_interval(d['mean_b_ci'][0], d['mean_b_ci'][1], scale, digits)}</td>"
            + (f"<td><b>{diff}</b> ≠ 0</td>" if d["excludes_zero"] else f"<td>{diff}</td>") + "</tr>")
    out.append("</tbody></table>")
    return "\n".join(out)
