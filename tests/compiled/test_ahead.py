"""The kernels compiled ahead of time (slipdaq/compiled/ahead.py): built once, loaded without numba, the same bytes
out of a replay as numba's JIT; a build that fails falls back to the JIT. The kernels' own bits against their Python
are the kernel tests' (tests/estimator, tests/decode): they run the compiled kernel, which is this module's."""

from __future__ import annotations

import hashlib
import importlib
import inspect
import os
import pkgutil
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

import slipdaq
from conftest import CONFIG
from slipdaq import compiled
from slipdaq.compiled import ahead, registry
from slipdaq.decode.can_wheels import LAYOUT_CACHE_NAME

needs_compiler = pytest.mark.skipif(
    importlib.util.find_spec("numba") is None or shutil.which(sysconfig.get_config_var("CC").split()[0]) is None,
    reason="numba or a C compiler is missing: the kernels are numba's JIT or Python here")

PROBE = """
import runpy, sys
sys.argv = ["slipdaq", *sys.argv[1:]]
try:
    runpy.run_module("slipdaq", run_name="__main__")
except SystemExit as e:
    from slipdaq import compiled
    kinds = sorted({type(k()).__module__ for k in compiled.kernels()})
    print("exit", e.code, "numba" in sys.modules, len(compiled.kernels()), *kinds)
"""


