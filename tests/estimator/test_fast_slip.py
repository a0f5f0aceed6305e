"""High-rate slip (/slip/fast, `export --fast-csv`) against the simulator's truth; the vehicle-speed filter; the
rows are the same however the records are batched, and read back from the log by the mcap library."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from slipdaq import WHEELS
from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.estimator.vehicle_speed import VehicleSpeedFilter
from slipdaq.logformat.json_codec import rows_of_columns
from slipdaq.logformat.reader import iter_fast_slip
from slipdaq.logformat.schemas import SCHEMAS
from slipdaq.logformat.topics import TOPIC_FAST_SLIP
from slipdaq.offline.run import process, process_to_log
from slipdaq.records import CanFrame
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.truth import truth_series
from slipdaq.sinks import CollectingSink
from support.paths import CONFIG

SETTINGS = SimSettings(wpt_rate_hz=200.0, can_jitter_s=0.0005, gps_latency_s=0.05)


def _drive(cfg, duration_s: float = 20.0, settings: SimSettings = SETTINGS):
    records, truth = [], []
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=duration_s):
        if ev.record is not None:
            records.append(ev.record)
        if ev.truth is not None:
            truth.append(ev.truth)
    return records, truth_series(truth, settings.start_utc_s)


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIG).with_overrides(gps={"latency_s": 0.05})


@pytest.fixture(scope="module")
def drive(cfg):
    return _drive(cfg)


@pytest.fixture(scope="module")
def rows(cfg, drive):
    sink = CollectingSink()
    process(cfg, drive[0], [sink])
    return sink.fast


def test_rows_on_the_grid_follow_the_truth(rows, drive) -> None:
    truth = drive[1]
    t = np.array([r.time_s for r in rows])
    assert len(rows) > 1500  # 100 Hz over most of 20 s
    steps = np.diff(t)
    assert np.allclose(steps, 0.01, atol=1e-6)  # estimator.fast_rate_hz = 100: one row per instant, none skipped
    assert np.allclose(np.round(t * 100.0), t * 100.0, atol=1e-4)
    v = np.array([r.speed_mps for r in rows])
    vt = np.interp(t, truth["time_s"], truth["speed_mps"])
    moving = vt > 5.0
    assert np.sqrt(np.mean((v[moving] - vt[moving]) ** 2)) < 0.08
    for w in WHEELS:
        s = np.array([math.nan if r.wheels[w].slip is None else r.wheels[w].slip for r in rows])
        st = np.interp(t, truth["time_s"], truth[f"slip_{w}"])
        ok = moving & np.isfinite(s)
        assert ok.sum() > 0.9 * moving.sum()
        rms_points = 100 * np.sqrt(np.mean((s[ok] - st[ok]) ** 2))
        assert rms_points < 0.8, (w, rms_points)
    slow = np.array([r.speed_mps < 1.0 for r in rows])
    assert slow.any() and all(r.wheels[w].slip is None for r, s in zip(rows, slow) if s for w in WHEELS)


def test_rows_do_not_depend_on_batching(cfg, drive) -> None:
    records = drive[0][: len(drive[0]) // 3]
    one = CollectingSink()
    process(cfg, records, [one])
    frames = [r for r in records if isinstance(r, CanFrame)]
    assert frames
    single = CollectingSink()
    from slipdaq.pipeline import Pipeline

    pipe = Pipeline(cfg, [single])
    for r in records:
        pipe.process(r)
    pipe.finish()
    assert [r.as_row() for r in one.fast] == [r.as_row() for r in single.fast]
    assert len(one.fast) > 300


def test_log_round_trip_schema_and_fast_csv(cfg, drive, rows, tmp_path: Path, capsys) -> None:
    log = tmp_path / "drive.mcap"
    process_to_log(cfg, drive[0], log, "import")
    schema = SCHEMAS[TOPIC_FAST_SLIP]
    logged = []
    with open(log, "rb") as f:
        for _schema, _channel, message in make_reader(f).iter_messages(topics=[TOPIC_FAST_SLIP]):
            d = json.loads(message.data)
            jsonschema.validate(d, schema)
            logged += rows_of_columns(d)
    assert logged == [json.loads(json.dumps(r.as_row())) for r in rows]
    assert list(iter_fast_slip(log)) == logged
    out = tmp_path / "fast.csv"
    assert main(["export", str(log), "--fast-csv", str(out)]) == 0
    with open(out, newline="") as f:
        table = list(csv.reader(f))
    assert table[0] == ["time_s", "speed_mps", "slip_FL", "slip_FR", "slip_RL", "slip_RR"]
    assert len(table) == len(rows) + 1
    for r, line in zip(rows[::97], table[1::97]):
        assert float(line[0]) == r.time_s and float(line[1]) == r.speed_mps
        for w, cell in zip(WHEELS, line[2:]):
            assert cell == ("" if r.wheels[w].slip is None else repr(r.wheels[w].slip))
    # both at once, and the same file twice refused
    assert main(["export", str(log), "--csv", str(tmp_path / "e.csv"), "--fast-csv", str(tmp_path / "f.csv")]) == 0
    assert (tmp_path / "e.csv").exists() and (tmp_path / "f.csv").read_text() == out.read_text()
    capsys.readouterr()
    assert main(["export", str(log), "--csv", str(out), "--fast-csv", str(out)]) == 2
    assert "same file" in capsys.readouterr().err
    assert main(["export", str(log)]) == 2


def test_fast_rate_zero_writes_none_and_export_says_so(cfg, drive, tmp_path: Path, capsys) -> None:
    off = cfg.with_overrides(estimator={"fast_rate_hz": 0.0})
    log = tmp_path / "off.mcap"
    process_to_log(off, drive[0][:20000], log, "import")
    capsys.readouterr()
    assert main(["export", str(log), "--fast-csv", str(tmp_path / "f.csv")]) == 1
    err = capsys.readouterr().err
    assert "no high-rate slip rows" in err and "fast_rate_hz" in err
    assert not (tmp_path / "f.csv").exists()


def test_the_filter_with_an_imu_follows_a_changing_acceleration_better() -> None:
    """A speed with a 7 Hz acceleration ripple (an ABS cycle), a 10 Hz reference with noise: the IMU's samples keep
    the filter on it between the fixes."""
    rng = np.random.default_rng(3)

    def speed(t: float) -> float:
        return 20.0 - 8.0 * t + 3.0 / (2 * math.pi * 7) * math.sin(2 * math.pi * 7 * t)

    def accel(t: float) -> float:
        return -8.0 + 3.0 * math.cos(2 * math.pi * 7 * t)

    errors = {}
    for with_imu in (False, True):
        f = VehicleSpeedFilter(100.0)
        imu_t = np.arange(0.0, 2.0, 0.01) + 0.003
        fix_t = np.arange(0.0, 2.0, 0.1)
        k = 0
        out = []
        for t in fix_t:
            while with_imu and k < len(imu_t) and imu_t[k] <= t:
                f.add_imu(float(imu_t[k]), accel(float(imu_t[k])) + float(rng.normal(0, 0.05)))
                k += 1
            f.add_speed(float(t), speed(float(t)) + float(rng.normal(0, 0.02)), 0.02)
            out += f.take_rows()
        late = [(t, v) for t, v, _ in out if t > 0.5]
        errors[with_imu] = math.sqrt(sum((v - speed(t)) ** 2 for t, v in late) / len(late))
    assert errors[True] < 0.5 * errors[False], errors
    assert errors[True] < 0.03, errors


def test_released_columns_are_the_rows_made_one_by_one(cfg, drive, monkeypatch) -> None:
    """Each fix's rows as columns (FastSlipRows.release) hold what the rows made one at a time held: per grid instant
    its speed and acceleration, and per wheel omega*r0 (None where undefined) and its slip, None below the minimum
    speed or where omega*r0 is undefined or not finite."""
    from collections import deque

    from tests.logformat.test_epoch_json import exact

    from slipdaq.estimator.fast_slip import FastSlipRows
    from slipdaq.records import FastSlip, FastWheel

    release = FastSlipRows.release
    pairs: list[tuple[FastSlip, FastSlip]] = []

    def checked(self: FastSlipRows, rings, r0_m, now_s):
        pending = list(deque(self._pending)) + list(self.speed.rows)
        got = release(self, rings, r0_m, now_s)
        if got is None:
            return got
        taken = pending[: len(got)]
        times = np.array([t for t, _v, _a in taken])
        speeds = [FastSlipRows._wheel_speeds(ring, r0, times) for ring, r0 in zip(rings, r0_m)]
        source = "imu" if self.speed.has_imu else "gps"
        for k, ((t, v, a), row) in enumerate(zip(taken, got)):
            wheels = {}
            for w, ws_all in zip(WHEELS, speeds):
                ws = ws_all[k]
                slip = (ws - v) / v if ws is not None and v >= self.min_speed_mps and math.isfinite(ws) else None
                wheels[w] = FastWheel(slip, ws)
            pairs.append((row, FastSlip(t, v, a, source, wheels)))
        return got

    monkeypatch.setattr(FastSlipRows, "release", checked)
    sink = CollectingSink()
    process(cfg, drive[0][: len(drive[0]) // 2], [sink])
    assert len(pairs) == len(sink.fast) > 500
    assert sum(r.wheels["FL"].slip is None for r, _ in pairs) > 10  # standstill and start-up: undefined values too
    assert [exact(json.dumps(got.as_row()).encode()) for got, _ in pairs] == \
        [exact(json.dumps(want.as_row()).encode()) for _, want in pairs]
