"""The report as a page in a real browser: two simulated drives (a paved cycle, a sand brake run; simulator ->
Pipeline -> McapLogSink, in process) reported by `slipdaq report`, opened from disk in headless Chromium (the OS's
package, /usr/bin/chromium, driven by Playwright). Checked: no console error, no request outside the report's
directory, every plot rendered (at least 5 per maneuver), a hover label with a value of the data, the maneuvers table
(a row per maneuver of summary.json, sorting, a row going to its maneuver's plots), the time axes of a maneuver linked,
a legend toggle; the HTML valid and readable without JavaScript. Without the browser the module skips with one
line. (Without a browser, tests/test_report.py checks that the default report imports no matplotlib.)"""

from __future__ import annotations

import contextlib
import json
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.pipeline import Pipeline
from slipdaq.report.labels import labels_metadata
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks.mcap_log import McapLogSink
from support.paths import CONFIG

CHROMIUM = Path(os.environ.get("SLIPDAQ_CHROMIUM", "/usr/bin/chromium"))
try:
    from playwright.sync_api import sync_playwright
except ImportError:
    pytest.skip("report page: Playwright is not installed (pip install -e '.[test]')", allow_module_level=True)
if not CHROMIUM.is_file():
    pytest.skip(f"report page: no Chromium at {CHROMIUM} (apt-get install chromium; tests/run_all.sh does it as root)",
                allow_module_level=True)
DRIVES = (("drive-paved", "cycle", "paved", 16.0, 3), ("drive-sand", "brake", "sand", 14.0, 4))
RENDER_TIMEOUT_MS = 20_000


def _drive(out: Path, scenario: str, road: str, duration_s: float, seed: int) -> Path:
    cfg = load_config(CONFIG)
    sink = McapLogSink(out, cfg, "import", metadata=labels_metadata({"road": road}))
    events = generate(cfg, scenario, road, SimSettings(seed=seed), duration_s=duration_s)
    Pipeline(cfg, [sink]).run(e.record for e in events if e.record is not None)
    sink.close()
    return out


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """`slipdaq report` of the two drives: DIR and its summary.json."""
    d = tmp_path_factory.mktemp("page")
    logs = [_drive(d / f"{name}.mcap", *rest) for name, *rest in DRIVES]
    out = d / "report"
    with open(os.devnull, "w") as quiet, contextlib.redirect_stdout(quiet):
        assert main(["report", *map(str, logs), "-o", str(out)]) == 0
    return {"out": out, "logs": logs, "summary": json.loads((out / "summary.json").read_text())}


def _maneuvers(summary: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    return [(log["log"], m) for log in summary["logs"] for m in log["maneuvers"]]


class Browser:
    """A page of the report in headless Chromium, with every console message, page error and request recorded."""

    def __init__(self, pw: Any, out: Path, javascript: bool = True) -> None:
        self.browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True)
        self.context = self.browser.new_context(viewport={"width": 1400, "height": 900}, java_script_enabled=javascript)
        self.page = self.context.new_page()
        self.console: list[tuple[str, str]] = []
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.console.append((m.type, m.text)))
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.context.on("request", lambda r: self.requests.append(r.url))
        self.page.goto((out / "index.html").as_uri())

    def close(self) -> None:
        self.context.close()
        self.browser.close()


@pytest.fixture(scope="module")
def playwright() -> Iterator[Any]:
    """Playwright's sync API (a skip where the browser is there but does not start)."""
    with sync_playwright() as pw:
        try:
            pw.chromium.launch(executable_path=str(CHROMIUM), headless=True).close()
        except Exception as e:  # the browser is there but cannot start here
            pytest.skip(f"report page: {CHROMIUM} does not start: {str(e).splitlines()[0]}")
        yield pw


@pytest.fixture(scope="module")
def browser(playwright: Any, report: dict[str, Any]) -> Iterator[Browser]:
    """The page with every plot scrolled into view and drawn (or failed: the tests say which)."""
    b = Browser(playwright, report["out"])
    boxes = b.page.locator("[data-slipdaq-plot]")
    for i in range(boxes.count()):
        box = boxes.nth(i)
        box.scroll_into_view_if_needed()
        b.page.wait_for_function("el => ['rendered', 'failed'].includes(el.dataset.state)", arg=box.element_handle(),
                                 timeout=RENDER_TIMEOUT_MS)
    yield b
    b.close()


def _box(name: str) -> str:
    return f'[data-slipdaq-plot="{name}"]'


# ---- rendered, offline, no errors ---------------------------------------------------------------------------------

