"""The fuzzing battery: every reader of a file someone else wrote, fed real seed files damaged by
hypothesis (tests/fuzz_support.py: bits flipped, bytes overwritten, zeroed, cut, inserted, deleted, duplicated,
syntax tokens dropped in), must raise only its documented error, return, exit 0/1/2 (3 from `recover` with losses)
and leave nothing behind when it fails.

A short, reproducible run here (derandomized: the same inputs every time, seconds in all); the long run, random,
SCALE times as many inputs per target: `SLIPDAQ_FUZZ_SCALE=50 .venv/bin/python -m pytest tests/test_fuzz.py -q
--hypothesis-show-statistics` (docs/reliability.md, "Fuzzing", has its figures). Each crash or hang a run found is a
regression test at the end of this file.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.logformat.errors import LogError
from slipdaq.logformat.reader import iter_raw_records
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from support import fuzz_support as fz
from support.paths import CONFIG, DATA, ROOT, write_config

SCALE = int(os.environ.get("SLIPDAQ_FUZZ_SCALE", "0"))


def runs(short: int) -> settings:
    """`short` inputs, the same every time; SLIPDAQ_FUZZ_SCALE times as many random ones for a long run."""
    return settings(max_examples=short * (SCALE or 1), derandomize=not SCALE, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture, HealthCheck.large_base_example])


class Seeds(dict):  # type: ignore[type-arg]  # {kind: {file name: bytes}}
    def __repr__(self) -> str:  # hypothesis prints a failing case's arguments: not the seeds' megabytes
        return f"Seeds({', '.join(f'{k}: {sorted(v)}' for k, v in self.items())})"


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, bytes]]:
    """Seed files: slipdaq logs (an import of a 3 s simulated drive in 32 KiB chunks, with the calibration it saved,
    and the log of commit 42c5f78), the drive's candump and NMEA logs."""
    d = tmp_path_factory.mktemp("fuzz-seeds")
    cfg = write_config(d, CONFIG.read_text().replace("# chunk_size_bytes = 1048576", "chunk_size_bytes = 32768"))
    write_drive_logs(generate(load_config(cfg), "cycle", "paved", SimSettings(seed=7), duration_s=3.0),
                     d / "drive.log", d / "drive.nmea")
    assert main(["import", "--can", str(d / "drive.log"), "--nmea", str(d / "drive.nmea"), "--config", str(cfg),
                 "-o", str(d / "drive.mcap"), "--calibration", str(d / "calibration.toml")]) == 0
    old = DATA / "slipdaq-42c5f78" / "logfile-asc-import.mcap"
    return Seeds(mcap={"drive.mcap": (d / "drive.mcap").read_bytes(), old.name: old.read_bytes()},
                 calibration={"calibration.toml": (d / "calibration.toml").read_bytes()},
                 drive={"drive.log": (d / "drive.log").read_bytes(), "drive.nmea": (d / "drive.nmea").read_bytes()})


def fresh(tmp_path: Path) -> Path:
    return Path(tempfile.mkdtemp(dir=tmp_path))


def put(d: Path, name: str, data: bytes) -> Path:
    (d / name).write_bytes(data)
    return d / name


@runs(40)
@given(data=st.data())
def test_fuzz_mcap_reader_salvage_and_recover(seeds: dict[str, dict[str, bytes]], tmp_path: Path,
                                               data: st.DataObject) -> None:
    name, damaged = data.draw(fz.damaged(seeds["mcap"]))
    d = fresh(tmp_path)
    fz.mcap_readers(put(d, name, damaged), d)


@runs(8)
@given(data=st.data())
def test_fuzz_mcap_verbs(seeds: dict[str, dict[str, bytes]], tmp_path: Path, data: st.DataObject) -> None:
    name, damaged = data.draw(fz.damaged(seeds["mcap"]))
    d = fresh(tmp_path)
    fz.mcap_verbs(put(d, name, damaged), d, replay=True)


@runs(3)
@given(data=st.data())
def test_fuzz_report_verb(seeds: dict[str, dict[str, bytes]], tmp_path: Path, data: st.DataObject) -> None:
    name, damaged = data.draw(fz.damaged(seeds["mcap"]))
    d = fresh(tmp_path)
    fz.report_verb(put(d, name, damaged), d)


@runs(60)
@given(case=fz.damaged(fz.gps_seeds()), pieces=st.lists(st.integers(1, 700), max_size=30))
def test_fuzz_gps_framer_and_decoders(case: tuple[str, bytes], pieces: list[int]) -> None:
    fz.gps_decoders(case[1], pieces)


