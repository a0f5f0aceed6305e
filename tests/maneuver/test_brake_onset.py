"""The brake's onset to the millisecond: UBX-TIM-TM2 time marks (decoded against pyubx2), their placing on the host's
clock, a receiver's raw capture imported with --gps-raw, and a sampled brake signal's onset interval."""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from pyubx2 import GET, UBXMessage, UBXReader

from slipdaq.cli import main
from slipdaq.decode.framing import GpsFramer
from slipdaq.decode.timemark import GPS_EPOCH_UNIX_S, LEAP_SECONDS, SECONDS_PER_WEEK, decode_tim_tm2, gps_minus_utc_s
from slipdaq.maneuver.brake_noise import brake_intervals
from slipdaq.maneuver.brake_test import brake_figures, brake_onset_s
from slipdaq.records import UbxFrame
from slipdaq.sim.emit import SimSettings, generate, tim_tm2_frame
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.truth import brake_onset_time_s, speed_at_onset_mps, stopping_distance_m
from support.live_drive import drive_live
from support.paths import CONFIG

# ---- TIM-TM2 against pyubx2 ----------------------------------------------------------------------------------------


def _pyubx2_utc_s(week: int, tow_ms: int, sub_ns: int, time_base: int) -> float:
    """The edge's UTC from pyubx2's parsed fields, by the interface description's arithmetic."""
    gps = GPS_EPOCH_UNIX_S + SECONDS_PER_WEEK * week + tow_ms / 1000.0 + sub_ns / 1e9
    return gps - gps_minus_utc_s(gps) if time_base == 1 else gps


@settings(max_examples=150, deadline=None)
@given(ch=st.integers(0, 1), flags=st.integers(0, 255), count=st.integers(0, 65535),
       wn_r=st.integers(1, 3000), wn_f=st.integers(1, 3000), ms_r=st.integers(1, SECONDS_PER_WEEK * 1000 - 1),
       ms_f=st.integers(1, SECONDS_PER_WEEK * 1000 - 1), sub_r=st.integers(0, 999_999),
       sub_f=st.integers(0, 999_999), acc=st.integers(0, 2**32 - 1))
def test_tim_tm2_decodes_as_pyubx2_parses_it(ch: int, flags: int, count: int, wn_r: int, wn_f: int, ms_r: int,
                                             ms_f: int, sub_r: int, sub_f: int, acc: int) -> None:
    bits = {"mode": flags & 1, "run": flags >> 1 & 1, "newFallingEdge": flags >> 2 & 1, "timeBase": flags >> 3 & 3,
            "utc": flags >> 5 & 1, "time": flags >> 6 & 1, "newRisingEdge": flags >> 7 & 1}
    frame = bytes(UBXMessage("TIM", "TIM-TM2", GET, ch=ch, count=count, wnR=wn_r, wnF=wn_f, towMsR=ms_r,
                             towSubMsR=sub_r, towMsF=ms_f, towSubMsF=sub_f, accEst=acc, **bits).serialize())
    ref = UBXReader.parse(frame)
    mark = decode_tim_tm2(frame)
    assert mark is not None
    assert (mark.channel, mark.count, mark.time_base) == (ref.ch, ref.count, ref.timeBase)
    assert (mark.new_rising, mark.new_falling, mark.valid) == (bool(ref.newRisingEdge), bool(ref.newFallingEdge),
                                                               bool(ref.time))
    assert mark.accuracy_s == pytest.approx(ref.accEst * 1e-9)
    if ref.timeBase in (1, 2):
        assert mark.rising_utc_s == pytest.approx(_pyubx2_utc_s(ref.wnR, ref.towMsR, ref.towSubMsR, ref.timeBase),
                                                  abs=1e-6)
        assert mark.falling_utc_s == pytest.approx(_pyubx2_utc_s(ref.wnF, ref.towMsF, ref.towSubMsF, ref.timeBase),
                                                   abs=1e-6)
    else:  # receiver time: no UTC to place it by
        assert mark.rising_utc_s is None and mark.falling_utc_s is None


def test_tim_tm2_other_messages_and_short_frames_are_no_mark() -> None:
    pvt = bytes(UBXMessage("NAV", "NAV-PVT", GET).serialize())
    assert decode_tim_tm2(pvt) is None
    good = bytes(UBXMessage("TIM", "TIM-TM2", GET, towMsR=5).serialize())
    assert decode_tim_tm2(good[:20]) is None


def test_leap_seconds_are_gps_minus_utc() -> None:
    """18 s since 2017-01-01 (and 17 s in 2016), counted from the GPS instant."""
    jan_2017 = LEAP_SECONDS[-1]
    assert gps_minus_utc_s(jan_2017 + 18 + 100.0) == 18
    assert gps_minus_utc_s(jan_2017 - 100.0 + 17) == 17
    assert gps_minus_utc_s(GPS_EPOCH_UNIX_S + 10.0) == 0


