"""The command's start: python-can imported without asammdf for the verbs that read no file through python-can."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from slipdaq.__main__ import PYTHON_CAN_MF4_VERBS, reads_mf4, verb_of

PROBE = """
import sys
from slipdaq.__main__ import import_python_can
import_python_can(with_mf4={with_mf4})
import can.io.mf4
print(can.io.mf4.asammdf is not None, "asammdf" in sys.modules)
import asammdf  # importable all the same
print(asammdf.__name__)
"""


def test_verb_of() -> None:
    assert verb_of(["replay", "in.mcap", "-o", "out.mcap"]) == "replay"
    assert verb_of(["-v", "import", "--can", "x.mf4"]) == "import"
    assert verb_of(["--version"]) is None
    assert "import" in PYTHON_CAN_MF4_VERBS and "replay" not in PYTHON_CAN_MF4_VERBS


@pytest.mark.skipif(importlib.util.find_spec("asammdf") is None, reason="asammdf (the mdf extra) is not installed")
@pytest.mark.parametrize("with_mf4", [False, True])
def test_python_can_with_and_without_asammdf(with_mf4: bool) -> None:
    got = subprocess.run([sys.executable, "-c", PROBE.format(with_mf4=with_mf4)], capture_output=True, text=True,
                         check=True).stdout.split()
    assert got == [str(with_mf4), str(with_mf4), "asammdf"]


def test_reads_mf4() -> None:
    assert reads_mf4(["import", "--can", "drive.MF4", "--nmea", "d.nmea", "-o", "x.mcap"])
    assert reads_mf4(["import", "--mf4", "a", "b", "-o", "x.mcap"]) and reads_mf4(["import", "--mf4=a", "-o", "x"])
    assert not reads_mf4(["import", "--can", "drive.log", "--nmea", "d.nmea", "-o", "x.mcap"])
    assert not reads_mf4(["export", "x.mcap", "--mf4", "out.mf4"])  # written with asammdf itself, not python-can


COMMAND = """
import runpy, sys
sys.argv = ["slipdaq", *sys.argv[1:]]
try:
    runpy.run_module("slipdaq", run_name="__main__")
except SystemExit as e:
    print("exit", e.code, "asammdf" in sys.modules)
"""


@pytest.mark.skipif(importlib.util.find_spec("asammdf") is None, reason="asammdf (the mdf extra) is not installed")
def test_an_import_loads_asammdf_only_for_an_mf4_file(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`slipdaq import` of a candump log leaves asammdf (and its pandas and sympy) unloaded; of an MF4 file, loads it
    and reads it."""
    from mcap.reader import make_reader

    from conftest import CONFIG
    from slipdaq.config import load_config
    from slipdaq.sim.emit import SimSettings, generate
    from slipdaq.sim.logs import write_drive_logs

    cfg = load_config(CONFIG)
    write_drive_logs(generate(cfg, "cycle", "paved", SimSettings(), 3.0), tmp_path / "d.log", tmp_path / "d.nmea")
    mf4 = Path(__file__).resolve().parents[1] / "data" / "css-electronics" / "7512BE4D" / "00000427" / "00000001.MF4"

    def run(*argv: str) -> str:
        done = subprocess.run([sys.executable, "-c", COMMAND, *argv], capture_output=True, text=True, check=True)
        return done.stdout.splitlines()[-1]

    assert run("import", "--can", str(tmp_path / "d.log"), "--nmea", str(tmp_path / "d.nmea"), "--config",
               str(CONFIG), "-o", str(tmp_path / "a.mcap"), "--no-calibration") == "exit 0 False"
    assert run("import", "--can", str(mf4), "--nmea", str(tmp_path / "d.nmea"), "--config", str(CONFIG), "-o",
               str(tmp_path / "b.mcap"), "--allow-empty", "--no-calibration") == "exit 0 True"
    with open(tmp_path / "b.mcap", "rb") as f:  # the MF4's frames, read through python-can's MF4Reader
        assert make_reader(f).get_summary().statistics.channel_message_counts  # type: ignore[union-attr]


KERNELS_PROBE = """
import os, sys
os.environ["SLIPDAQ_JIT"] = "1"
os.environ["SLIPDAQ_AOT"] = "0"  # numba's JIT: the module compiled ahead of time imports no numba at all
import slipdaq.estimator.ring
from slipdaq import compiled
compiled.prepare()
print(all(k() is not k.py_func for k in compiled._kernels), "scipy.linalg" in sys.modules)
import scipy.linalg  # importable all the same
print(scipy.linalg.solve([[2.0]], [4.0])[0])
"""


@pytest.mark.skipif(importlib.util.find_spec("numba") is None or importlib.util.find_spec("scipy") is None,
                    reason="numba or scipy is not installed")
def test_kernels_load_without_scipy_linalg() -> None:
    """numba's kernels load (compiled) without numba's array maths importing scipy.linalg, which imports as usual
    afterwards."""
    got = subprocess.run([sys.executable, "-c", KERNELS_PROBE], capture_output=True, text=True,
                         check=True).stdout.split()
    assert got == ["True", "False", "2.0"]


GC_THRESHOLD = """
import gc, runpy, sys
sys.argv = ["slipdaq", *sys.argv[1:]]
try:
    runpy.run_module("slipdaq", run_name="__main__")
except SystemExit:
    print(*gc.get_threshold())
"""


@pytest.mark.parametrize("verb", ["replay", "report", "export", "import", "batch", "run", "demo"])
def test_offline_verbs_collect_the_young_generation_less_often(verb: str) -> None:
    """A verb that processes whole logs runs with OFFLINE_GC_THRESHOLD, a live one with Python's own (its pauses
    short); the process's own threshold as the command left it (`--help` ends it before any work)."""
    from slipdaq.__main__ import OFFLINE_GC_THRESHOLD, OFFLINE_VERBS

    out = subprocess.run([sys.executable, "-c", GC_THRESHOLD, verb, "--help"], capture_output=True, text=True,
                         check=True).stdout.split("\n")[-2]
    threshold = tuple(int(x) for x in out.split())
    assert threshold == (OFFLINE_GC_THRESHOLD if verb in OFFLINE_VERBS else (700, 10, 10))
    assert OFFLINE_GC_THRESHOLD[0] > 700