def test_every_plot_renders_offline_without_errors(browser: Browser, report: dict[str, Any]) -> None:
    page, out = browser.page, report["out"].resolve()
    maneuvers = _maneuvers(report["summary"])
    assert {log for log, _ in maneuvers} == {"drive-paved", "drive-sand"}
    assert [m["phase"] for _, m in maneuvers] == ["accelerate", "cruise", "brake", "cruise", "brake"]
    names = page.eval_on_selector_all("[data-slipdaq-plot]", "els => els.map(e => e.dataset.slipdaqPlot)")
    assert len(names) == len(set(names))
    rendered = set(page.eval_on_selector_all(
        "[data-slipdaq-plot]", "els => els.filter(e => e.querySelector('.main-svg') && e.classList.contains("
        "'js-plotly-plot') && e.dataset.state === 'rendered').map(e => e.dataset.slipdaqPlot)"))
    assert rendered == set(names)
    for log, m in maneuvers:
        plots = set(m["plots"].values())
        assert len(plots) >= 5 and plots <= rendered, (log, m["maneuver"])
        assert all(name.startswith(f"{log}/") for name in plots)
        # the plots draw the maneuver's data (a trace with points): all of them accelerating and braking; cruising
        # has no Cx (no slip to divide by) and no μ fit
        drawn = [name for name in plots if page.eval_on_selector(
            _box(name), "el => el.data.some(t => (t.x || []).some(v => v !== null))")]
        assert len(drawn) >= 5 and (len(drawn) == len(plots) or m["phase"] == "cruise"), (log, m["maneuver"], drawn)
    comparison = [c["plot"] for c in report["summary"]["comparison"]]
    assert comparison and set(comparison) <= rendered
    assert all(log["overview"] in rendered for log in report["summary"]["logs"])
    assert browser.errors == []
    assert [text for kind, text in browser.console if kind == "error"] == []
    outside = [u for u in browser.requests if not u.startswith("file://")
               or not Path(u.removeprefix("file://")).resolve().is_relative_to(out)]
    assert outside == []
    assert any(u.endswith("/plotly.min.js") for u in browser.requests)
    assert len([u for u in browser.requests if u.endswith("/plotly.min.js")]) == 1
    assert not list(out.rglob("*.png"))  # the default: no PNG drawn


def test_high_rate_slip_keeps_every_point_of_a_maneuver(browser: Browser, report: dict[str, Any]) -> None:
    """The slip-time plot of the sand brake has every high-rate row of the maneuver's span (maneuver.figures.span_s)
    of the report's (two-pass) estimation; the whole-log overview is thinned to at most 2 points per time slice."""
    from slipdaq.maneuver.figures import span_s
    from slipdaq.report.build import read_log
    from slipdaq.report.labels import labels_of
    from slipdaq.report.page_compare import OVERVIEW_BUCKETS
    from slipdaq.report.summary import summarize_log

    with open(os.devnull, "w") as quiet:
        data = read_log(report["logs"][1], two_pass=True, progress=quiet)
    log = summarize_log(data.rows, data.metadata, data.diagnostics, path="", name="drive-sand",
                        labels=labels_of(data.metadata), fast=data.fast, sensors=data.sensors)
    m = next(m for m in log.maneuvers if m.phase == "brake")
    t_from, t_to = span_s(m.phase, m.rows)
    times = [r["time_s"] for r in data.fast if t_from <= r["time_s"] <= t_to]
    name = report["summary"]["logs"][1]["maneuvers"][-1]["plots"]["slip-time"]
    assert name == "drive-sand/brake-slip-time"
    got = browser.page.eval_on_selector(_box(name), """el => el.data.filter(t => t.name.endsWith('high-rate'))
                                                         .map(t => t.x.length)""")
    assert got == [len(times)] * 4 and len(times) > 300
    over = browser.page.eval_on_selector(_box("drive-sand/overview"), "el => el.data.map(t => t.x.length)")
    assert all(0 < n <= 2 * OVERVIEW_BUCKETS for n in over)


def test_hover_shows_a_value_of_the_data(browser: Browser, report: dict[str, Any]) -> None:
    page = browser.page
    m = next(m for name, m in _maneuvers(report["summary"]) if name == "drive-paved" and m["phase"] == "accelerate")
    name = m["plots"]["fx-slip"]
    page.locator(_box(name)).scroll_into_view_if_needed()
    where = page.eval_on_selector(_box(name), """el => {
        const t = el.data[0], i = Math.floor(t.x.length / 2), fl = el._fullLayout, r = el.getBoundingClientRect();
        return {px: r.left + fl.xaxis._offset + fl.xaxis.l2p(t.x[i]), py: r.top + fl.yaxis._offset + fl.yaxis.l2p(t.y[i]),
                ys: el.data.filter(d => d.mode === 'markers').flatMap(d => d.y)};
    }""")
    page.mouse.move(where["px"] - 30, where["py"] - 30)
    page.mouse.move(where["px"], where["py"], steps=5)
    label = page.locator(f"{_box(name)} .hoverlayer .hovertext").first
    label.wait_for(timeout=5_000)
    text = label.text_content() or ""
    got = re.search(r"slip (-?\d+\.\d\d) %.*Fx (-?\d+) N", text)
    assert got, text
    assert any(abs(float(got.group(2)) - y) <= 0.5 for y in where["ys"]), text  # a value of the data, to the N


