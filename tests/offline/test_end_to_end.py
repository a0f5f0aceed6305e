"""End to end on real parts: simulator -> virtual CAN bus + pseudo-terminal -> daemon -> MCAP; then replay
(equal estimates, bit for bit), export (CSV), import (candump -L + timestamped NMEA), and `slipdaq run` as a process."""

from __future__ import annotations

import asyncio
import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.export.csv_file import COLUMNS
from slipdaq.live.demo import run_demo_async
from slipdaq.logformat.reader import config_from_log, iter_estimates, iter_raw_records, iter_topic
from slipdaq.logformat.schemas import BATCH_SCHEMAS, SCHEMAS
from slipdaq.logformat.topics import RAW_TOPICS, TOPIC_CAN, TOPIC_ESTIMATE, TOPIC_GPS, TOPIC_NMEA
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.truth import slip_error, truth_series
from support.paths import CONFIG, ROOT


@pytest.fixture(scope="module")
def live_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object, object]:
    """A 16 s live run (one whole accelerate-cruise-brake cycle):
    simulator and daemon on a virtual bus and a real pty (as `slipdaq demo`)."""
    out = tmp_path_factory.mktemp("live")
    with open(out / "status.txt", "w") as status:
        result, err, cfg = asyncio.run(run_demo_async(16.0, "cycle", "paved", out, status_stream=status,
                                                      status_every_s=2.0))
    return result.log_path, result, err


def test_live_log_has_every_frame_and_valid_structure(live_log) -> None:  # type: ignore[no-untyped-def]
    path, result, _ = live_log
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(SCHEMAS) | set(BATCH_SCHEMAS) <= set(topics)
        for c in topics.values():
            schema = summary.schemas[c.schema_id]
            if c.topic in BATCH_SCHEMAS:  # /can/raw and /wpt/count: CDR batches
                assert (schema.name, schema.encoding, c.message_encoding) == (BATCH_SCHEMAS[c.topic][0], "ros2msg",
                                                                              "cdr")
                continue
            assert schema.encoding == "jsonschema" and c.message_encoding == "json"
            json.loads(schema.data)
        assert summary.chunk_indexes and all(ci.compression == "zstd" for ci in summary.chunk_indexes)
        counts = summary.statistics.channel_message_counts
        can_messages = counts[topics[TOPIC_CAN].id]
    frames = [r for r in iter_raw_records(path) if hasattr(r, "arbitration_id")]
    # 4 wheels x 100 Hz x 16 s, all of them, none lost (counted by total and by Seq), in batches
    assert len(frames) == result.can_frames and len(frames) >= 4 * 100 * 15
    assert can_messages < len(frames) / 4
    nmea = [d for _, _, d in iter_topic(path, (TOPIC_NMEA,))]
    assert nmea[0]["can_index"] <= nmea[-1]["can_index"] <= len(frames)
    for wid in range(0x310, 0x314):
        seqs = [r.data[7] for r in frames if r.arbitration_id == wid]
        assert all((b - a) % 256 == 1 for a, b in zip(seqs, seqs[1:]))
    assert result.lost_frames == 0 and result.bad_sentences == 0
    assert counts[topics[TOPIC_NMEA].id] >= 3 * 10 * 15
    assert counts[topics[TOPIC_GPS].id] >= 10 * 15


def test_live_estimates_follow_the_truth(live_log) -> None:  # type: ignore[no-untyped-def]
    path, result, err = live_log
    rows = list(iter_estimates(path))
    assert len(rows) >= 100 and result.estimates == len(rows)
    assert err.samples > 50
    # Fix times come from the sentences' UTC (no read jitter) and frames carry their nominal time (as a hardware
    # timestamp would): measured 0.04-0.05 points median, 0.14-0.17 p95 on a loaded 2-core machine.
    assert err.median_abs_points < 0.2 and err.p95_abs_points < 1.0
    driving = [r for r in rows if r["accel_mps2"] and r["accel_mps2"] > 2 and r["slip_FL"] is not None]
    braking = [r for r in rows if r["accel_mps2"] and r["accel_mps2"] < -4 and r["slip_FL"] is not None]
    assert driving and braking
    assert sum(r["slip_FL"] > 0.01 for r in driving) > 0.8 * len(driving)
    assert sum(r["slip_FL"] < -0.01 for r in braking) > 0.8 * len(braking)


def test_config_stored_in_log_and_replay_equals_live_exactly(live_log, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path, _, _ = live_log
    cfg = config_from_log(path)
    assert cfg.vehicle.mass_kg == 1300.0 and cfg.can.interface == "virtual"
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(path), "-o", str(out)]) == 0
    live = list(iter_topic(path, (TOPIC_ESTIMATE,)))
    replayed = list(iter_topic(out, (TOPIC_ESTIMATE,)))
    assert len(live) > 100
    assert replayed == live  # every field of every estimate, bit for bit, and the log time (its releasing record)


