"""The Magic Formula tire file from the road (tire_model/): the MF 6.1 evaluator against a published .tir and an
independent evaluator's values for it, the .tir written and read back, and the fit."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq.cli import main
from slipdaq.config import Config
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.logformat.reader import iter_topic
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.maneuver.record import Z95
from slipdaq.offline.run import Rows
from slipdaq.pipeline import Pipeline
from slipdaq.report.build import make_report, read_log
from slipdaq.report.summary import detect_maneuvers, summarize_log
from slipdaq.report.tires import ThreadFits, fit_here, tire_jobs
from slipdaq.sim.emit import generate
from slipdaq.sim.scenarios import limiting_axle
from slipdaq.sim.vehicle import ROADS, TireModel
from slipdaq.tire_model import fit as fit_module
from slipdaq.tire_model.files import build_tire, static_load_n
from slipdaq.tire_model.fit import MF61Fit, fit_mf61
from slipdaq.tire_model.mf61 import JACOBIAN_NAMES, Fx0Terms, LongitudinalMF61
from slipdaq.tire_model.tir_file import TireFile, longitudinal_model, parse_tir, read_tir, tir_text, write_tir
from support.paths import DATA, ROOT

MF_DATA = DATA / "tyredyn-mf"
RAV4 = DATA / "rav4-comma2k19"


def test_the_evaluator_gives_an_independent_evaluators_fx0_on_a_published_tir() -> None:
    """TyreDyn's car205_60R19.tir (MF 6.2 file at its nominal pressure: Fx0 is MF 6.1's) with every longitudinal
    shift and load term nonzero; Fx0 at 33 (slip, load) points as TyreDyn computed it (tests/data/README), to 1e-6 N."""
    model = longitudinal_model(read_tir(MF_DATA / "car205_60R19.tir"))
    assert model.fnomin == 4000.0 and model.pkx3 == -0.4119 and model.phx2 == 0.0011538
    ref = np.loadtxt(MF_DATA / "car205_60R19_fx0.csv", delimiter=",", comments="#")
    assert ref.shape == (33, 3)
    got = model.fx0(ref[:, 0], ref[:, 1])
    np.testing.assert_allclose(got, ref[:, 2], rtol=0, atol=1e-6)
    # the slope at kx = 0 is Kxk (4.E15): PKX1·Fz at the nominal load
    assert model.slip_stiffness(4000.0) == pytest.approx(21.69 * 4000.0)
    h = 1e-6
    shx = model.phx1  # at FNOMIN
    slope = (model.fx0(-shx + h, 4000.0) - model.fx0(-shx - h, 4000.0)) / (2 * h)
    assert float(slope) == pytest.approx(21.69 * 4000.0, rel=1e-6)


def test_a_written_tir_reads_back_to_the_same_curve(tmp_path: Path) -> None:
    model = LongitudinalMF61(fnomin=3500.0, pcx1=1.6, pdx1=1.17, pkx1=24.0, pdx2=-0.05, pex1=0.2, pkx2=2.0)
    tire = TireFile(model, unloaded_radius_m=0.3071, width_m=0.195, aspect_ratio=0.6, rim_radius_m=0.1905,
                    slip_min=-0.31, slip_max=0.02, notes={"PEX4": "no driving data"}, slipdaq=["log: x.mcap"])
    path = write_tir(tmp_path / "FL.tir", tire)
    sections = read_tir(path)
    assert sections["MODEL"]["FITTYP"] == 61.0 and sections["MDI_HEADER"]["FILE_TYPE"] == "tir"
    assert sections["LONG_SLIP_RANGE"] == {"KPUMIN": -0.31, "KPUMAX": 0.02}
    assert sections["DIMENSION"]["UNLOADED_RADIUS"] == 0.3071 and sections["VERTICAL"]["FNOMIN"] == 3500.0
    assert all(v == 1.0 for v in sections["SCALING_COEFFICIENTS"].values()) and len(sections["SCALING_COEFFICIENTS"]) == 25
    # every MF 6.1 section an evaluator reads, the unmeasured ones neutral: no lateral friction, no moments
    for sec in ("INERTIA", "STRUCTURAL", "CONTACT_PATCH", "INFLATION_PRESSURE_RANGE", "VERTICAL_FORCE_RANGE",
                "SLIP_ANGLE_RANGE", "INCLINATION_ANGLE_RANGE", "OVERTURNING_COEFFICIENTS", "LATERAL_COEFFICIENTS",
                "ROLLING_COEFFICIENTS", "ALIGNING_COEFFICIENTS"):
        assert sections[sec], sec
    assert sections["LATERAL_COEFFICIENTS"]["PDY1"] == 0.0 and sections["LONGITUDINAL_COEFFICIENTS"]["RBX1"] == 0.0
    assert sections["ALIGNING_COEFFICIENTS"]["QDZ1"] == 0.0 and sections["ROLLING_COEFFICIENTS"]["QSY1"] == 0.0
    back = longitudinal_model(sections)
    assert back == model
    k = np.linspace(-0.3, 0.02, 50)
    np.testing.assert_array_equal(back.fx0(k, 4200.0), model.fx0(k, 4200.0))
    text = path.read_text()
    assert "$   log: x.mcap" in text and "no driving data" in text
    assert parse_tir(tir_text(tire)) == sections


TRUTH = TireModel.with_peak(1.17, 0.17, TireModel.C)
"""The ABS stop's tire: peak mu 1.17 at 17 % slip (the simulator's curve, shape C 1.65)."""


@pytest.fixture(scope="module")
def abs_stop() -> tuple[ManeuverSummary, Config]:
    """brake-abs from 80 km/h with the front axle at its limit (benchmarks/maneuvers.py's front-limited stop), on
    TRUTH; the stop as the report summarizes it."""
    ROADS["tire 1.17 at 17 %"] = TRUTH
    cfg = demo_config("/dev/null", "chan", "brake-abs")
    share = next(x for x in (0.85, 0.9, 0.95)
                 if limiting_axle(TRUTH.mu, cfg.with_overrides(vehicle={"brake_front_share": x}).vehicle) == "front")
    cfg = cfg.with_overrides(vehicle={"brake_front_share": share})
    rows = Rows()
    events = generate(cfg, "brake-abs", "tire 1.17 at 17 %", demo_settings("brake-abs"), 14.0)  # type: ignore[arg-type]
    Pipeline(cfg, [rows]).run(e.record for e in events if e.record is not None)
    (stop,) = [m for m in detect_maneuvers(rows.rows, cfg, fast=rows.fast, sensors=rows.sensors) if m.phase == "brake"]
    return stop, cfg


@pytest.mark.parametrize("wheel", ["FL", "FR"])
def test_the_tir_of_an_abs_stops_tire_gives_the_tires_force(abs_stop: tuple[ManeuverSummary, Config], wheel: str,
                                                            tmp_path: Path) -> None:
    """The front tire's .tir, written and read back, evaluated by the MF 6.1 evaluator at the stop's mean front load:
    Fx within 5 % of the truth tire's from 2 % to 25 % slip, the peak within 5 % and 2 points of slip, the slip
    stiffness within 5 % of the truth's Cx; the range it holds for is what the stop covered."""
    stop, cfg = abs_stop
    got = build_tire(wheel, [("abs.mcap", stop)], cfg.vehicle, cfg.tire)
    assert got.file is not None and got.fit is not None and got.fit.peak_passed
    model = longitudinal_model(read_tir(write_tir(tmp_path / f"{wheel}.tir", got.file)))
    fz = float(np.mean(stop.mu_loads[wheel]))
    assert model.fnomin == pytest.approx(static_load_n(wheel, cfg.vehicle)) and fz > 1.1 * model.fnomin
    k = -np.linspace(0.02, 0.25, 47)
    truth = np.array([TRUTH.force_n(x, fz) for x in k])
    assert np.max(np.abs(model.fx0(k, fz) / truth - 1.0)) <= 0.05
    peak_n, peak_slip = model.peak(fz, -1.0)
    assert peak_n == pytest.approx(TRUTH.mu * fz, rel=0.05)
    assert abs(peak_slip - TRUTH.peak_slip) <= 0.02
    assert float(model.slip_stiffness(fz)) == pytest.approx(TRUTH.stiffness_n(fz), rel=0.05)
    slips = stop.mu_points[wheel][0]
    assert got.file.slip_min <= -0.25 and got.file.slip_min >= float(np.min(slips)) - 1e-4
    assert 0.0 <= got.file.slip_max <= max(float(np.max(slips)), 0.0) + 1e-4
    text = (tmp_path / f"{wheel}.tir").read_text()
    assert "peak passed" in text and "load dependence" in text and text.isascii()


@pytest.fixture(scope="module")
def rav4(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rav4") / "rav4.mcap"
    assert main(["import", "--can", str(RAV4 / "rav4_bus0.candump.log"), "--nmea", str(RAV4 / "rav4_ublox.nmea"),
                 "--config", str(ROOT / "config" / "examples" / "rav4-comma2k19.toml"), "-o", str(out)]) == 0
    return out


def test_a_real_drive_gives_valid_tir_files_limited_to_its_slip(rav4: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """The RAV4's highway drive (slip within a few %, no peak): export --tir writes FL..RR.tir, each a valid MF 6.1
    file (FITTYP 61, every section, finite coefficients, the calibrated r0, the tire size's width and rim) whose
    KPUMIN/KPUMAX are the slip the drive covered, and which says that the peak was not passed."""
    out = tmp_path / "tires"
    assert main(["export", str(rav4), "--tir", str(out)]) == 0
    assert "peak not passed" in capsys.readouterr().out
    fast = [r for _, _, r in iter_topic(rav4, ("/slip/fast",))]
    for w in ("FL", "FR", "RL", "RR"):
        sections = read_tir(out / f"{w}.tir")
        assert sections["MODEL"]["FITTYP"] == 61.0
        for sec in ("MDI_HEADER", "UNITS", "DIMENSION", "OPERATING_CONDITIONS", "VERTICAL", "LONG_SLIP_RANGE",
                    "SCALING_COEFFICIENTS", "LONGITUDINAL_COEFFICIENTS", "LATERAL_COEFFICIENTS"):
            assert sections[sec], sec
        assert sections["DIMENSION"]["UNLOADED_RADIUS"] == pytest.approx(0.36215 / 0.991, abs=0.0015)
        assert sections["DIMENSION"]["WIDTH"] == 0.225 and sections["DIMENSION"]["RIM_RADIUS"] == pytest.approx(0.2159)
        lo, hi = sections["LONG_SLIP_RANGE"]["KPUMIN"], sections["LONG_SLIP_RANGE"]["KPUMAX"]
        slips = np.array([r[f"slip_{w}"] for r in fast if r.get(f"slip_{w}") is not None])
        assert isinstance(lo, float) and isinstance(hi, float)
        assert float(np.min(slips)) <= lo < 0.0 < hi <= float(np.max(slips)) and hi - lo < 0.1
        model = longitudinal_model(sections)
        assert all(np.isfinite(v) for v in model.values().values()) and model.pkx1 > 1.0 and model.pdx1 > 0.1
        if w in ("FL", "FR"):  # the driven axle: its force-slip lines' slope per unit load, a passenger tire's 10-40
            assert 10.0 < model.pkx1 < 40.0 and "from the force-slip line" in (out / f"{w}.tir").read_text()
        k = np.linspace(lo, hi, 41)
        fx = model.fx0(k, model.fnomin)
        assert np.all(np.diff(fx) > 0)  # within the range the drive covered: the rising, nearly linear part
        assert "peak NOT passed" in (out / f"{w}.tir").read_text()


def test_the_report_writes_and_links_the_tire_files(rav4: Path, tmp_path: Path) -> None:
    result = make_report([rav4], tmp_path / "report")
    page = result.index.read_text()
    for w in ("FL", "FR", "RL", "RR"):
        rel = f"tires/no_labels/{w}.tir"
        assert (tmp_path / "report" / rel).is_file() and f'href="{rel}"' in page
        assert read_tir(tmp_path / "report" / rel)["MODEL"]["FITTYP"] == 61.0


def test_the_tire_files_fitted_on_threads_are_the_ones_fitted_in_turn(rav4: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The report's fitter (ThreadFits: the jobs on threads, the longest first) gives each wheel's result in the
    jobs' order, the same file and the same fit as fitting one job after the other."""
    monkeypatch.setattr("os.cpu_count", lambda: 4)  # threads, whatever cores this machine has
    data = read_log(rav4)
    log = summarize_log(data.rows, data.metadata, data.diagnostics, path=str(rav4), name="rav4", labels={},
                        fast=data.fast, sensors=data.sensors)
    jobs = [j for _, _, group in tire_jobs([log]) for j in group]
    with ThreadFits() as fits:
        threaded = fits(jobs)()
        assert len(fits.futures) == len(jobs) == 4
    in_turn = fit_here(jobs)()
    assert [r.wheel for r in threaded] == [j.wheel for j in jobs] == ["FL", "FR", "RL", "RR"]
    for a, b in zip(threaded, in_turn, strict=True):
        assert a.file is not None and b.file is not None and a.fit is not None and b.fit is not None
        assert tir_text(a.file) == tir_text(b.file) and a.fit.model == b.fit.model
        assert a.fit.rms_mu == b.fit.rms_mu and a.fit.n_points == b.fit.n_points


def test_export_without_an_output_names_tir(rav4: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", str(rav4)]) != 0
    assert "--tir" in capsys.readouterr().err


def _points(truth: LongitudinalMF61, seed: int, n: int = 3000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ABS-like points: slip cycling 2-30 % braking, the load rising with the slip (load transfer), mu noise 0.02."""
    rng = np.random.default_rng(seed)
    k = -rng.uniform(0.0, 0.3, n)
    fz = truth.fnomin * (1.0 + 0.6 * rng.uniform(-0.5, 0.5, n))
    fx = truth.fx0(k, fz) + 0.02 * fz * rng.standard_normal(n)
    return k, fx, fz


def test_the_fit_finds_load_dependence_only_where_the_points_carry_it() -> None:
    """Synthetic points over loads +-30 % of FNOMIN: a tire whose friction falls with load (PDX2 = -0.1) gets PDX2
    back within its interval; one without gets 0 and the file's note says why."""
    sensitive = LongitudinalMF61(fnomin=4000.0, pcx1=1.65, pdx1=1.17, pkx1=16.0, pdx2=-0.1, pkx2=-3.0)
    fit = fit_mf61(*_points(sensitive, 1), 4000.0)
    assert fit is not None and fit.peak_passed and fit.load_terms
    assert abs(fit.model.pdx2 - sensitive.pdx2) <= Z95 * fit.stderr["PDX2"] and fit.model.pdx2 < -0.05
    assert fit.model.pdx1 == pytest.approx(1.17, abs=0.02) and fit.model.pkx1 == pytest.approx(16.0, rel=0.05)
    plain = dataclasses.replace(sensitive, pdx2=0.0, pkx2=0.0)
    fit0 = fit_mf61(*_points(plain, 2), 4000.0)
    assert fit0 is not None and not fit0.load_terms and fit0.model.pdx2 == 0.0 and fit0.model.pkx2 == 0.0
    assert "not identified" in fit0.load_note


def _richardson(model: LongitudinalMF61, name: str, k: np.ndarray, fz: np.ndarray, h: float) -> np.ndarray:
    """dFx0/d(name) by central differences of steps h and h/2, extrapolated (error O(h⁴))."""
    c = getattr(model, name)

    def central(step: float) -> np.ndarray:
        return (dataclasses.replace(model, **{name: c + step}).fx0(k, fz)
                - dataclasses.replace(model, **{name: c - step}).fx0(k, fz)) / (2.0 * step)

    return (4.0 * central(h / 2.0) - central(h)) / 3.0


@settings(max_examples=200)
@given(pcx1=st.floats(1.0, 2.5), pdx1=st.floats(0.05, 3.0), pdx2=st.floats(-1.0, 1.0), pex1=st.floats(-5.0, 0.99),
       pex4=st.floats(-0.99, 0.99), pkx1=st.floats(1.0, 200.0), pkx2=st.floats(-100.0, 100.0),
       pkx3=st.floats(-1.0, 1.0), pex2=st.floats(-1.0, 1.0), phx1=st.floats(-0.01, 0.01), pvx1=st.floats(-0.05, 0.05),
       lmux=st.floats(0.5, 1.5), fnomin=st.floats(1000.0, 8000.0), seed=st.integers(0, 2**32 - 1))
def test_the_closed_form_jacobian_is_the_curves_derivative(pcx1: float, pdx1: float, pdx2: float, pex1: float,
                                                           pex4: float, pkx1: float, pkx2: float, pkx3: float,
                                                           pex2: float, phx1: float, pvx1: float, lmux: float,
                                                           fnomin: float, seed: int) -> None:
    """Fx0Terms.jacobian against central differences (Richardson-extrapolated) over random coefficients within the
    fit's bounds (and the terms it holds fixed), loads from 0.2 to 2 FNOMIN and slip over ±60 %: each row within
    1e-6 of its largest value (and 1e-9 of the largest |Fx0|: the differences' rounding), away from where Ex meets
    its limit 1 (a kink) and where the friction mux (PDX2 against the load) falls to 0 (Bx's pole); Fx0Terms' Fx0 is
    fx0's, the same bits."""
    model = LongitudinalMF61(fnomin=fnomin, pcx1=pcx1, pdx1=pdx1, pdx2=pdx2, pex1=pex1, pex4=pex4, pkx1=pkx1,
                             pkx2=pkx2, pkx3=pkx3, pex2=pex2, phx1=phx1, pvx1=pvx1, lmux=lmux)
    rng = np.random.default_rng(seed)
    k = rng.uniform(-0.6, 0.6, 400)
    fz = fnomin * rng.uniform(0.2, 2.0, 400)
    terms = model.fx0_terms(model.point_terms(k, fz))
    np.testing.assert_array_equal(terms.fx0, model.fx0(k, fz))
    ex_raw = terms.ex_shape * (1.0 - pex4 * terms.points.sign_kx)
    smooth = (np.abs(ex_raw - 1.0) > 0.05) & (model.friction(fz) > 0.05)  # no kink, no pole of Bx at Dx = 0
    got = terms.jacobian(JACOBIAN_NAMES)
    assert got.shape == (len(JACOBIAN_NAMES), k.size)
    floor = 1e-9 * float(np.max(np.abs(terms.fx0)))
    for i, name in enumerate(JACOBIAN_NAMES):
        want = _richardson(model, name, k, fz, 1e-4 * max(1.0, abs(getattr(model, name))))
        tol = 1e-6 * float(np.max(np.abs(want[smooth]), initial=0.0)) + floor
        np.testing.assert_allclose(got[i, smooth], want[smooth], rtol=0, atol=tol, err_msg=name)


def _central_differences(terms: Fx0Terms, names: Sequence[str]) -> np.ndarray:
    """The Jacobian the fit took before its closed form: central differences of Fx0, step 1e-6·max(1, |c|)."""
    m = terms.model
    cols = []
    for n in names:
        c = getattr(m, n)
        h = 1e-6 * max(1.0, abs(c))
        cols.append((dataclasses.replace(m, **{n: c + h}).fx0(terms.points.slip, terms.points.fz)
                     - dataclasses.replace(m, **{n: c - h}).fx0(terms.points.slip, terms.points.fz)) / (2 * h))
    return np.stack(cols)


FIT_REL = 1e-6
"""The coefficients of the fit with the closed-form Jacobian against those with central differences: relative."""
CURVE_OF_PEAK = 1e-4
"""Their curves (Fx0 over slip at FNOMIN and ±30 %): apart by at most this fraction of the peak |Fx0|."""


def _agrees_with_central_differences(fit: MF61Fit | None, oracle: MF61Fit | None) -> None:
    assert fit is not None and oracle is not None
    assert (fit.peak_passed, fit.load_terms, fit.asymmetry, fit.stiffness_from) == \
        (oracle.peak_passed, oracle.load_terms, oracle.asymmetry, oracle.stiffness_from)
    assert fit.stderr.keys() == oracle.stderr.keys()
    for name, value in oracle.model.values().items():
        assert fit.model.values()[name] == pytest.approx(value, rel=FIT_REL, abs=1e-12), name
    for name, se in oracle.stderr.items():
        assert fit.stderr[name] == pytest.approx(se, rel=1e-4), name
    assert fit.rms_mu == pytest.approx(oracle.rms_mu, rel=1e-9)
    k = np.linspace(-0.6, 0.6, 241)
    for fz in (0.7 * fit.model.fnomin, fit.model.fnomin, 1.3 * fit.model.fnomin):
        want = oracle.model.fx0(k, fz)
        assert np.max(np.abs(fit.model.fx0(k, fz) - want)) <= CURVE_OF_PEAK * np.max(np.abs(want))


def test_a_coefficient_held_at_its_bound_leaves_the_others_at_the_boxs_optimum() -> None:
    """Points of the linear range only, PDX1 bounded below above what they want (as the fit bounds it by the friction
    seen): PDX1 stays at its bound and PKX1 goes where scipy's bounded least squares (trf) puts it, in a few steps
    (a step that moved PDX1 too, then clipped it, zig-zags PKX1 to the step limit 0.2 % short)."""
    from scipy.optimize import least_squares

    truth = LongitudinalMF61(fnomin=4000.0, pcx1=1.65, pdx1=1.17, pkx1=16.0)
    rng = np.random.default_rng(5)
    k = -rng.uniform(0.0, 0.06, 3000)
    fz = truth.fnomin * (1.0 + 0.6 * rng.uniform(-0.5, 0.5, k.size))
    fx = truth.fx0(k, fz) + 0.02 * fz * rng.standard_normal(k.size)
    start = LongitudinalMF61(fnomin=4000.0, pcx1=1.65, pdx1=1.6, pkx1=30.0)
    model, _, ssr = fit_module._fit(start, ("pdx1", "pkx1"), k, fx, fz, lower={"pdx1": 1.5})

    def residual(x: np.ndarray) -> np.ndarray:
        return np.asarray((dataclasses.replace(start, pdx1=x[0], pkx1=x[1]).fx0(k, fz) - fx) / fz)

    box = ([1.5, fit_module.BOUNDS["pkx1"][0]], [fit_module.BOUNDS["pdx1"][1], fit_module.BOUNDS["pkx1"][1]])
    want = least_squares(residual, [1.6, 30.0], bounds=box, method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert model.pdx1 == 1.5 and want.x[0] == pytest.approx(1.5, rel=1e-12)
    assert model.pkx1 == pytest.approx(want.x[1], rel=1e-8)
    assert ssr == pytest.approx(2 * want.cost, rel=1e-12)


@pytest.mark.parametrize("seed, load_terms", [(1, True), (2, False), (3, True)])
def test_the_fit_gives_the_coefficients_of_central_differences_on_synthetic_points(
        seed: int, load_terms: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """The load test's points (and a third draw): fit_mf61 with the closed-form Jacobian against fit_mf61 with the
    central differences it used before: the same steps taken, coefficients within FIT_REL, curves within
    CURVE_OF_PEAK of the peak, standard errors within 1e-4."""
    truth = LongitudinalMF61(fnomin=4000.0, pcx1=1.65, pdx1=1.17, pkx1=16.0, pdx2=-0.1 if load_terms else 0.0,
                             pkx2=-3.0 if load_terms else 0.0)
    points = _points(truth, seed)
    fit = fit_mf61(*points, 4000.0)
    monkeypatch.setattr(Fx0Terms, "jacobian", _central_differences)
    _agrees_with_central_differences(fit, fit_mf61(*points, 4000.0))
    assert fit is not None and fit.load_terms == load_terms


@pytest.mark.parametrize("wheel", ["FL", "FR"])
def test_the_abs_stops_fit_gives_the_coefficients_of_central_differences(
        abs_stop: tuple[ManeuverSummary, Config], wheel: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The ABS stop's front tires (peak passed): as on synthetic points."""
    stop, cfg = abs_stop
    got = build_tire(wheel, [("abs.mcap", stop)], cfg.vehicle, cfg.tire)
    monkeypatch.setattr(Fx0Terms, "jacobian", _central_differences)
    _agrees_with_central_differences(got.fit, build_tire(wheel, [("abs.mcap", stop)], cfg.vehicle, cfg.tire).fit)


def test_a_real_drives_fits_give_the_coefficients_of_central_differences(rav4: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The RAV4's drive (the peak not passed, PKX1 from the points or the force-slip line): as on synthetic points."""
    data = read_log(rav4)
    log = summarize_log(data.rows, data.metadata, data.diagnostics, path=str(rav4), name="rav4", labels={},
                        fast=data.fast, sensors=data.sensors)
    jobs = [j for _, _, group in tire_jobs([log]) for j in group]
    fits = [j.fit().fit for j in jobs]
    monkeypatch.setattr(Fx0Terms, "jacobian", _central_differences)
    for fit, job in zip(fits, jobs, strict=True):
        _agrees_with_central_differences(fit, job.fit().fit)
