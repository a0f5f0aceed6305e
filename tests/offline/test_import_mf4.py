"""`slipdaq import --mf4`: real CANedge logs (CSS Electronics' examples, MIT: tests/data/css-electronics) in both bus-
logging layouts (one CAN_DataFrame group; per-channel groups CAN1_Rx, CAN9_Rx, ...), a split session joined in time
order, every frame kept as asammdf reads it, and the reference speed from a GNSS on the bus equal to asammdf's own
DBC decoding of the same frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from slipdaq.cli import main
from slipdaq.logformat.reader import iter_raw_records, iter_topic
from slipdaq.logformat.topics import TOPIC_GPS
from slipdaq.records import CanFrame
from support.paths import CONFIG

asammdf = pytest.importorskip("asammdf")
DATA = Path(__file__).resolve().parents[1] / "data" / "css-electronics"
CANMOD = DATA / "3BA199E2" / "00000164" / "00000005-60FEB5A8.MF4"  # one CAN_DataFrame group, a CANmod.gps on bus 2
SPLIT = sorted((DATA / "2F6913DB" / "00001089").glob("*.MF4"))  # per-channel groups, a session in two files
NO_GNSS_DBC = DATA / "7512BE4D" / "00000427" / "00000001.MF4"  # per-channel, GNSS on bus 9 that no DBC here decodes
REFERENCE = {"canmod-gps.dbc": CANMOD, "canedge-gnss.dbc": SPLIT[0]}


def _config(tmp: Path, dbc: str) -> Path:
    """The packaged config with the wheels' DBC and the GNSS DBC, the reference speed from CAN (gnss_speed.Speed)."""
    for name in ("wpt.dbc",):
        (tmp / name).write_text((CONFIG.parent / name).read_text())
    (tmp / dbc).write_text((DATA / dbc).read_text())
    text = CONFIG.read_text().replace('dbc = "wpt.dbc"', f'dbc = ["wpt.dbc", "{dbc}"]')
    text = text.replace('latency_s = "auto"', 'latency_s = "auto"\nsource = "can"\nmessage = "gnss_speed"\n'
                        'signal = "Speed"\nvalid_signal = "SpeedValid"\naccuracy_signal = "SpeedAccuracy"')
    path = tmp / f"{dbc}.toml"
    path.write_text(text)
    return path


def _asammdf_frames(paths: list[Path]) -> list[tuple[float, int, bool, bytes, str, bool]]:
    """(time, id, extended, data, bus channel, rx) of every CAN data frame of the files, by asammdf's raw columns of
    each bus-logging group, in time order."""
    out = []
    for path in paths:
        mdf = asammdf.MDF(path)
        start = mdf.start_time.timestamp()
        for g, group in enumerate(mdf.groups):
            names = {c.name for c in group.channels}
            if "CAN_DataFrame.ID" not in names or not group.channel_group.cycles_nr:
                continue
            col = {n: mdf.get(f"CAN_DataFrame.{n}", group=g) for n in ("ID", "IDE", "DataLength", "DataBytes",
                                                                        "BusChannel", "Dir")}
            t = col["ID"].timestamps + start
            for k in range(len(t)):
                n = int(col["DataLength"].samples[k])
                out.append((float(t[k]), int(col["ID"].samples[k]) & 0x1FFFFFFF, bool(col["IDE"].samples[k]),
                            bytes(col["DataBytes"].samples[k][:n]), str(int(col["BusChannel"].samples[k])),
                            not bool(col["Dir"].samples[k])))
    return sorted(out, key=lambda x: x[0])


def _logged_frames(log: Path) -> list[tuple[float, int, bool, bytes, str, bool]]:
    return sorted(((f.timestamp_s, f.arbitration_id, f.is_extended_id, f.data, str(f.channel), f.is_rx)
                   for f in iter_raw_records(log) if isinstance(f, CanFrame)), key=lambda x: x[0])


