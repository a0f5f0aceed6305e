"""`slipdaq report` on real logs: a paved cycle and a sand brake run made by the real pipeline from simulator
records (offline, as `import`), and a short live demo log; PNGs (`--png`) checked as images, the summary against the
simulator's truth. Plus the pure parts: the linearity rule, the phase fallback, labels and grouping."""

from __future__ import annotations

import asyncio
import contextlib
import csv
import io
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest
from mcap.writer import Writer

from slipdaq import WHEELS
from slipdaq.cli import build_parser, main
from slipdaq.config import load_config
from slipdaq.live.demo import run_demo_async
from slipdaq.logformat.reader import read_metadata
from slipdaq.maneuver import fallback
from slipdaq.maneuver.events import debounce
from slipdaq.maneuver.linearity import analyse_linearity
from slipdaq.offline.run import process_to_log
from slipdaq.report.labels import LabelError, labels_metadata, labels_of, parse_labels
from slipdaq.report.page_data import script
from slipdaq.report.plots import FIG_H_PX, FIG_W_PX, PLOTS
from slipdaq.report.summary import group_of, summarize_log
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.vehicle import ACCEL_MPS2, DECEL_MPS2, ROADS, force_shares, static_loads_n
from support.paths import CONFIG

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _sim_log(cfg, out: Path, scenario: str, road: str, duration_s: float, labels: dict[str, str], seed: int) -> Path:  # type: ignore[no-untyped-def]
    records = (ev.record for ev in generate(cfg, scenario, road, SimSettings(seed=seed), duration_s=duration_s)
               if ev.record is not None)
    with open(os.devnull, "w") as quiet:
        process_to_log(cfg, records, out, "import", metadata=labels_metadata(labels), stream=quiet)
    return out


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """Three logs (paved cycle, sand brake, 8 s live demo) and one `slipdaq report --png` over them."""
    d = tmp_path_factory.mktemp("report")
    cfg = load_config(CONFIG)
    paved = _sim_log(cfg, d / "cycle-paved.mcap", "cycle", "paved", 16.0, {"road": "paved"}, seed=3)
    sand = _sim_log(cfg, d / "brake-sand.mcap", "brake", "sand", 14.0, {"road": "sand", "maneuver": "brake"}, seed=4)
    with open(os.devnull, "w") as quiet:
        result, _, _ = asyncio.run(run_demo_async(8.0, "cycle", "paved", d / "demo", status_stream=quiet,
                                                  labels={"driver": "sim"}))
    demo = result.log_path
    out = d / "out"
    progress = io.StringIO()
    with contextlib.redirect_stdout(progress):
        rc = main(["report", str(paved), str(sand), str(demo), "-o", str(out), "--png"])
    return {"cfg": cfg, "paved": paved, "sand": sand, "demo": demo, "out": out, "rc": rc,
            "progress": progress.getvalue().splitlines()}


def _summary(report):  # type: ignore[no-untyped-def]
    return json.loads((report["out"] / "summary.json").read_text())


def _row(rows: list[dict], log: str, phase: str, wheel: str) -> dict:
    (r,) = [r for r in rows if r["log"] == log and r["phase"] == phase and r["wheel"] == wheel]
    return r


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, f"{path} is not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


# ---- the report over real logs -----------------------------------------------------------------------------