def test_export_csv_columns_and_values(live_log, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    path, _, _ = live_log
    out = tmp_path / "est.csv"
    assert main(["export", str(path), "--csv", str(out)]) == 0
    with open(out, newline="") as f:
        rows = list(csv.reader(f))
    header = rows[0]
    assert header[:4] == ["time_s", "speed_mps", "accel_mps2", "force_n"]
    assert header[4:8] == ["slip_FL", "re_FL_m", "r0_FL_m", "cx_FL_n"] and tuple(header[: len(COLUMNS)]) == COLUMNS
    est = list(iter_estimates(path))
    assert len(rows) - 1 == len(est)
    for row, e in zip(rows[1:], est):
        for name, cell in zip(header, row):
            if e[name] is None:
                assert cell == ""
            elif isinstance(e[name], str):
                assert cell == e[name]
            else:
                assert float(cell) == e[name]
    assert any(r[4] == "" for r in rows[1:]) and any(r[4] != "" for r in rows[1:])  # standstill and driving


def _write_import_files(cfg, tmp_path: Path, duration_s: float, latency_s: float = 0.0):  # type: ignore[no-untyped-def]
    settings = SimSettings(gps_latency_s=latency_s, can_jitter_s=0.0005, seed=3)
    can_path, nmea_path = tmp_path / "drive.log", tmp_path / "drive.nmea"
    truth = write_drive_logs(generate(cfg, "cycle", "paved", settings, duration_s=duration_s), can_path, nmea_path,
                             nmea_header="# comment lines and blank lines are skipped\n\n", channel="vcan0")
    return can_path, nmea_path, truth, settings


def test_import_candump_and_nmea_log(cfg, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    can_path, nmea_path, truth, settings = _write_import_files(cfg, tmp_path, 20.0)
    assert can_path.read_text().startswith("(")  # candump -L text
    out = tmp_path / "imported.mcap"
    assert main(["import", "--can", str(can_path), "--nmea", str(nmea_path), "--config", str(CONFIG),
                 "-o", str(out)]) == 0
    raw = list(iter_raw_records(out))
    assert sum(hasattr(r, "arbitration_id") for r in raw) == 4 * 100 * 20
    assert all(a.timestamp_s <= b.timestamp_s for a, b in zip(raw, raw[1:]))  # merged in time order
    rows = list(iter_estimates(out))
    err = slip_error(rows, truth_series(truth, settings.start_utc_s))
    assert err.samples > 200
    assert err.rms_points < 0.3  # zero latency, exact radius: only GPS noise and count quantisation remain
    # replay of an imported log gives the same estimates too
    again = tmp_path / "again.mcap"
    assert main(["replay", str(out), "-o", str(again)]) == 0
    assert list(iter_estimates(again)) == rows


def test_import_bare_nmea_sentences_take_their_own_time(cfg, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    can_path, nmea_path, _, _ = _write_import_files(cfg, tmp_path, 5.0)
    bare = tmp_path / "bare.nmea"
    bare.write_text("".join(line.split(") ", 1)[1] if line.startswith("(") else line
                            for line in nmea_path.read_text().splitlines(keepends=True)))
    out = tmp_path / "bare.mcap"
    assert main(["import", "--can", str(can_path), "--nmea", str(bare), "--config", str(CONFIG), "-o", str(out)]) == 0
    fixes = list(iter_topic(out, (TOPIC_GPS,)))
    assert len(fixes) == 50
    for _, _, fx in fixes:
        assert fx["timestamp_s"] == pytest.approx(fx["fix_time_utc_s"], abs=1e-6)


def test_import_missing_file_is_a_clear_error(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    rc = main(["import", "--can", str(tmp_path / "no.log"), "--nmea", str(tmp_path / "no.nmea"),
               "--config", str(CONFIG), "-o", str(tmp_path / "x.mcap")])
    assert rc == 1 and "no.log" in capsys.readouterr().err


def test_run_as_a_process_sigint_finishes_the_log(tmp_path: Path) -> None:
    """`slipdaq run` on a virtual bus with NMEA from a real pty; SIGINT -> exit 0 and a finished, readable log."""
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    port = os.ttyname(slave)
    (tmp_path / "wpt.dbc").write_text((ROOT / "config" / "wpt.dbc").read_text())
    (tmp_path / "slipdaq.toml").write_text(
        CONFIG.read_text().replace('interface = "socketcan"', 'interface = "virtual"')
        .replace('"/dev/ttyUSB0"', f'"{port}"')
    )
    proc = subprocess.Popen([sys.executable, "-m", "slipdaq", "run", "--log-dir", str(tmp_path / "logs")],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        from slipdaq.config import load_config

        lines = [line for ev in generate(load_config(CONFIG), "cycle", "paved", SimSettings(), duration_s=3.0)
                 if (line := getattr(ev.record, "line", None))]
        deadline = time.monotonic() + 30
        logs: list[Path] = []
        while time.monotonic() < deadline and not logs:
            logs = list((tmp_path / "logs").glob("*.mcap"))
            time.sleep(0.1)
        time.sleep(1.0)  # the daemon opens the port (which flushes its input) right after creating the log
        for line in lines:
            os.write(master, (line + "\r\n").encode())
            time.sleep(0.01)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
        os.close(slave)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "log written" in out
    (log,) = (tmp_path / "logs").glob("*.mcap")
    with open(log, "rb") as f:
        summary = make_reader(f).get_summary()  # a finished file has a summary
    assert summary is not None
    nmea = [r for r in iter_raw_records(log) if hasattr(r, "line")]
    assert len(nmea) == len(lines)  # every line written reached the log
    assert [r.line for r in nmea] == lines
    assert math.isfinite(nmea[0].timestamp_s)
    assert set(RAW_TOPICS) == {"/can/raw", "/nmea/raw", "/gps/ubx/raw", "/imu/raw", "/gps/rtcm/raw"} \
        and TOPIC_ESTIMATE == "/estimate"
