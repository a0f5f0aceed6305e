"""`export --mf4` and `--parquet`: read back with asammdf and pyarrow, every value equals the CSV export's bit for bit
(repr of the float64 = the CSV cell; NaN or null where the cell is empty); the MF4's units, comments, header, and its
wheel-speed and GPS groups; refused or failed exports leave nothing."""

from __future__ import annotations

import csv
import datetime as dt
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.export.csv_file import ALL_COLUMNS
from slipdaq.logformat.reader import iter_estimates, iter_fast_slip, iter_topic, read_metadata
from slipdaq.logformat.topics import TOPIC_GPS
from slipdaq.offline.run import process_to_log
from slipdaq.report.labels import labels_metadata
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG

asammdf = pytest.importorskip("asammdf")
pq = pytest.importorskip("pyarrow.parquet")

TEXTS = {"phase", "source", "latency_source", "quality", "accel_source", *(f"r0_source_{w}" for w in WHEELS)}
UNITS = {"time_s": "s", "speed_mps": "m/s", "accel_mps2": "m/s^2", "force_n": "N", "gps_latency_s": "s"}
for _w in WHEELS:
    UNITS |= {f"slip_{_w}": "1", f"re_{_w}_m": "m", f"r0_{_w}_m": "m", f"cx_{_w}_n": "N", f"slip_nd_{_w}": "1",
              f"cx_fit_{_w}_n": "N", f"cx_fit_{_w}_conf": "1"}


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cfg = load_config(CONFIG).with_overrides(gps={"latency_s": 0.05})
    settings = SimSettings(wpt_rate_hz=200.0, can_jitter_s=0.0005, gps_latency_s=0.05)
    records = [ev.record for ev in generate(cfg, "cycle", "paved", settings, duration_s=20) if ev.record is not None]
    path = tmp_path_factory.mktemp("export") / "drive-sand.mcap"
    process_to_log(cfg, records, path, "import", metadata=labels_metadata({"road": "sand"}))
    return path


@pytest.fixture(scope="module")
def out(log: Path) -> dict[str, Path]:
    d = log.parent
    paths = {"csv": d / "e.csv", "mf4": d / "e.mf4", "parquet": d / "e.parquet"}
    assert main(["export", str(log), "--csv", str(paths["csv"]), "--mf4", str(paths["mf4"]),
                 "--parquet", str(paths["parquet"])]) == 0
    assert not list(d.glob(".*.part"))
    return paths