def test_report_writes_every_plot_as_a_real_png_of_the_fixed_size(report) -> None:  # type: ignore[no-untyped-def]
    assert report["rc"] == 0
    out: Path = report["out"]
    summary = _summary(report)
    maneuvers = {log["log"]: [m["phase"] for m in log["maneuvers"]] for log in summary["logs"]}
    demo = report["demo"].stem
    assert maneuvers["cycle-paved"] == ["accelerate", "cruise", "brake"]
    assert maneuvers["brake-sand"] == ["cruise", "brake"]
    assert "accelerate" in maneuvers[demo]
    expected = [out / log / f"{phase}-{stem}.png" for log, phases in maneuvers.items() for phase in phases
                for stem, _ in PLOTS]
    expected += [out / f"compare-{p}-fx-slip.png" for p in ("accelerate", "cruise", "brake")]
    assert len(expected) == len(PLOTS) * (3 + 2 + len(maneuvers[demo])) + 3 and len(PLOTS) == 6
    for png in expected:
        assert png.is_file(), png
        assert _png_size(png) == (FIG_W_PX, FIG_H_PX) == (800, 600)
        assert 5_000 < png.stat().st_size < 300_000
    assert sorted(out.rglob("*.png")) == sorted(expected)  # nothing else
    import matplotlib.image

    img = matplotlib.image.imread(out / "cycle-paved" / "accelerate-fx-slip.png")
    assert img.shape[:2] == (600, 800)
    assert float(np.std(img[..., :3])) > 0.05  # drawn, not blank
    # the wheel colours are in it: FL blue #1f77b4 and FR orange #ff7f0e points
    rgb = (img[..., :3] * 255).round().astype(int).reshape(-1, 3)
    for color in ((0x1F, 0x77, 0xB4), (0xFF, 0x7F, 0x0E)):
        assert np.any(np.all(np.abs(rgb - color) <= 3, axis=1))


def test_index_html_shows_every_png_offline(report) -> None:  # type: ignore[no-untyped-def]
    out: Path = report["out"]
    html = (out / "index.html").read_text()
    srcs = set(re.findall(r'<img src="([^"]+)"', html))
    pngs = {p.relative_to(out).as_posix() for p in out.rglob("*.png")}
    assert srcs == pngs
    assert all(not s.startswith(("/", "http")) for s in srcs)  # relative links, nothing online
    assert "http://" not in html and "https://" not in html
    assert 'href="summary.csv"' in html and 'href="summary.json"' in html
    for text in ("cycle-paved (road=paved)", "brake-sand (maneuver=brake, road=sand)", "accelerate 0–60 km/h",
                 "brake 90–0 km/h", "linear throughout", "Comparison by labels"):
        assert text in html, text


