"""The Magic Formula tire file from the road (tire_model/): the MF 6.1 evaluator against a published .tir and an
independent evaluator's values for it, the .tir written and read back, and the fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slipdaq.tire_model.mf61 import LongitudinalMF61
from slipdaq.tire_model.tir_file import TireFile, longitudinal_model, parse_tir, read_tir, tir_text, write_tir

DATA = Path(__file__).parent / "data" / "tyredyn-mf"


def test_the_evaluator_gives_an_independent_evaluators_fx0_on_a_published_tir() -> None:
    """TyreDyn's car205_60R19.tir (MF 6.2 file at its nominal pressure: Fx0 is MF 6.1's) with every longitudinal
    shift and load term nonzero; Fx0 at 33 (slip, load) points as TyreDyn computed it (tests/data/README), to 1e-6 N."""
    model = longitudinal_model(read_tir(DATA / "car205_60R19.tir"))
    assert model.fnomin == 4000.0 and model.pkx3 == -0.4119 and model.phx2 == 0.0011538
    ref = np.loadtxt(DATA / "car205_60R19_fx0.csv", delimiter=",", comments="#")
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
    assert all(v == 1.0 for v in sections["SCALING_COEFFICIENTS"].values())
    back = longitudinal_model(sections)
    assert back == model
    k = np.linspace(-0.3, 0.02, 50)
    np.testing.assert_array_equal(back.fx0(k, 4200.0), model.fx0(k, 4200.0))
    text = path.read_text()
    assert "$   log: x.mcap" in text and "no driving data" in text
    assert parse_tir(tir_text(tire)) == sections