@pytest.mark.parametrize("edge", ["rising", "falling"])
def test_simulated_time_mark_is_the_edge_to_a_microsecond(edge: str) -> None:
    utc = 1_767_225_604.017_3
    frame = tim_tm2_frame(utc, edge, 7)
    ref = UBXReader.parse(frame)  # pyubx2 reads the simulator's frame ...
    assert ref.timeBase == 1 and ref.time == 1 and ref.count == 7
    mark = decode_tim_tm2(frame)  # ... and the decoder gives back the edge's UTC
    assert mark is not None
    got = mark.rising_utc_s if edge == "rising" else mark.falling_utc_s
    assert got == pytest.approx(utc, abs=1e-6)
    assert (mark.new_rising, mark.new_falling) == (edge == "rising", edge == "falling")
    framed = GpsFramer().feed(b"$GPTXT,01*00\r\n" + frame + b"$GPRMC", 1.0)  # cut from a mixed stream as live
    assert [r.data for r in framed if isinstance(r, UbxFrame)] == [frame]


def test_brake_source_keys() -> None:
    from slipdaq.config import ConfigError, parse_config

    assert parse_config("").brake.source == "can" and parse_config("").brake.edge == "rising"
    b = parse_config('[brake]\nsource = "gps-timemark"\nedge = "falling"\n').brake
    assert (b.source, b.edge, b.message) == ("gps-timemark", "falling", None)
    with pytest.raises(ConfigError, match="edge"):
        parse_config('[brake]\nedge = "both"\n')
    with pytest.raises(ConfigError, match="serial port"):
        parse_config('[gps]\nsource = "can"\nmessage = "REF_SPEED"\nsignal = "Speed"\n'
                     '[brake]\nsource = "gps-timemark"\n')


# ---- the onset of a sampled brake signal -------------------------------------------------------------------------

def _stop(onset_s: float, v0_mps: float = 27.0, decel_mps2: float = 9.0, dt: float = 0.01):
    """A stop at constant deceleration from onset_s (the speed linear, exactly integrable)."""
    t = np.arange(0.0, onset_s + v0_mps / decel_mps2 + 1.0, dt)
    v = np.where(t < onset_s, v0_mps, np.maximum(v0_mps - decel_mps2 * (t - onset_s), 0.0))
    a = np.where((t >= onset_s) & (v > 0), -decel_mps2, 0.0)
    return t, v, a, v0_mps**2 / (2 * decel_mps2)


def test_sampled_brake_onset_is_the_midpoint_and_its_half_interval() -> None:
    t, v, a, _ = _stop(2.013)
    bt = np.arange(0.0, 6.0, 0.02)  # 50 Hz switch
    bv = (bt >= 2.013).astype(float)
    assert brake_onset_s(t, a, bt, bv) == pytest.approx(2.01)  # between 2.00 (released) and 2.02 (pressed)
    f = brake_figures(t, v, a, brake_time_s=bt, brake_value=bv)
    assert f is not None and f.onset_source == "brake signal" and f.onset_half_s == pytest.approx(0.01)
    # a time mark in the span comes first, exactly
    g = brake_figures(t, v, a, brake_time_s=bt, brake_value=bv, mark_time_s=[2.013, 9.0])
    assert g is not None and g.onset_source == "time mark" and g.onset_s == 2.013 and g.onset_half_s == 0.0


@pytest.mark.parametrize("phase_s", [0.0005, 0.007, 0.013, 0.0195])
def test_onset_half_interval_is_carried_into_the_stopping_distance(phase_s: float) -> None:
    """Wherever the press falls between two 50 Hz samples, the true distance lies in [lo, hi], and the interval is at
    least as wide as the distance driven in the samples' interval (v0 * 20 ms)."""
    onset = 2.0 + phase_s
    t, v, a, truth_m = _stop(onset)
    bt = np.arange(0.0, 6.0, 0.02)
    bv = (bt >= onset).astype(float)
    f = brake_figures(t, v, a, brake_time_s=bt, brake_value=bv)
    assert f is not None and f.stopping_distance_m is not None
    iv = brake_intervals(t, v, a, f, bt)["stopping_distance_m"]
    assert iv is not None
    lo, hi = iv
    assert lo <= truth_m <= hi
    assert hi - lo >= 27.0 * 0.02 * 0.99
    assert abs(f.stopping_distance_m - truth_m) <= 27.0 * 0.01 + 0.01  # the midpoint: at most half an interval off
    # from a time mark there is no onset term: the interval is the speed's alone, narrower by the switch's
    m = brake_figures(t, v, a, mark_time_s=[onset])
    assert m is not None and m.stopping_distance_m == pytest.approx(truth_m, abs=0.005)
    mlo, mhi = brake_intervals(t, v, a, m)["stopping_distance_m"] or (math.nan, math.nan)
    assert mlo <= truth_m <= mhi
    assert (hi - lo) - (mhi - mlo) >= 27.0 * 0.02 * 0.99