def test_summary_json_and_csv_have_a_row_per_log_maneuver_and_wheel(report) -> None:  # type: ignore[no-untyped-def]
    out: Path = report["out"]
    summary = _summary(report)
    rows = summary["rows"]
    with open(out / "summary.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows) == 4 * sum(len(log["maneuvers"]) for log in summary["logs"])
    assert list(table[0]) == summary["columns"]
    for r, c in zip(rows, table):
        assert c["log"] == r["log"] and c["wheel"] == r["wheel"] and c["maneuver"] == r["maneuver"]
        for key in ("mean_re_m", "cx_fit_n", "peak_linear_fx_n"):
            assert (c[key] == "") == (r[key] is None)
            if r[key] is not None:
                assert float(c[key]) == pytest.approx(r[key])
    keys = {(r["log"], r["maneuver"]) for r in rows}
    assert ("cycle-paved", "accelerate 0–60 km/h") in keys and ("brake-sand", "brake 90–0 km/h") in keys
    for r in rows:
        assert r["lost_frames"] == 0 and r["bad_sentences"] == 0  # the simulator loses nothing
        assert r["r0_m"] is not None and r["gps_latency_s"] is not None


def test_summary_values_match_the_simulator_truth(report) -> None:  # type: ignore[no-untyped-def]
    cfg = report["cfg"]
    rows = _summary(report)["rows"]
    fz = static_loads_n(cfg.vehicle.mass_kg)
    drive, brake = force_shares(cfg.vehicle.driven_axle, cfg.vehicle.brake_front_share)
    r0 = cfg.tire.radius_m
    for log, phase in (("cycle-paved", "cruise"), ("brake-sand", "cruise")):
        for w in WHEELS:
            assert abs(_row(rows, log, phase, w)["mean_re_m"] - r0) < 0.001, (log, w)
    # paved accelerate: front (driven) wheels
    tire = ROADS["paved"]
    for w in ("FL", "FR"):
        r = _row(rows, "cycle-paved", "accelerate", w)
        truth_cx = tire.stiffness_n(fz[w])  # the initial slope of the simulator's tire curve
        f_truth = cfg.vehicle.mass_kg * ACCEL_MPS2["paved"] * drive[w]
        s_truth = tire.slip_for_force(f_truth, fz[w])
        # the line through the origin is the secant at the working point (Pacejka: below the initial slope)
        assert 0.90 * truth_cx < r["cx_line_n"] < truth_cx, r["cx_line_n"]
        assert r["cx_line_n"] == pytest.approx(f_truth / s_truth, rel=0.05)
        assert 0.80 * truth_cx < r["cx_fit_n"] < 1.20 * truth_cx, (r["cx_fit_n"], r["cx_fit_source"])
        assert 0 < r["cx_fit_conf"] <= 1
        assert r["linearity"] == "linear throughout" and r["linear_end_slip"] is None  # no end invented
        assert f_truth <= r["peak_linear_fx_n"] < 1.25 * f_truth
        assert abs(r["peak_linear_fx_slip"] - s_truth) < 0.005
        assert r["mean_slip"] > 0.01
    for w in ("RL", "RR"):  # undriven: no force, no line
        r = _row(rows, "cycle-paved", "accelerate", w)
        assert r["cx_line_n"] is None and r["linearity"] == "no force–slip points"
    # sand braking: every wheel brakes
    tire = ROADS["sand"]
    for w in WHEELS:
        r = _row(rows, "brake-sand", "brake", w)
        truth_cx = tire.stiffness_n(fz[w])
        f_truth = -cfg.vehicle.mass_kg * DECEL_MPS2["sand"] * brake[w]
        s_truth = tire.slip_for_force(f_truth, fz[w])
        assert 0.85 * truth_cx < r["cx_line_n"] < truth_cx, (w, r["cx_line_n"])
        assert r["cx_line_n"] == pytest.approx(f_truth / s_truth, rel=0.05)
        assert 0.80 * truth_cx < r["cx_fit_n"] < 1.20 * truth_cx, (w, r["cx_fit_n"], r["cx_fit_source"])
        assert r["linearity"] == "linear throughout"
        assert 1.25 * f_truth < r["peak_linear_fx_n"] <= f_truth  # negative: braking
        assert abs(r["peak_linear_fx_slip"] - s_truth) < 0.006
        assert r["mean_re_m"] > r0  # braking: the wheel turns slower, Re = V/omega grows
        assert abs(r["gps_latency_s"]) < 0.05  # the simulator sends with no latency


def test_comparison_groups_logs_by_label(report) -> None:  # type: ignore[no-untyped-def]
    summary = _summary(report)
    groups = {log["log"]: log["group"] for log in summary["logs"]}
    demo = report["demo"].stem
    assert groups == {"cycle-paved": "road=paved", "brake-sand": "road=sand", demo: "driver=sim, road=paved"}
    labels = {log["log"]: log["labels"] for log in summary["logs"]}
    assert labels[demo] == {"driver": "sim", "maneuver": "cycle", "road": "paved"}  # demo metadata -> labels
    brake = next(c for c in summary["comparison"] if c["phase"] == "brake")
    assert [g["group"] for g in brake["groups"]] == ["road=paved", "road=sand"]
    paved, sand = brake["groups"]
    assert paved["logs"] == ["cycle-paved"] and sand["logs"] == ["brake-sand"]
    assert paved["wheels"]["FL"]["cx_fit_n"] > 1.5 * sand["wheels"]["FL"]["cx_fit_n"]  # paved is stiffer
    assert brake["plot"] == "compare-brake-fx-slip" and brake["png"] == "compare-brake-fx-slip.png"


def test_report_progress_lines_and_group_by(report, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    lines = report["progress"]
    assert lines[0].startswith("report: read ") and lines[0].endswith(" estimates (two-pass)")
    assert "report: brake-sand: brake 90–0 km/h: 7 plots" in lines
    assert "report: brake-sand: brake 90–0 km/h: 6 PNGs" in lines
    assert "report: comparison brake: road=paved, road=sand" in lines
    assert lines[-1].startswith("report: wrote ") and "index.html" in lines[-1]
    out = tmp_path / "r"
    assert main(["report", str(report["demo"]), "--group-by", "road", "--group-by", "tire", "-o", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [log["group"] for log in summary["logs"]] == ["road=paved, tire=–"]
    assert summary["comparison"] == []  # one log: nothing to compare
    assert not list(out.rglob("*.png"))  # without --png: none
    # the page: plotly.js written once (the package's own file), the log's plot data beside it, nothing online
    import plotly.offline

    assert (out / "plotly.min.js").read_text(encoding="utf-8") == plotly.offline.get_plotlyjs()
    demo = report["demo"].stem
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.js")) == sorted(
        [f"{demo}/plots.js", "plotly.min.js", "slipdaq-report.js"])
    html = (out / "index.html").read_text()
    assert "http://" not in html and "https://" not in html
    assert html.count('data-slipdaq-table="maneuvers"') == 1 and "<noscript>" in html


def test_default_report_and_batch_task_import_no_matplotlib(report, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """`report` and a batch task (fleet.process_log) draw no PNG and never import matplotlib (a fresh interpreter)."""
    log = str(report["paved"])
    code = (
        "import sys\n"
        "from slipdaq.cli import main\n"
        "from slipdaq.fleet.batch import Job, process_log\n"
        f"assert main(['report', {log!r}, '-o', {str(tmp_path / 'r')!r}]) == 0\n"
        f"r = process_log(Job({log!r}, 'x', '0' * 16, {log!r}))\n"
        "assert r.error is None and not r.pngs and r.page is not None, r.error\n"
        "assert 'matplotlib' not in sys.modules, 'matplotlib imported'\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert not list((tmp_path / "r").rglob("*.png"))


def test_a_logs_plots_script_is_its_figures_as_json_writes_them(report) -> None:  # type: ignore[no-untyped-def]
    """Each log's plots.js is `slipdaqReport.add(FIGURES);` with FIGURES the bytes `json.dumps` gives the figures
    (compact, UTF-8 unescaped), every plot of the log in it."""
    for log in ("cycle-paved", "brake-sand"):
        text = (report["out"] / log / "plots.js").read_bytes()
        head, tail = b"slipdaqReport.add(", b");\n"
        assert text.startswith(head) and text.endswith(tail)
        body = text[len(head):-len(tail)]
        figures = json.loads(body)
        assert body == json.dumps(figures, ensure_ascii=False, separators=(",", ":"), allow_nan=False).encode()
        names = {n for m in next(x for x in _summary(report)["logs"] if x["log"] == log)["maneuvers"]
                 for n in m["plots"].values()}
        assert names and names <= set(figures) and all(figures[n]["data"] is not None for n in names)


def test_the_plots_script_writes_text_numbers_and_nan_as_the_page_reads_them() -> None:
    """Text unescaped but for JSON's own escapes, numbers (numpy's too) read back as they were, NaN as null."""
    figures = {"a/b": {"data": [{"x": [0.0, -0.0, 1.5, np.float64(2.25), None, float("nan"), 1e-05, 12345678901],
                                 "name": 'FL – μ "q" \\ <br>\n'}], "layout": {"title": {"text": "Fx–s"}}}}
    got = script(figures)
    assert got.startswith(b"slipdaqReport.add(") and got.endswith(b");\n")
    back = json.loads(got[len(b"slipdaqReport.add("):-len(b");\n")])
    assert back["a/b"]["data"][0]["x"] == [0.0, -0.0, 1.5, 2.25, None, None, 1e-05, 12345678901]
    assert back["a/b"]["data"][0]["name"] == figures["a/b"]["data"][0]["name"]
    assert "FL – μ".encode() in got and b'\\"q\\"' in got


def test_report_of_a_file_that_is_not_a_slipdaq_log_is_one_line_exit_1(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    text = tmp_path / "notes.mcap"
    text.write_text("not an mcap file\n")
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start(profile="other", library="test")
        w.add_metadata("something", {"a": "b"})
        w.finish()
    for bad in (text, foreign, tmp_path / "missing.mcap"):
        assert main(["report", str(bad), "-o", str(tmp_path / "out")]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("slipdaq: ") and str(bad) in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()  # nothing written for a bad input


# ---- labels on run, import and demo ------------------------------------------------------------------------

def test_import_stores_labels_in_the_metadata(cfg, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    can_path, nmea_path = tmp_path / "drive.log", tmp_path / "drive.nmea"
    with can.Logger(str(can_path)) as writer, open(nmea_path, "w") as nmea:
        for ev in generate(cfg, "accelerate", "sand", SimSettings(), duration_s=2.0):
            r = ev.record
            if hasattr(r, "arbitration_id"):
                writer(can.Message(timestamp=r.timestamp_s, arbitration_id=r.arbitration_id, data=r.data,
                                   is_extended_id=False, channel="vcan0"))
            elif r is not None:
                nmea.write(f"({r.timestamp_s:.6f}) {r.line}\n")
    out = tmp_path / "x.mcap"
    assert main(["import", "--can", str(can_path), "--nmea", str(nmea_path), "--config", str(CONFIG), "-o", str(out),
                 "--label", "road=sand", "--label", "maneuver=accelerate"]) == 0
    meta = read_metadata(out)
    assert meta["label.road"] == "sand" and meta["label.maneuver"] == "accelerate" and meta["mode"] == "import"
    assert labels_of(meta) == {"maneuver": "accelerate", "road": "sand"}


def test_label_option_on_run_import_and_demo(capsys) -> None:  # type: ignore[no-untyped-def]
    parser = build_parser()
    for verb in (["run"], ["demo"], ["import", "--can", "a", "--nmea", "b", "-o", "c"]):
        args = parser.parse_args(verb + ["--label", "road=sand", "--label", "note=wet, 5 °C"])
        assert parse_labels(args.label) == {"road": "sand", "note": "wet, 5 °C"}
    with pytest.raises(SystemExit) as e:
        parser.parse_args(["run", "--label", "no-equals-sign"])
    assert e.value.code == 2 and "KEY=VALUE" in capsys.readouterr().err
    with pytest.raises(LabelError, match="twice"):
        parse_labels(["road=sand", "road=paved"])
    assert labels_metadata({"road": "sand"}) == {"label.road": "sand"}


# ---- pure parts ---------------------------------------------------------------------------------------------

def test_linearity_ends_where_the_force_saturates() -> None:
    """Fx = Cx·s up to 15 % slip, flat beyond: 10 % below the line from s = 0.15/0.9 = 16.7 %."""
    s = np.linspace(0.005, 0.30, 300)
    f = 50_000.0 * np.minimum(s, 0.15)
    lin = analyse_linearity(s.tolist(), f.tolist())
    assert lin.line is not None and lin.line.cx_n == pytest.approx(50_000.0)
    assert lin.end_slip is not None and 0.17 <= lin.end_slip < 0.18  # the first 1 % bin below the line
    assert lin.peak_fx_n == pytest.approx(7_500.0) and lin.peak_fx_slip == pytest.approx(0.15, abs=0.002)
    assert lin.verdict == "ends at 17.5 % slip"
    # braking: the same, mirrored
    neg = analyse_linearity((-s).tolist(), (-f).tolist())
    assert neg.end_slip == pytest.approx(-lin.end_slip) and neg.peak_fx_n == pytest.approx(-7_500.0)


def test_linearity_of_a_pacejka_curve_refits_below_the_end() -> None:
    tire = ROADS["sand"]
    s = np.linspace(0.005, 0.30, 300)
    f = [tire.force_n(x, 3000.0) for x in s]
    lin = analyse_linearity(s.tolist(), f)
    assert lin.end_slip is not None and lin.end_slip < tire.peak_slip
    assert lin.end_force_n < 0.9 * lin.line.force_n(lin.end_slip)
    assert lin.line.points < sum(s <= 0.10)  # refitted on the points below the end only
    assert 0.75 * tire.stiffness_n(3000.0) < lin.line.cx_n < tire.stiffness_n(3000.0)


def test_noisy_cluster_in_the_linear_region_is_linear_throughout() -> None:
    rng = np.random.default_rng(1)
    s = 0.026 + rng.normal(0.0, 0.002, 200)
    f = 72_000.0 * 0.026 + rng.normal(0.0, 120.0, 200)
    lin = analyse_linearity(s.tolist(), f.tolist())
    assert lin.verdict == "linear throughout" and lin.end_slip is None
    assert lin.line.cx_n == pytest.approx(72_000.0, rel=0.03) and lin.line.confidence > 0.9
    assert analyse_linearity([0.03, None, 0.02], [0.0, 10.0, None]).verdict == "no force–slip points"
    assert analyse_linearity([0.03, 0.02], [100.0, 80.0]).verdict == "too few points"


def test_phase_fallback_and_fitted_cx_fallback() -> None:
    speeds = [0.0] * 5 + [1.0 + i for i in range(10)] + [11.0] * 10 + [11.0 - i for i in range(10)]
    accels = [0.0] * 5 + [2.5] * 10 + [0.05, 0.1, -0.4, 0.1, 0.0, -0.1, 0.2, 0.0, 0.1, 0.0] + [-4.0] * 10
    rows = [{"speed_mps": v, "accel_mps2": a} for v, a in zip(speeds, accels)]
    phases = debounce(fallback.derive_phases(rows))
    assert phases == ["standstill"] * 5 + ["accelerate"] * 10 + ["cruise"] * 10 + ["brake"] * 10  # -0.4 merged
    rows = [{"cx_fit_FL_n": None}, {"cx_fit_FL_n": 60_000.0, "cx_fit_FL_conf": 0.8},
            {"cx_fit_FL_n": 90_000.0, "cx_fit_FL_conf": 0.1}, {"cx_fit_FL_n": None}]
    assert fallback.fitted_cx(rows, "FL", 50_000.0, 0.9) == (60_000.0, 0.8, "online")  # the most confident
    assert fallback.fitted_cx(rows, "FR", 50_000.0, 0.9) == (50_000.0, 0.9, "report")
    # rows that carry their own phase are taken as they are (a lone row of another phase is noise)
    own = ["brake"] * 3 + ["accelerate"] + ["brake"] * 3
    log = summarize_log(
        [{"time_s": float(i), "speed_mps": 10.0, "accel_mps2": 0.0, "phase": p, "slip_FL": -0.01,
          "force_FL_n": -500.0} for i, p in enumerate(own)],
        {}, None, path="x", name="x", labels={})
    assert [m.phase for m in log.maneuvers] == ["brake"] and len(log.maneuvers[0].rows) == 7


def test_labels_and_groups() -> None:
    assert labels_of({"label.road": "sand", "mode": "live", "demo_road": "paved"}) == {"road": "sand"}
    assert labels_of({"demo_road": "paved", "demo_scenario": "cycle"}) == {"maneuver": "cycle", "road": "paved"}
    assert group_of({"maneuver": "brake", "road": "sand"}) == "road=sand"
    assert group_of({}) == "(no labels)"
    assert group_of({"road": "sand", "tire": "A"}, ["tire"]) == "tire=A"
    assert group_of({"road": "sand"}, ["tire"]) == "tire=–"