@pytest.fixture(scope="module")
def table(out: dict[str, Path]) -> dict[str, list[str]]:
    """The CSV by column: its cells."""
    with open(out["csv"], newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == ALL_COLUMNS and len(rows) > 150
    return {c: [r[i] for r in rows[1:]] for i, c in enumerate(rows[0])}


@pytest.fixture(scope="module")
def mdf(out: dict[str, Path]) -> Any:
    m = asammdf.MDF(out["mf4"])
    yield m
    m.close()


def _t0(log: Path) -> float:
    times = [r["time_s"] for r in iter_estimates(log)] + [r["time_s"] for r in iter_fast_slip(log)]
    return min(times + [d["timestamp_s"] for _t, _lt, d in iter_topic(log, (TOPIC_GPS,))])


def _group(mdf: Any, name: str) -> str:
    (where,) = mdf.whereis(name)  # one channel of that name in the file
    return str(mdf.groups[where[0]].channel_group.acq_name)


def _same_floats(got: np.ndarray, expected: list[float | None]) -> None:
    """got (float64) is expected bit for bit, NaN where expected is None."""
    assert got.dtype == np.float64 and len(got) == len(expected)
    for g, e in zip(got.tolist(), expected):
        assert math.isnan(g) if e is None else repr(g) == repr(e), (g, e)


def test_mf4_estimates_equal_the_csv_bit_for_bit(log: Path, mdf: Any, table: dict[str, list[str]]) -> None:
    assert [g.channel_group.acq_name for g in mdf.groups] == ["estimates", "wheel speeds", "GPS"]
    t0 = _t0(log)
    times = np.array([float(c) for c in table["time_s"]])
    empties = 0
    for name, cells in table.items():
        s = mdf.get(name)
        assert _group(mdf, name) == "estimates"
        assert s.comment, name
        assert np.array_equal(s.timestamps, times - t0)
        if name in TEXTS:
            assert [b.decode() for b in s.samples] == cells, name
            assert mdf.get(name, raw=True).samples.dtype.kind == "u"  # codes with a value-to-text conversion
            assert s.unit == ""
        else:
            for g, cell in zip(s.samples.tolist(), cells):
                assert math.isnan(g) if cell == "" else repr(g) == cell, (name, g, cell)
            assert s.samples.dtype == np.float64 and "NaN" in s.comment
            assert s.unit == UNITS[name], name
            empties += cells.count("")
    assert empties > 0  # the comparison saw undefined values
    assert "slip of the FL wheel, SAE, a fraction" in mdf.get("slip_FL").comment


def test_mf4_wheel_speeds_and_gps_groups(log: Path, mdf: Any) -> None:
    t0 = _t0(log)
    fast = list(iter_fast_slip(log))
    fixes = [d for _t, _lt, d in iter_topic(log, (TOPIC_GPS,))]
    assert len(fast) > 1500 and len(fixes) > 150
    fast_t = np.array([r["time_s"] for r in fast]) - t0
    for w in WHEELS:
        for name, key in ((f"wheel_speed_{w}_mps", f"wheel_speed_{w}_mps"), (f"fast_slip_{w}", f"slip_{w}")):
            s = mdf.get(name)
            assert _group(mdf, name) == "wheel speeds" and s.comment
            _same_floats(s.samples, [r[key] for r in fast])
            assert np.array_equal(s.timestamps, fast_t)
        assert mdf.get(f"wheel_speed_{w}_mps").unit == "m/s" and mdf.get(f"fast_slip_{w}").unit == "1"
    s = mdf.get("fast_speed_mps")
    _same_floats(s.samples, [r["speed_mps"] for r in fast])
    assert s.unit == "m/s" and _group(mdf, "fast_speed_mps") == "wheel speeds"
    gps_t = np.array([d["timestamp_s"] for d in fixes]) - t0
    s = mdf.get("gps_speed_mps")
    assert _group(mdf, "gps_speed_mps") == "GPS" and s.unit == "m/s" and s.comment
    _same_floats(s.samples, [d["speed_mps"] for d in fixes])
    assert np.array_equal(s.timestamps, gps_t)
    s = mdf.get("gps_valid")
    assert s.samples.dtype == np.uint8 and s.samples.tolist() == [int(d["valid"]) for d in fixes]
    assert np.array_equal(s.timestamps, gps_t)


def test_mf4_header_has_the_labels_the_config_and_the_start(log: Path, mdf: Any) -> None:
    meta = read_metadata(log)
    t0 = _t0(log)
    xml = ET.fromstring(mdf.header.comment)  # what asammdf writes: <HDcomment><TX>...</TX>...</HDcomment>
    assert xml.tag == "HDcomment"
    text = xml.findtext("TX")
    assert text == mdf.header.description
    assert "label.road = sand" in text and "drive-sand.mcap" in text and f"t0_s = {t0!r}" in text
    assert meta["config_toml"].strip() in text and "[estimator]" in text
    assert mdf.header.start_time == dt.datetime.fromtimestamp(t0, dt.UTC)


def test_parquet_equals_the_csv_with_the_log_and_its_labels(out: dict[str, Path], table: dict[str, list[str]]) -> None:
    t = pq.read_table(out["parquet"])
    assert t.column_names == [*ALL_COLUMNS, "log", "label_road"]
    n = len(table["time_s"])
    assert t.num_rows == n
    for name, cells in table.items():
        values = t.column(name).to_pylist()
        if name in TEXTS:
            assert values == [c or None for c in cells], name
        else:
            assert str(t.schema.field(name).type) == "double"
            assert [None if v is None else repr(v) for v in values] == [c or None for c in cells], name
    assert t.column("log").to_pylist() == ["drive-sand"] * n
    assert t.column("label_road").to_pylist() == ["sand"] * n


def test_refused_exports_leave_nothing(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = log.read_bytes()
    a, b = tmp_path / "a.csv", tmp_path / "b.mf4"
    assert main(["export", str(log), "--csv", str(a), "--mf4", str(tmp_path / "." / "a.csv")]) == 2
    assert "--csv and --mf4 name the same file" in capsys.readouterr().err
    assert main(["export", str(log), "--csv", str(a), "--mf4", str(b), "--parquet", str(log)]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert main(["export", str(log), "--mf4", str(b), "--parquet", str(b)]) == 2
    assert log.read_bytes() == before and list(tmp_path.iterdir()) == []


def test_a_log_without_estimates_fails_and_leaves_nothing_unless_allowed(tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    process_to_log(load_config(CONFIG), [], empty, "import")
    outs = [tmp_path / "o.csv", tmp_path / "o.mf4", tmp_path / "o.parquet"]
    args = ["export", str(empty), "--csv", str(outs[0]), "--mf4", str(outs[1]), "--parquet", str(outs[2])]
    assert main(args) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mcap"]
    assert main([*args, "--allow-empty"]) == 0
    m = asammdf.MDF(outs[1])
    assert len(m.get("slip_FL").samples) == 0 and len(m.get("quality").samples) == 0
    assert len(m.get("gps_speed_mps").samples) == 0
    m.close()
    assert pq.read_table(outs[2]).num_rows == 0 and outs[0].read_text().count("\n") == 1