@runs(30)
@given(case=fz.damaged(fz.gps_seeds()))
def test_fuzz_nmea_log_import(case: tuple[str, bytes], tmp_path: Path) -> None:
    fz.nmea_log(put(fresh(tmp_path), case[0], case[1]))


@runs(60)
@given(case=fz.damaged(fz.can_seeds()))
def test_fuzz_can_log_import(case: tuple[str, bytes], tmp_path: Path) -> None:
    fz.can_log(put(fresh(tmp_path), case[0], case[1]))


@runs(40)
@given(case=fz.damaged(fz.config_seeds(), max_edits=2))
def test_fuzz_config(case: tuple[str, bytes], tmp_path: Path) -> None:
    d = fresh(tmp_path)
    for dbc in [*(ROOT / "config").glob("*.dbc"), *(ROOT / "config" / "examples").glob("*.dbc")]:
        shutil.copy(dbc, d / dbc.name)
    fz.config_file(put(d, case[0], case[1]))


@runs(25)
@given(data=st.data())
def test_fuzz_calibration(seeds: dict[str, dict[str, bytes]], tmp_path: Path, data: st.DataObject) -> None:
    name, damaged = data.draw(fz.damaged(seeds["calibration"], max_edits=2))
    fz.calibration_file(put(fresh(tmp_path), name, damaged))


@runs(6)
@given(data=st.data())
def test_fuzz_import_verb(seeds: dict[str, dict[str, bytes]], tmp_path: Path, data: st.DataObject) -> None:
    """`import` of a damaged candump log or NMEA log (the other one as it was): exit 0 or 1, nothing left on 1."""
    name, damaged = data.draw(fz.damaged(seeds["drive"]))
    d = fresh(tmp_path)
    for n, b in seeds["drive"].items():
        put(d, n, damaged if n == name else b)
    before = fz.left(d)
    rc = fz.cli(["import", "--can", d / "drive.log", "--nmea", d / "drive.nmea", "--config", CONFIG,
                 "-o", d / "out.mcap", "--no-calibration"], {0, 1})
    assert (rc == 1) == (fz.left(d) == before)


# ---- regressions: what the runs found ----

@pytest.mark.parametrize("which", ["drive.log", "drive.nmea"])
def test_regression_a_time_stamp_no_log_holds_is_one_line(seeds: dict[str, dict[str, bytes]], tmp_path: Path,
                                                          which: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Found by test_fuzz_import_verb: a candump line whose stamp lost its decimal point (1767220274.999 s became
    176722027499.9 s, after the year 2554) made the MCAP writer raise struct.error out of `import` (a traceback). A
    stamp no log can hold is now one line naming the file and the frame or line, exit 1, nothing left."""
    d = fresh(tmp_path)
    for n, b in seeds["drive"].items():
        put(d, n, b)
    text = (d / which).read_bytes()
    first = text.index(b"(") + 1
    (d / which).write_bytes(text[:first] + b"99" + text[first:])  # the first stamp, 100 times later
    before = fz.left(d)
    capsys.readouterr()
    rc = main([str(a) for a in ["import", "--can", d / "drive.log", "--nmea", d / "drive.nmea", "--config", CONFIG,
                                "-o", d / "out.mcap", "--no-calibration"]])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1 and "Traceback" not in err
    assert f"{d / which}: {'frame' if which == 'drive.log' else 'line'} 1 is stamped " in err and "no log holds" in err
    assert fz.left(d) == before


def test_regression_damaged_can_channels_metadata_is_a_log_error(seeds: dict[str, dict[str, bytes]], tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Found by test_fuzz_mcap_reader_salvage_and_recover: a byte flipped inside the metadata's can_channels (a
    metadata record has no CRC, and the flip kept it valid UTF-8) made iter_raw_records raise json's
    JSONDecodeError. It is now a LogError naming the file; `replay` exits 1 with one line, nothing left."""
    data = seeds["mcap"]["drive.mcap"]
    assert data.count(b'["can0"]') >= 1
    d = fresh(tmp_path)
    bad = put(d, "bad.mcap", data.replace(b'["can0"]', b'["can0#]'))
    with pytest.raises(LogError, match=r"bad\.mcap: its metadata's can_channels is not a list of CAN channel names"):
        list(iter_raw_records(bad))
    capsys.readouterr()
    assert main(["replay", str(bad), "-o", str(d / "out.mcap"), "--no-calibration"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "can_channels" in err and fz.left(d) == ["bad.mcap"]
