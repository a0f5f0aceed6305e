"""Inputs that must destroy nothing and crash nothing: an output path that is an input, malformed and
empty inputs, outputs that are in place only when complete, and live logs that never overwrite a file.

Every failing case is checked the same way: the exit status, one line on stderr naming the file, no traceback, and
the directory exactly as before (inputs byte-identical, no output, no temporary file, no new directory)."""

from __future__ import annotations

import asyncio
import datetime as dt
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

import can
import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.live.daemon import new_log_path, run_daemon
from slipdaq.logformat.reader import iter_estimates, iter_raw_records, read_metadata
from slipdaq.logformat.rotation import segment_path
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from support.paths import CONFIG, DATA

PYCAN = DATA / "python-can"


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory with a 4 s simulated drive: drive.log (candump -L), drive.nmea, and its import drive.mcap."""
    d = tmp_path_factory.mktemp("drive")
    cfg = load_config(CONFIG)
    write_drive_logs(generate(cfg, "cycle", "paved", SimSettings(seed=3), duration_s=4.0),
                     d / "drive.log", d / "drive.nmea")
    assert main(["import", "--can", str(d / "drive.log"), "--nmea", str(d / "drive.nmea"), "--config", str(CONFIG),
                 "-o", str(d / "drive.mcap")]) == 0
    return d


@pytest.fixture
def work(drive: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fresh copy of the drive as the current directory."""
    for p in drive.iterdir():
        shutil.copy(p, tmp_path / p.name)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def snapshot(d: Path) -> dict[str, object]:
    """Every file (its bytes), symlink (its target) and directory under d, hidden ones included."""
    out: dict[str, object] = {}
    for p in sorted(d.rglob("*")):
        key = p.relative_to(d).as_posix()
        out[key] = ("link", os.readlink(p)) if p.is_symlink() else "dir" if p.is_dir() else p.read_bytes()
    return out


def fails_cleanly(args: list[str], d: Path, capsys: pytest.CaptureFixture[str], status: int, *names: str) -> str:
    """Run the CLI; assert the exit status, one line on stderr naming `names`, and d exactly as before."""
    before = snapshot(d)
    capsys.readouterr()
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == status, err
    assert err.startswith("slipdaq: ") and err.endswith("\n") and err.count("\n") == 1, err
    assert "Traceback" not in err
    for name in names:
        assert name in err, err
    assert snapshot(d) == before
    return err


IMPORT = ["import", "--can", "drive.log", "--nmea", "drive.nmea", "--config", str(CONFIG)]


# ---- 1. an output path that is one of the inputs ----

def _links(d: Path) -> None:
    (d / "link.log").symlink_to("drive.log")
    os.link(d / "drive.nmea", d / "hard.nmea")
    (d / "link.mcap").symlink_to(d / "drive.mcap")
    os.link(d / "drive.mcap", d / "hard.mcap")
    shutil.copy(CONFIG, d / "slipdaq.toml")
    shutil.copy(CONFIG.parent / "wpt.dbc", d / "wpt.dbc")
    (d / "rep").mkdir()
    shutil.copy(d / "drive.mcap", d / "rep" / "index.html")


@pytest.mark.parametrize("args, output", [
    (IMPORT + ["-o", "drive.log"], "drive.log"),
    (IMPORT + ["-o", "./drive.nmea"], "./drive.nmea"),
    (IMPORT + ["-o", "link.log"], "link.log"),
    (IMPORT + ["-o", "hard.nmea"], "hard.nmea"),
    (["import", "--can", "drive.log", "--nmea", "drive.nmea", "--config", "slipdaq.toml", "-o", "slipdaq.toml"],
     "slipdaq.toml"),
    (["replay", "drive.mcap", "-o", "./drive.mcap"], "./drive.mcap"),
    (["replay", "drive.mcap", "-o", "link.mcap"], "link.mcap"),
    (["export", "drive.mcap", "--csv", "drive.mcap"], "drive.mcap"),
    (["export", "drive.mcap", "--csv", "hard.mcap"], "hard.mcap"),
    (["recover", "drive.mcap", "-o", "./drive.mcap"], "./drive.mcap"),
    (["recover", "drive.mcap", "-o", "hard.mcap"], "hard.mcap"),
    (["report", "drive.mcap", "-o", "drive.mcap"], "drive.mcap"),
    (["report", "rep/index.html", "-o", "rep"], "rep/index.html"),
], ids=["import-can", "import-nmea-dot", "import-symlink", "import-hardlink", "import-config", "replay-dot",
        "replay-symlink", "export-same", "export-hardlink", "recover-dot", "recover-hardlink", "report-file",
        "report-index"])