def _slipdaq(*argv: str, **env: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True,
                          env={**os.environ, **env}, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout.splitlines()[-1].split()


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


def test_kernel_modules_name_every_kernel() -> None:
    """KERNEL_MODULES, which the build and its key import, are the modules of every kernel in slipdaq."""
    for info in pkgutil.walk_packages(slipdaq.__path__, "slipdaq."):
        try:
            importlib.import_module(info.name)
        except ImportError:  # an extra that is not installed
            continue
    assert sorted({k.py_func.__module__ for k in compiled.kernels()}) == sorted(registry.KERNEL_MODULES)
    assert len({k.export_name for k in compiled.kernels()}) == len(compiled.kernels())


def test_key_follows_the_kernels_code(monkeypatch: pytest.MonkeyPatch) -> None:
    """A constant a kernel reads, or the code of a function it calls, changes the key; code no kernel runs does not."""
    from slipdaq.estimator import numpy_rules, ring

    base = ahead.key()
    assert ahead.key() == base
    monkeypatch.setattr(ring, "MIN_LINE_SPAN_S", ring.MIN_LINE_SPAN_S * 2)
    assert ahead.key() != base
    monkeypatch.undo()
    assert ahead.key() == base
    monkeypatch.setattr(numpy_rules.pairwise_sum, "__code__", numpy_rules.block_sum.__code__)
    assert ahead.key() != base
    monkeypatch.undo()
    monkeypatch.setattr(ring.SeriesRing, "extend", lambda self, *a: None)
    assert ahead.key() == base


TABLE = np.arange(4.0)
SCALE = np.float64(2.0)


def _reads_globals(i: int) -> float:
    return float(TABLE[i] * SCALE)


def _digest() -> str:
    h = hashlib.sha256()
    ahead._function_digest(_reads_globals, h, set())
    return h.hexdigest()


def test_digest_takes_global_arrays_and_numpy_scalars_by_value(monkeypatch: pytest.MonkeyPatch) -> None:
    """numba compiles a global array or scalar in as a constant: its value is in the key."""
    base = _digest()
    monkeypatch.setattr(sys.modules[__name__], "TABLE", np.arange(4.0) + 1.0)
    assert _digest() != base
    monkeypatch.undo()
    monkeypatch.setattr(sys.modules[__name__], "SCALE", np.float64(3.0))
    assert _digest() != base
    monkeypatch.undo()
    assert _digest() == base


@needs_compiler
def test_replay_the_same_bytes_ahead_of_time_and_jit(tmp_path: Path) -> None:
    """`replay --two-pass` (every kernel runs) with the module compiled ahead of time, built here in a cache of its
    own, and with numba's JIT (SLIPDAQ_AOT=0): the same messages. The first process does not import numba at all."""
    from slipdaq.config import load_config
    from slipdaq.sim.emit import SimSettings, generate
    from slipdaq.sim.logs import write_drive_logs

    cfg = load_config(CONFIG)
    write_drive_logs(generate(cfg, "cycle", "paved", SimSettings(), 12.0), tmp_path / "d.log", tmp_path / "d.nmea")
    cache = tmp_path / "cache"
    assert _slipdaq("import", "--can", str(tmp_path / "d.log"), "--nmea", str(tmp_path / "d.nmea"), "--config",
                    str(CONFIG), "-o", str(tmp_path / "raw.mcap"), "--no-calibration",
                    SLIPDAQ_AOT="0")[:3] == ["exit", "0", "True"]
    runs = {}
    for aot in ("1", "0"):
        out = tmp_path / f"aot-{aot}.mcap"
        runs[aot] = _slipdaq("replay", str(tmp_path / "raw.mcap"), "-o", str(out), "--two-pass",
                             SLIPDAQ_AOT=aot, SLIPDAQ_CACHE_DIR=str(cache))
    built = sorted(p.name for p in cache.iterdir() if p.suffix != ".lock")
    layouts = [n for n in built if n.startswith(LAYOUT_CACHE_NAME)]  # the wheel decoder's, kept beside
    assert len(layouts) == 1
    assert [n for n in built if n not in layouts] == [ahead.module_name(ahead.key()) + sysconfig.get_config_var(
        "EXT_SUFFIX")]
    assert runs["1"][:4] == ["exit", "0", "False", str(len(registry.all_kernels()))]  # every kernel ran in two passes
    assert runs["1"][4:] == ["builtins"]  # the ahead module's functions
    assert runs["0"][:3] == ["exit", "0", "True"] and runs["0"][4:] == ["numba.core.registry"]
    a, b = _messages(tmp_path / "aot-1.mcap"), _messages(tmp_path / "aot-0.mcap")
    assert len(a) > 1000 and a == b


@needs_compiler
def test_a_failed_build_falls_back_to_the_jit(tmp_path: Path) -> None:
    """A build that fails (here: no working C compiler) leaves NAME.failed with its output; the kernels are numba's
    JIT, and the next process does not try again. On a terminal (stderr a pseudo-terminal here) the build says that
    it compiles, then that it failed; the next process says nothing."""
    import pty

    probe = ("from slipdaq import compiled; import slipdaq.estimator.ring; compiled.prepare(); import sys; "
             "print(sorted({type(k()).__module__ for k in compiled.kernels()}), 'numba' in sys.modules)")
    env = {**os.environ, "SLIPDAQ_CACHE_DIR": str(tmp_path), "CC": "false"}
    said = []
    for _ in range(2):
        terminal, stderr = pty.openpty()
        try:
            try:
                done = subprocess.run([sys.executable, "-c", probe], stdout=subprocess.PIPE, stderr=stderr,
                                      text=True, env=env, timeout=600)
            finally:
                os.close(stderr)  # the terminal's other side: reading it then ends after what was written
            said.append(_read_all(terminal))
        finally:
            os.close(terminal)
        assert done.returncode == 0, said[-1]
        assert done.stdout.split() == ["['numba.core.registry']", "True"]
    failed = [p for p in tmp_path.iterdir() if p.suffix == ".failed"]
    assert [p.name for p in failed] == [ahead.module_name(ahead.key()) + ".failed"]
    assert "exit status" in failed[0].read_text()
    assert not [p for p in tmp_path.iterdir() if p.is_dir()]  # the build's temporary directory is gone
    lines = said[0].splitlines()
    assert len(lines) == 2 and "slipdaq: compiling the kernels ahead of time" in lines[0], said[0]
    assert "could not be compiled ahead of time" in lines[1] and str(failed[0]) in lines[1]
    assert said[1] == ""


def _read_all(fd: int) -> str:
    """What a pseudo-terminal's other side wrote (its writer closed: reading ends with EIO or an empty read)."""
    out = b""
    while True:
        try:
            got = os.read(fd, 4096)
        except OSError:  # EIO: the other side is closed
            break
        if not got:
            break
        out += got
    return out.decode().replace("\r\n", "\n")


def test_kernels_python_when_jit_is_off() -> None:
    """SLIPDAQ_JIT=0 runs the Python functions, ahead of time module or not."""
    import slipdaq.estimator.ring  # noqa: F401
    from support.paths import kernels

    with kernels(False):
        assert all(k() is k.py_func for k in compiled.kernels())
    with kernels(True):
        assert all(not inspect.isfunction(k()) for k in compiled.kernels())
