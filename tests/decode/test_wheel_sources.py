"""Wheel sources of two kinds (pulse counts, wheel-speed signals), counter resets, and the real RAV4 drive."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import cantools
import numpy as np
import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.config import ConfigError, load_config
from slipdaq.decode.can_wheels import DbcError, WheelDecoder
from slipdaq.logformat.reader import iter_estimates, iter_topic
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch
from slipdaq.sinks import CollectingSink
from support.paths import CONFIG, ROOT, write_config

EXAMPLES = ROOT / "config" / "examples"
RAV4 = ROOT / "tests" / "data" / "rav4-comma2k19"
SPEED_DBC = '''VERSION ""
NS_ :
BS_:
BU_: ABS
BO_ 464 WHEEL_SPEEDS: 8 ABS
 SG_ WHEEL_SPEED_FL : 7|15@0+ (0.01,0) [0|250] "kph" Vector__XXX
 SG_ WHEEL_SPEED_FR : 8|15@0+ (0.01,0) [0|250] "kph" Vector__XXX
 SG_ WHEEL_SPEED_RL : 25|15@0+ (0.01,0) [0|250] "kph" Vector__XXX
 SG_ WHEEL_SPEED_RR : 42|15@0+ (0.01,0) [0|250] "kph" Vector__XXX
BO_ 465 WHEEL_RPM: 8 ABS
 SG_ RPM_FL : 0|16@1+ (0.1,0) [0|6000] "rpm" Vector__XXX
'''
SPEED_CONFIG = "".join(
    f'[wheels.{w}]\nkind = "speed"\nmessage = "WHEEL_SPEEDS"\nsignal = "WHEEL_SPEED_{w}"\n' for w in ("FL", "FR", "RL", "RR")
)


def test_default_is_the_wpt_contract() -> None:
    cfg = load_config(CONFIG)
    src = cfg.wheel_source("RR")
    assert (src.kind, src.message, src.signal, src.seq_signal) == ("count", "WPT_RR", "PulseCount", "Seq")


def test_speed_source_one_message_for_four_wheels(tmp_path: Path) -> None:
    cfg = load_config(write_config(tmp_path, SPEED_CONFIG + '[can]\ndbc = "wpt.dbc"\n', dbc=SPEED_DBC))
    dec = WheelDecoder(cfg)
    msg = cantools.database.load_string(SPEED_DBC).get_message_by_name("WHEEL_SPEEDS")
    kph = {"FL": 72.0, "FR": 72.36, "RL": 71.64, "RR": 72.0}
    samples = []
    for k in range(101):  # 1 s at 100 Hz, constant speeds
        data = msg.encode({f"WHEEL_SPEED_{w}": v for w, v in kph.items()})
        samples.append(dec.decode(CanFrame(k * 0.01, 464, bytes(data))))
    assert all(len(s) == 4 for s in samples)
    last = {s.wheel: s for s in samples[-1]}
    r = cfg.tire.radius_m
    for w, v in kph.items():
        # 1 s at v km/h is v/3.6 m, i.e. v/3.6/(2*pi*r) revolutions of a wheel of the tire's radius
        assert last[w].revolutions == pytest.approx(v / 3.6 / (2 * math.pi * r), rel=1e-9)
        assert last[w].raw == pytest.approx(v) and last[w].count is None
    assert dec.frames["FL"] == 101


def test_speed_in_rpm_and_config_unit_override(tmp_path: Path) -> None:
    text = '[wheels.FL]\nkind = "speed"\nmessage = "WHEEL_RPM"\nsignal = "RPM_FL"\n[can]\ndbc = "wpt.dbc"\n'
    dbc = SPEED_DBC + (ROOT / "config" / "wpt.dbc").read_text().split("BU_: WPT_NODE SLIPDAQ", 1)[1]
    cfg = load_config(write_config(tmp_path, text, dbc=dbc))
    dec = WheelDecoder(cfg)
    for k in range(3):
        (s,) = dec.decode(CanFrame(k * 0.5, 465, struct.pack("<H6x", 6000)))  # 600.0 rpm = 10 rev/s
    assert s.revolutions == pytest.approx(10.0)


@pytest.mark.parametrize(
    "text, words",
    [
        ('[wheels.FL]\nkind = "speed"\nmessage = "NOPE"\nsignal = "X"\n', "wheels.FL.message"),
        ('[wheels.FL]\nkind = "speed"\nmessage = "WHEEL_SPEEDS"\nsignal = "X"\n', "wheels.FL.signal"),
        ('[wheels.XX]\nkind = "speed"\nmessage = "WHEEL_SPEEDS"\nsignal = "WHEEL_SPEED_FL"\n', "wheels.XX"),
    ],
)
def test_bad_wheel_sources_are_named(tmp_path: Path, text: str, words: str) -> None:
    path = write_config(tmp_path, text, dbc=SPEED_DBC)
    try:
        cfg = load_config(path)
        with pytest.raises(DbcError, match=words.replace(".", r"\.")):
            WheelDecoder(cfg)
    except ConfigError as e:
        assert words in str(e) and str(path) in str(e)


def test_speed_kind_rejects_count_keys(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="pulses_per_rev and seq_signal"):
        load_config(write_config(tmp_path, '[wheels.FL]\nkind = "speed"\nmessage = "M"\nsignal = "S"\npulses_per_rev = 5\n'))


def test_counter_reset_is_a_new_segment_not_a_huge_slip(cfg) -> None:  # type: ignore[no-untyped-def]
    dec = WheelDecoder(cfg)
    counts = [1000 + 10 * k for k in range(50)] + [5 + 10 * k for k in range(50)]  # node reset after 50 frames
    out = [dec.decode(CanFrame(k * 0.01, 0x310, struct.pack("<I3xB", c, k % 256)))[0] for k, c in enumerate(counts)]
    assert dec.counter_resets["FL"] == 1
    steps = np.diff([s.count for s in out])
    assert (steps == 10).all()  # the reset frame continues at the wheel's last rate
    # and a reset to a count just below the wrap, which looks like +2^32-x, is a reset too
    dec2 = WheelDecoder(cfg)
    for k, c in enumerate([500, 510, 2**32 - 7, 2**32 + 3 - 2**32]):
        dec2.decode(CanFrame(k * 0.01, 0x311, struct.pack("<I3xB", c % 2**32, k)))
    assert dec2.counter_resets["FR"] == 1 and dec2.count_wraps["FR"] == 1


def test_honda_example_config_loads_its_dbc() -> None:
    cfg = load_config(EXAMPLES / "honda-civic.toml")
    dec = WheelDecoder(cfg)
    assert dec.wheel_frames(CanFrameBatch.from_frames([CanFrame(0.0, 0x1D0, bytes(8))])).tolist()[0] >= 0
    assert cfg.tire.radius_m == pytest.approx((2 * 0.40 * 235 + 18 * 25.4) / 2000)


@pytest.fixture(scope="module")
def rav4(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rav4") / "rav4.mcap"
    assert main(["import", "--can", str(RAV4 / "rav4_bus0.candump.log"), "--nmea", str(RAV4 / "rav4_ublox.nmea"),
                 "--config", str(EXAMPLES / "rav4-comma2k19.toml"), "-o", str(out)]) == 0
    return out


def test_rav4_real_drive(rav4: Path) -> None:
    """A real car's ABS wheel speeds and u-blox GNSS: r0 calibrated per wheel, latency estimated, slip near 0."""
    diag = [d for _, _, d in iter_topic(rav4, ("/diagnostics",))][-1]
    assert diag["can_frames"] == 53800 and diag["bad_sentences"] == 0
    assert all(n > 4900 for n in diag["wpt_frames"].values())  # WHEEL_SPEEDS at about 83 Hz for 60 s
    est = diag["estimator"]
    for w in ("FL", "FR", "RL", "RR"):
        assert est["r0_source"][w] == "calibrated"
        # wheel speed / u-blox speed has a median of 0.991 on this drive: r0 = 362.15 mm / 0.991 = 365.4 mm
        assert est["r0_m"][w] == pytest.approx(0.36215 / 0.991, abs=0.0015)
    assert est["latency_source"] == "wheels" and 0.05 < est["gps_latency_s"] < 0.25
    rows = list(iter_estimates(rav4))
    assert len(rows) > 500
    for w in ("FL", "FR", "RL", "RR"):
        slips = [r[f"slip_{w}"] for r in rows if r[f"slip_{w}"] is not None and r[f"r0_source_{w}"] == "calibrated"]
        assert len(slips) > 100
        assert abs(float(np.median(slips))) < 0.005  # steady highway drive: within +-0.5 %