# ---- the maneuvers table ------------------------------------------------------------------------------------------

def test_maneuvers_table_has_a_row_per_maneuver_and_a_row_goes_to_its_plots(browser: Browser,
                                                                             report: dict[str, Any]) -> None:
    page = browser.page
    maneuvers = _maneuvers(report["summary"])
    table = page.locator('table[data-slipdaq-table="maneuvers"]')
    rows = table.locator("tbody tr")
    assert rows.count() == len(maneuvers) == 5
    hrefs = rows.evaluate_all("rs => rs.map(r => r.querySelector('a').getAttribute('href'))")
    assert len(set(hrefs)) == len(maneuvers)
    for href in hrefs:  # each link's target holds the plots of one maneuver of summary.json
        inside = page.eval_on_selector_all(f'[id="{href[1:]}"] [data-slipdaq-plot]',
                                           "els => els.map(e => e.dataset.slipdaqPlot)")
        assert any(set(inside) == set(m["plots"].values()) for _, m in maneuvers), href
    # a click on a row (not on its link) goes to its maneuver: the hash, and its section at the top of the view
    row = rows.nth(4)
    target = row.get_attribute("data-href")
    assert target
    row.locator("td").nth(3).click()
    page.wait_for_function("h => window.location.hash === h", arg=target)
    top = page.eval_on_selector(f'[id="{target[1:]}"]', "el => el.getBoundingClientRect().top")
    assert -5 <= top <= 60
    # sortable: by start time, up then down
    head = table.locator("thead th", has_text="start [s]")
    head.click()
    starts = rows.evaluate_all("rs => rs.map(r => parseFloat(r.cells[4].dataset.v))")
    assert starts == sorted(starts) and head.get_attribute("aria-sort") == "ascending"
    head.click()
    assert rows.evaluate_all("rs => rs.map(r => parseFloat(r.cells[4].dataset.v))") == sorted(starts, reverse=True)


# ---- linked axes, legend ------------------------------------------------------------------------------------------

def test_time_axes_of_a_maneuver_zoom_together_and_a_legend_entry_hides_its_trace(browser: Browser,
                                                                                  report: dict[str, Any]) -> None:
    page = browser.page
    m = next(m for name, m in _maneuvers(report["summary"]) if name == "drive-sand" and m["phase"] == "brake")
    slip, speed = _box(m["plots"]["slip-time"]), _box(m["plots"]["speed-time"])
    page.locator(slip).scroll_into_view_if_needed()
    page.eval_on_selector(slip, "el => Plotly.relayout(el, {'xaxis.range': [5.25, 6.5]})")
    page.wait_for_function("""s => { const r = document.querySelector(s).layout.xaxis.range;
                               return Math.abs(r[0] - 5.25) < 1e-9 && Math.abs(r[1] - 6.5) < 1e-9; }""", arg=speed)
    page.eval_on_selector(speed, "el => Plotly.relayout(el, {'xaxis.autorange': true})")
    page.wait_for_function("s => document.querySelector(s).layout.xaxis.autorange === true", arg=slip)
    fx = _box(m["plots"]["fx-slip"])
    page.locator(fx).scroll_into_view_if_needed()
    page.locator(f"{fx} .legend .traces").first.click()
    page.wait_for_function("s => document.querySelector(s).data[0].visible === 'legendonly'", arg=fx)


# ---- without JavaScript -------------------------------------------------------------------------------------------

def test_html_is_valid_and_readable_without_javascript(playwright: Any, report: dict[str, Any]) -> None:
    import html5lib

    out: Path = report["out"]
    text = (out / "index.html").read_text(encoding="utf-8")
    html5lib.HTMLParser(strict=True).parse(text)  # raises at the first parse error
    ids = re.findall(r'\bid="([^"]+)"', text)
    assert len(ids) == len(set(ids))
    b = Browser(playwright, out, javascript=False)
    try:
        page = b.page
        assert page.locator("noscript").first.count() == 1
        assert "drawn by JavaScript" in page.inner_text("body")
        table = page.locator('table[data-slipdaq-table="maneuvers"]')
        assert table.is_visible() and table.locator("tbody tr").count() == len(_maneuvers(report["summary"]))
        assert not page.locator("[data-slipdaq-plot]").first.is_visible()  # empty plot boxes are not shown
        assert page.locator("text=linear throughout").first.is_visible()
        assert [u for u in b.requests if not u.endswith("/index.html")] == []  # no script loaded
    finally:
        b.close()