def test_speed_at_onset_is_interpolated_between_rows() -> None:
    """v0 on the fused speed's rows at the onset instant, not the nearest row's."""
    t = np.arange(0.0, 10.0, 0.1)  # rows 100 ms apart, the onset 40 ms after one
    onset = 3.04
    v = np.where(t < onset, 20.0 + 0.5 * t, np.maximum(20.0 + 0.5 * onset - 8.0 * (t - onset), 0.0))
    a = np.gradient(v, t)
    f = brake_figures(t, v, a, mark_time_s=[onset])
    assert f is not None
    assert f.brake_speed_kmh == pytest.approx(float(np.interp(onset, t, v)) * 3.6, rel=1e-12)
    assert f.brake_speed_kmh != pytest.approx(float(v[30]) * 3.6, rel=1e-4)


# ---- an ABS stop from 100 km/h, imported from a raw capture ------------------------------------------------------

ONSET_S = 4.0173
"""Off the 50 Hz switch's grid (the worst case for the first pressed sample is a whole interval)."""
ABS_SETTINGS = SimSettings(imu_rate_hz=100.0, brake_rate_hz=50.0, wpt_rate_hz=100.0, gps_latency_s=0.05, seed=3,
                           can_jitter_s=0.0005, brake_speed_kmh=100.0, brake_onset_s=ONSET_S,
                           brake_timemark_edge="rising")


def _config(tmp_path: Path, source: str, edge: str = "rising") -> Path:
    text = CONFIG.read_text().replace('dbc = "wpt.dbc"', 'dbc = ["wpt.dbc", "sensors.dbc"]')
    text += ('\n[imu]\nmessage = "IMU_ACCEL"\nsignal = "AccelX"\n\n'
             f'[brake]\nmessage = "BRAKE"\nsignal = "BrakePressed"\nsource = "{source}"\nedge = "{edge}"\n')
    for name in ("wpt.dbc", "sensors.dbc"):
        (tmp_path / name).write_text((CONFIG.parent / name).read_text())
    p = tmp_path / f"{source}-{edge}.toml"
    p.write_text(text)
    return p


@cache
def _abs_drive(directory: str) -> tuple[Path, Path, float]:
    """CAN log and raw GPS capture (NMEA and the TIM-TM2 mark, no stamps) of the stop; the true stopping distance."""
    from slipdaq.config import load_config

    d = Path(directory)
    cfg = load_config(_config(d, "can"))
    can_path, raw_path = d / "abs.log", d / "abs.gps"
    truth = write_drive_logs(generate(cfg, "brake-abs", "paved", ABS_SETTINGS, 12.0), can_path, raw_path, gps_raw=True)
    assert brake_onset_time_s(truth) == pytest.approx(ONSET_S)
    assert speed_at_onset_mps(truth) == pytest.approx(100.0 / 3.6)
    distance = stopping_distance_m(truth)
    assert distance is not None
    return can_path, raw_path, distance


@pytest.fixture(scope="module")
def abs_drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, float]:
    return _abs_drive(str(tmp_path_factory.mktemp("abs")))


def _import(abs_drive: tuple[Path, Path, float], tmp_path: Path, source: str,
            edge: str = "rising") -> tuple[list[dict], list[dict]]:
    can_path, raw_path, _ = abs_drive
    out = tmp_path / f"{source}.mcap"
    assert main(["import", "--can", str(can_path), "--gps-raw", str(raw_path),
                 "--config", str(_config(tmp_path, source, edge)), "-o", str(out)]) == 0
    with open(out, "rb") as f:
        msgs = [(ch.topic, json.loads(m.data)) for _s, ch, m in make_reader(f).iter_messages(
            topics=["/maneuver", "/can/sensors"])]
    return [m for t, m in msgs if t == "/maneuver" and m["kind"] == "brake"], \
        [m for t, m in msgs if t == "/can/sensors"]