def test_rav4_replay_and_export(rav4: Path, tmp_path: Path) -> None:
    """The replay of the import is the import, message for message in file order (log time and bytes): among the
    ABS speeds, other traffic ends the /can/raw batches at frames that carry no wheel sample."""
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(rav4), "-o", str(out)]) == 0
    assert list(iter_estimates(out)) == list(iter_estimates(rav4))

    def messages(path: Path) -> list[tuple[str, int, bytes]]:
        with open(path, "rb") as f:
            return [(c.topic, m.log_time, m.data) for _s, c, m in make_reader(f).iter_messages(log_time_order=False)]

    imported = messages(rav4)
    assert len(imported) > 12000 and messages(out) == imported
    assert main(["export", str(out), "--csv", str(tmp_path / "rav4.csv")]) == 0
    assert (tmp_path / "rav4.csv").read_text().count("\n") == len(list(iter_estimates(rav4))) + 1


def test_rav4_pipeline_counts_unknown_ids(rav4: Path) -> None:
    diag = [d for _, _, d in iter_topic(rav4, ("/diagnostics",))][-1]
    assert diag["unknown_frames"] == 53800 - sum(1 for _ in iter_topic(rav4, ("/can/raw",)) if _[2]["id"] == 0xAA)
    sink = CollectingSink()
    Pipeline(load_config(EXAMPLES / "rav4-comma2k19.toml"), [sink])  # builds from the example config alone