def test_an_output_that_is_an_input_is_refused(work: Path, capsys: pytest.CaptureFixture[str], args: list[str],
                                               output: str) -> None:
    _links(work)
    err = fails_cleanly(args, work, capsys, 2, output, "would overwrite the input")
    assert err.count(":") >= 2  # names the output and the input


# ---- 2. outputs in place only when complete ----

def _bad_id_log(d: Path) -> Path:
    """drive.log with line 101 holding a CAN ID that is not hex."""
    lines = (d / "drive.log").read_bytes().splitlines(keepends=True)
    p = d / "bad-id.log"
    p.write_bytes(b"".join(lines[:100]) + b"(1767225600.250000) can0 XYZ#00\n" + b"".join(lines[100:]))
    return p


def test_a_failed_import_leaves_the_previous_output_as_it_was(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A good log at the output path; an import that finds a bad record midway: the good log is untouched."""
    _bad_id_log(work)
    fails_cleanly(["import", "--can", "bad-id.log", "--nmea", "drive.nmea", "--config", str(CONFIG),
                   "-o", "drive.mcap"], work, capsys, 1, "bad-id.log")
    assert len(list(iter_estimates(work / "drive.mcap"))) > 0


def test_a_failed_import_into_new_directories_leaves_none(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _bad_id_log(work)
    fails_cleanly(["import", "--can", "bad-id.log", "--nmea", "drive.nmea", "--config", str(CONFIG),
                   "-o", "new/dir/out.mcap"], work, capsys, 1, "bad-id.log")


def test_interrupted_output_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    """Ctrl-C (KeyboardInterrupt) while an output is being written: the old file stays, nothing else is left."""
    from slipdaq.outputs import atomic_output

    out = tmp_path / "out.csv"
    out.write_text("good\n")
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(out) as tmp:
            tmp.write_text("half")
            raise KeyboardInterrupt
    assert sorted(tmp_path.iterdir()) == [out] and out.read_text() == "good\n"
    with atomic_output(out) as tmp:
        assert tmp.parent == tmp_path and tmp != out
        tmp.write_text("new\n")
        assert out.read_text() == "good\n"  # in place only at the end
    assert sorted(tmp_path.iterdir()) == [out] and out.read_text() == "new\n"


def test_a_report_that_fails_leaves_its_directory_as_it_was(tmp_path: Path) -> None:
    """An older report in DIR; a new one that fails midway changes nothing in it; a DIR made for it is removed."""
    from slipdaq.outputs import atomic_tree

    old = tmp_path / "rep"
    (old / "a").mkdir(parents=True)
    (old / "index.html").write_text("old index")
    (old / "a" / "x.png").write_bytes(b"old png")
    before = snapshot(tmp_path)
    with pytest.raises(RuntimeError):
        with atomic_tree(old, last=("index.html",)) as build:
            (build / "a").mkdir()
            (build / "a" / "x.png").write_bytes(b"new png")
            (build / "index.html").write_text("new index")
            raise RuntimeError("a plot failed")
    assert snapshot(tmp_path) == before
    with pytest.raises(RuntimeError):
        with atomic_tree(tmp_path / "new" / "rep") as build:
            (build / "index.html").write_text("new index")
            raise RuntimeError("a plot failed")
    assert snapshot(tmp_path) == before
    with atomic_tree(old, last=("index.html",)) as build:
        (build / "a").mkdir()
        (build / "a" / "x.png").write_bytes(b"new png")
        (build / "index.html").write_text("new index")
    assert snapshot(old) == {"a": "dir", "a/x.png": b"new png", "index.html": b"new index"}


# ---- 3. read errors: one line naming the file and where ----

def _bad_can_logs(d: Path) -> dict[str, str]:
    """name -> what the error line must say."""
    (d / "random.blf").write_bytes(random.Random(13).randbytes(4096))
    (d / "cut.blf").write_bytes((PYCAN / "test_CanMessage.blf").read_bytes()[:300])
    lines = (d / "drive.log").read_bytes().splitlines(keepends=True)
    (d / "latin1.log").write_bytes(b"".join(lines[:100]) + b"(1767225600.250000) can0 31\xff#00\n"
                                   + b"".join(lines[100:]))
    _bad_id_log(d)
    return {"random.blf": "python-can cannot read it", "cut.blf": "after record 2",
            "latin1.log": "line 101 is not utf-8 text", "bad-id.log": "after record 100"}


@pytest.mark.parametrize("name", ["random.blf", "cut.blf", "latin1.log", "bad-id.log"])
def test_a_malformed_can_log_is_one_line_and_leaves_nothing(work: Path, capsys: pytest.CaptureFixture[str],
                                                             name: str) -> None:
    where = _bad_can_logs(work)[name]
    fails_cleanly(["import", "--can", name, "--nmea", "drive.nmea", "--config", str(CONFIG), "-o", "out.mcap"],
                  work, capsys, 1, name, where)


def test_a_malformed_can_log_prints_no_traceback_from_the_command(work: Path) -> None:
    """The installed entry point, as a user runs it: one line per bad file, exit 1, nothing left."""
    where = _bad_can_logs(work)
    before = snapshot(work)
    for name, text in where.items():
        r = subprocess.run([sys.executable, "-m", "slipdaq", "import", "--can", name, "--nmea", "drive.nmea",
                            "--config", str(CONFIG), "-o", "out.mcap"], cwd=work, capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 1, r.stderr
        assert r.stderr.count("\n") == 1 and name in r.stderr and text in r.stderr, r.stderr
        assert snapshot(work) == before


def _corrupt_a_chunk(src: Path, dst: Path) -> None:
    """A copy of a finished log with bytes in the middle of its first chunk flipped."""
    data = bytearray(src.read_bytes())
    with open(src, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes
    c = summary.chunk_indexes[0]
    mid = c.chunk_start_offset + c.chunk_length // 2
    data[mid:mid + 4] = bytes(b ^ 0xFF for b in data[mid:mid + 4])
    dst.write_bytes(bytes(data))


@pytest.mark.parametrize("verb", ["replay", "export"])
def test_a_corrupt_log_is_one_line_and_leaves_nothing(work: Path, capsys: pytest.CaptureFixture[str],
                                                      verb: str) -> None:
    _corrupt_a_chunk(work / "drive.mcap", work / "corrupt.mcap")
    out = ["-o", "out.mcap"] if verb == "replay" else ["--csv", "out.csv"]
    with open(work / "drive.mcap", "rb") as f:
        c = make_reader(f).get_summary().chunk_indexes[0]  # type: ignore[union-attr]  # a finished log
    err = fails_cleanly([verb, "corrupt.mcap", *out], work, capsys, 1, "corrupt.mcap",
                        f"damaged at bytes {c.chunk_start_offset}-{c.chunk_start_offset + c.chunk_length} ",
                        "`slipdaq recover corrupt.mcap -o FIXED.mcap`")
    # flipped bytes of a compressed chunk: its CRC or the decompressor finds them, depending on where they fall
    assert "fails its CRC check" in err or "does not decompress" in err, err
    assert "at its start" not in err


# ---- 4. empty inputs ----

def _empty_inputs(d: Path) -> None:
    (d / "empty.log").write_bytes(b"")
    # python-can's test_CanMessage.asc without its two frames: header and trigger block only
    (d / "header.asc").write_text("".join(line for line in (PYCAN / "test_CanMessage.asc").read_text()
                                          .splitlines(keepends=True) if " d " not in line))
    (d / "empty.nmea").write_bytes(b"")
    (d / "garbage.nmea").write_bytes(b"# a receiver at the wrong baud rate\n\x00\xf0\x8c\x00x\x00\n"
                                     b"$GPRMC,garbage*00\nhello\n")


@pytest.mark.parametrize("can_log, nmea_log, says", [
    ("empty.log", "drive.nmea", "empty.log: no CAN frames"),
    ("header.asc", "drive.nmea", "header.asc: no CAN frames"),
    ("drive.log", "empty.nmea", "empty.nmea: no NMEA lines"),
    ("drive.log", "garbage.nmea", "garbage.nmea: no usable NMEA: 0 fixes"),
], ids=["empty-candump", "header-only-asc", "empty-nmea", "garbage-nmea"])
def test_an_empty_input_fails_unless_allowed(work: Path, capsys: pytest.CaptureFixture[str], can_log: str,
                                             nmea_log: str, says: str) -> None:
    _empty_inputs(work)
    args = ["import", "--can", can_log, "--nmea", nmea_log, "--config", str(CONFIG), "-o", "out.mcap"]
    fails_cleanly(args, work, capsys, 1, says, "--allow-empty")
    assert main([*args, "--allow-empty"]) == 0
    assert read_metadata(work / "out.mcap")["import_can"] == can_log


def test_replay_and_export_of_a_log_with_nothing_in_it_fail_unless_allowed(
        work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _empty_inputs(work)
    assert main(["import", "--can", "empty.log", "--nmea", "empty.nmea", "--config", str(CONFIG), "-o", "none.mcap",
                 "--allow-empty"]) == 0
    assert list(iter_raw_records(work / "none.mcap")) == []
    fails_cleanly(["replay", "none.mcap", "-o", "out.mcap"], work, capsys, 1, "none.mcap: no raw CAN or GPS records")
    fails_cleanly(["export", "none.mcap", "--csv", "out.csv"], work, capsys, 1, "none.mcap: no estimates")
    assert main(["replay", "none.mcap", "-o", "out.mcap", "--allow-empty"]) == 0
    assert main(["export", "none.mcap", "--csv", "out.csv", "--allow-empty"]) == 0
    assert (work / "out.csv").read_text().count("\n") == 1  # the header


# ---- run and demo: a new log never overwrites a file ----

def test_a_new_log_name_is_clear_of_every_segment_name(tmp_path: Path) -> None:
    """Files named like the second segment of the run about to start (a clock without a battery comes back to the
    same time): the new run takes a name none of whose segments exists."""
    now = dt.datetime.now(dt.UTC)
    taken = {}
    for s in range(-2, 30):
        stamp = (now + dt.timedelta(seconds=s)).strftime("%Y%m%d-%H%M%S")
        p = tmp_path / f"demo-{stamp}_002.mcap"
        p.write_bytes(b"an earlier run's second segment " + stamp.encode())
        taken[p] = p.read_bytes()
    path = new_log_path(tmp_path, "demo")
    assert not path.exists()
    assert all(not segment_path(path, n).exists() for n in range(2, 5))
    assert all(p.read_bytes() == b for p, b in taken.items())


def test_the_live_log_never_overwrites_a_file(tmp_path: Path) -> None:
    """run_daemon given a path that is there: FileExistsError before anything is read, the file untouched."""
    path = tmp_path / "slipdaq-20260101-000000.mcap"
    path.write_bytes(b"yesterday's log")
    cfg = load_config(CONFIG).with_overrides(can={"interface": "virtual", "channel": f"bad-inputs-{os.getpid()}"},
                                             gps={"port": str(tmp_path / "no-such-port")})

    async def run() -> None:
        with can.Bus(interface="virtual", channel=cfg.can.channel) as bus:
            await run_daemon(cfg, bus, path, duration_s=0.3, status_stream=open(os.devnull, "w"))

    with pytest.raises(FileExistsError):
        asyncio.run(run())
    assert path.read_bytes() == b"yesterday's log"
    assert sorted(tmp_path.iterdir()) == [path]