def test_raw_capture_import_places_messages_by_their_gnss_time(abs_drive, tmp_path: Path) -> None:
    """No stamps in the capture: every fix is placed at its own UTC, the CAN log's clock (here: UTC itself)."""
    _can, raw_path, _ = abs_drive
    assert raw_path.read_bytes()[:1] == b"$" and b"\xb5\x62\x0d\x03" in raw_path.read_bytes()
    out = tmp_path / "raw.mcap"
    assert main(["import", "--can", str(abs_drive[0]), "--gps-raw", str(raw_path),
                 "--config", str(_config(tmp_path, "can")), "-o", str(out)]) == 0
    with open(out, "rb") as f:
        msgs = [(ch.topic, json.loads(m.data)) for _s, ch, m in make_reader(f).iter_messages(
            topics=["/gps/fix", "/gps/ubx/raw"])]
    fixes = [m for t, m in msgs if t == "/gps/fix"]
    assert len(fixes) == 120
    assert all(fx["timestamp_s"] == pytest.approx(fx["fix_time_utc_s"], abs=1e-6) for fx in fixes)
    assert len([m for t, m in msgs if t == "/gps/ubx/raw"]) == 1  # the time mark, kept raw


def test_time_mark_gives_the_stopping_distance_within_5_cm(abs_drive, tmp_path: Path) -> None:
    stops, sensors = _import(abs_drive, tmp_path, "gps-timemark")
    marks = [s for s in sensors if s["kind"] == "brake_mark"]
    assert len(marks) == 1
    assert marks[0]["time_s"] == pytest.approx(ABS_SETTINGS.start_utc_s + ONSET_S, abs=5e-4)
    assert len(stops) == 1
    truth = abs_drive[2]
    assert abs(stops[0]["stopping_distance_m"] - truth) < 0.05
    assert stops[0]["stopping_distance_m_lo"] <= truth <= stops[0]["stopping_distance_m_hi"]


def test_time_mark_of_the_other_edge_is_not_the_press(abs_drive, tmp_path: Path) -> None:
    """The receiver marked a rising edge; a config that says the press is the falling edge takes no mark (and falls
    back to the CAN switch)."""
    stops, sensors = _import(abs_drive, tmp_path, "gps-timemark", "falling")
    assert not [s for s in sensors if s["kind"] == "brake_mark"]
    assert len(stops) == 1


def test_50_hz_brake_switch_within_30_cm_and_truth_inside_its_interval(abs_drive, tmp_path: Path) -> None:
    stops, _ = _import(abs_drive, tmp_path, "can")
    assert len(stops) == 1
    s, truth = stops[0], abs_drive[2]
    assert abs(s["stopping_distance_m"] - truth) < 0.3
    assert s["stopping_distance_m_lo"] <= truth <= s["stopping_distance_m_hi"]
    assert s["stopping_distance_m_hi"] - s["stopping_distance_m_lo"] >= 100.0 / 3.6 * 0.02  # the switch's interval


def test_live_time_mark_on_the_gps_port(tmp_path: Path) -> None:
    """The daemon reading NMEA with the TIM-TM2 mark between on a real pty ([brake] source = "gps-timemark"): the
    mark is placed on the host's clock within 5 ms of the press, and the stop's onset is it."""
    from slipdaq.live.demo import demo_config
    from slipdaq.live.simulate import PtyGps
    from slipdaq.logformat.reader import iter_topic

    gps = PtyGps()
    channel = f"timemark-live-{id(gps)}"
    cfg = demo_config(gps.path, channel, "brake-abs").with_overrides(brake={"source": "gps-timemark"})
    log = tmp_path / "live.mcap"
    run = drive_live(cfg, gps, channel, log, "brake-abs", ABS_SETTINGS, 11.0, 12.5)
    marks = [d for _, _, d in iter_topic(log, ("/can/sensors",)) if d["kind"] == "brake_mark"]
    assert len(marks) == 1
    assert abs(marks[0]["time_s"] - (run.start_utc_s + ONSET_S)) < 0.005
    stops = [d for _, _, d in iter_topic(log, ("/maneuver",)) if d["kind"] == "brake"]
    assert len(stops) == 1 and abs(stops[0]["brake_speed_kmh"] - 100.0) < 1.0


def test_raw_capture_without_a_gnss_time_is_a_clear_error(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    can = tmp_path / "one.log"
    can.write_text("(1700000000.000000) can0 123#00\n")
    raw = tmp_path / "no-time.ubx"
    raw.write_bytes(b"$GPTXT,01,01,02,u-blox*00\r\n" + tim_tm2_frame(1_700_000_000.5, "rising", 1) + b"(12.5) x\n")
    rc = main(["import", "--can", str(can), "--gps-raw", str(raw), "--config", str(CONFIG), "-o", str(tmp_path / "o.mcap")])
    err = capsys.readouterr().err
    assert rc == 1 and "no-time.ubx" in err and "GNSS time" in err
    assert not (tmp_path / "o.mcap").exists()
