"""RunCalibration.r0_all keeps its answer between changes: after every free-rolling window, every check of the
stored radii (one of them dropped on the way) and in a frozen run, it equals r0_per_wheel computed afresh."""

from __future__ import annotations

import numpy as np

from slipdaq import WHEELS
from slipdaq.config.calibration import Calibration, StoredRadius
from slipdaq.estimator.radius import r0_per_wheel
from slipdaq.estimator.run_calibration import RunCalibration
from support.estimator_params import params

TRUE_R0_M = 0.3075
STORED = Calibration(r0={"FL": StoredRadius(radius_m=0.3000, se_m=0.0001),  # 7.5 mm off: the run contradicts it
                         "RR": StoredRadius(radius_m=0.3076, se_m=0.0005)})


def fresh(cal: RunCalibration) -> dict[str, tuple[float, str]]:
    p = cal.p
    stored = {w: r for w, (r, _) in cal.stored_r0.items()}
    return r0_per_wheel(cal.radius, p.r_ref_m, p.r_ref_configured, p.calibrate_r0, stored, own=not cal.frozen)


def test_r0_all_follows_every_window_and_the_stored_radius_dropped() -> None:
    cal = RunCalibration(params(calibrate_r0=True, gps_latency_s=None), STORED, frozen=False, reference=("FL", "FR"))
    rng = np.random.default_rng(7)
    seen = set()
    assert cal.r0_all() == fresh(cal)
    for k in range(400):
        d_gps = 12.0 + rng.normal(0.0, 0.02)
        arcs: dict[str, float | None] = {w: d_gps / TRUE_R0_M * (1.0 + rng.normal(0.0, 1e-4)) for w in WHEELS}
        if k % 7 == 3:
            arcs["RL"] = None  # a wheel without an arc in this window
        accel = 0.0 if k % 5 else 2.0  # every fifth window accelerates: only the free-rolling wheels count
        cal.add_free_rolling(arcs, d_gps, accel, 12.0, 1.0, latency_known=k % 2 == 0)
        assert cal.r0_all() == fresh(cal), k
        cal.check_stored(float(k))
        assert cal.r0_all() == fresh(cal), k
        seen.add(tuple(sorted(source for _, source in cal.r0_all().values())))
    assert "FL" not in cal.stored_r0 and cal.events  # dropped on the way, with its event
    assert cal.r0_all()["FL"] == (cal.radius["FL"].radius_m, "calibrated")
    assert len(seen) > 2  # the answer changed as the fits converged


def test_a_frozen_run_keeps_the_stored_radii() -> None:
    cal = RunCalibration(params(calibrate_r0=True, gps_latency_s=None), STORED, frozen=True, reference=("FL", "FR"))
    first = cal.r0_all()
    for _ in range(50):
        cal.add_free_rolling(dict.fromkeys(WHEELS, 12.0 / TRUE_R0_M), 12.0, 0.0, 12.0, 1.0, latency_known=True)
        cal.check_stored(0.0)
    assert cal.r0_all() == first == fresh(cal)
    assert first["FL"] == (0.3, "stored") and first["FR"][1] == "other_wheels"