def _decoded_speed(decoded, dbc: str):  # type: ignore[no-untyped-def]
    """asammdf's gnss_speed.Speed of the message the config's name means (canedge-gnss.dbc has two messages of that
    name, 0x7 and 0x17: the later one is the name's, as cantools and slipdaq take it)."""
    import cantools

    frame_id = cantools.database.load_file(str(DATA / dbc), strict=False).get_message_by_name("gnss_speed").frame_id
    for g, i in decoded.whereis("gnss_speed.Speed"):
        if f"ID=0x{frame_id:X} " in decoded.groups[g].channel_group.acq_name + " ":
            return decoded.get("gnss_speed.Speed", group=g, index=i)
    raise AssertionError(f"asammdf decoded no gnss_speed 0x{frame_id:X}")


@pytest.mark.parametrize("dbc", sorted(REFERENCE))
def test_every_frame_kept_and_the_gnss_speed_as_asammdf_decodes_it(dbc: str, tmp_path: Path) -> None:
    files = [CANMOD] if dbc == "canmod-gps.dbc" else SPLIT
    out = tmp_path / "imported.mcap"
    assert main(["import", "--mf4", *map(str, files), "--config", str(_config(tmp_path, dbc)), "-o", str(out),
                 "--no-calibration"]) == 0
    logged, reference = _logged_frames(out), _asammdf_frames(files)
    assert len(logged) == len(reference) > 1000
    for a, b in zip(logged, reference):
        assert a[0] == pytest.approx(b[0], abs=1e-6) and a[1:] == b[1:]
    fixes = [d for _t, _x, d in iter_topic(out, (TOPIC_GPS,))]
    decoded = asammdf.MDF.concatenate([asammdf.MDF(f) for f in files]) if len(files) > 1 else asammdf.MDF(files[0])
    start = asammdf.MDF(files[0]).start_time.timestamp()
    ref = _decoded_speed(decoded.extract_bus_logging(database_files={"CAN": [(str(DATA / dbc), 0)]}), dbc)
    assert len(fixes) == len(ref.samples) > 40 and {f["sentence"] for f in fixes} == {"CAN"}
    np.testing.assert_allclose([f["speed_mps"] for f in fixes], ref.samples, rtol=0, atol=1e-12)
    np.testing.assert_allclose([f["timestamp_s"] for f in fixes], ref.timestamps + start, atol=1e-5)


def test_a_split_session_is_joined_in_time_order(tmp_path: Path) -> None:
    cfg = _config(tmp_path, "canedge-gnss.dbc")
    out = tmp_path / "joined.mcap"
    assert main(["import", "--mf4", *map(str, reversed(SPLIT)), "--config", str(cfg), "-o", str(out),
                 "--no-calibration"]) == 0  # given last file first
    t = [f[0] for f in _logged_frames(out)]
    raw = [r.timestamp_s for r in iter_raw_records(out) if isinstance(r, CanFrame)]
    assert raw == sorted(raw) and len(t) == sum(len(_asammdf_frames([f])) for f in SPLIT)
    # the same file twice is not one session: refused, nothing written
    bad = tmp_path / "bad.mcap"
    assert main(["import", "--mf4", str(SPLIT[0]), str(SPLIT[0]), "--config", str(cfg), "-o", str(bad),
                 "--no-calibration"]) == 1
    assert not bad.exists()


def test_a_file_without_a_decodable_gnss(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _config(tmp_path, "canedge-gnss.dbc")
    out = tmp_path / "none.mcap"
    capsys.readouterr()
    assert main(["import", "--mf4", str(NO_GNSS_DBC), "--config", str(cfg), "-o", str(out),
                 "--no-calibration"]) == 1
    err = capsys.readouterr().err
    assert "no reference speed in it" in err and "gnss_speed.Speed" in err and not out.exists()
    assert main(["import", "--mf4", str(NO_GNSS_DBC), "--config", str(cfg), "-o", str(out), "--no-calibration",
                 "--allow-empty"]) == 0
    logged, reference = _logged_frames(out), _asammdf_frames([NO_GNSS_DBC])
    assert len(logged) == len(reference) > 70_000 and {f[4] for f in logged} == {"1", "9"}
    assert [f[1:] for f in logged] == [f[1:] for f in reference]
    assert sum(not f[5] for f in logged) > 7000  # the OBD2 requests the logger sent: direction Tx kept


def test_without_nmea_the_reference_must_come_from_can(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["import", "--mf4", str(CANMOD), "--config", str(CONFIG), "-o", str(tmp_path / "x.mcap")]) == 2
    assert "--nmea" in capsys.readouterr().err
