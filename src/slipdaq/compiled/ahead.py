"""Every kernel compiled ahead of time into one CPython extension module (numba.pycc), built once per version of
their code, of Python, numpy and numba, in slipdaq's cache directory, and imported when the first kernel is needed:
a process then neither imports numba nor loads its JIT cache (0.35 s of each start on the 2-core machine:
docs/performance.md, "Start-up").

The module's name carries a key: a hash of the kernels' code (each kernel of registry.KERNEL_MODULES, with what it
calls and reads), of this file and of the versions above. A process that finds no module for its key builds it in a
process of its own (`build`), under a lock that other processes wait on (about 8 s of one core, once); the file is
written under a temporary name and renamed into place. A build that fails leaves `NAME.failed` with the compiler's
last lines, and the kernels are numba's JIT, as they are with SLIPDAQ_AOT=0 or without a writable cache directory.
The code is generic for the architecture (pycc's default CPU), so that one cache serves several machines; its bits
are the JIT's and the Python's (tests/compiled/test_ahead.py).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.machinery
import importlib.metadata
import importlib.util
import logging
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from types import CodeType, FunctionType, ModuleType
from typing import Any

import numpy as np

from slipdaq.compiled.registry import all_kernels

log = logging.getLogger(__name__)

FORMAT = "1"
"""Changes what the key means (the build's recipe is in the key too: this file's bytes)."""

CACHE_ENV = "SLIPDAQ_CACHE_DIR"
AOT_ENV = "SLIPDAQ_AOT"
BUILD_TIMEOUT_S = 600.0
BUILDER = "import sys; from pathlib import Path; from slipdaq.compiled.ahead import build; build(Path(sys.argv[1]), sys.argv[2])"
"""The build's process: OUT_DIR NAME."""
STALE_AFTER_S = 30 * 86400.0

_PACKAGE_DIR = Path(__file__).resolve().parents[1]
"""src/slipdaq: its parent goes on the builder's PYTHONPATH, so that it compiles this slipdaq."""
_UNSET = object()
_module: object = _UNSET


def enabled() -> bool:
    """SLIPDAQ_AOT=0 in the environment: numba's JIT only (neither built nor loaded)."""
    return os.environ.get(AOT_ENV, "1") != "0"


def cache_dir() -> Path:
    """$SLIPDAQ_CACHE_DIR, else $XDG_CACHE_HOME/slipdaq, else ~/.cache/slipdaq."""
    explicit = os.environ.get(CACHE_ENV)
    if explicit:
        return Path(explicit)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "slipdaq"


def key() -> str:
    """The build's key: 16 hex digits of a SHA-256 over what the module is compiled from (each kernel's name,
    signature and code, with the functions and constants it reads: _code_digest) and what it depends on (this
    file's recipe, the versions of Python, numpy and numba)."""
    h = hashlib.sha256()
    versions = (FORMAT, sys.version, sys.platform, platform.machine(), sysconfig.get_config_var("EXT_SUFFIX") or "",
                importlib.metadata.version("numpy"), importlib.metadata.version("numba"))
    h.update("\0".join(versions).encode())
    h.update(Path(__file__).read_bytes())
    seen: set[int] = set()
    for k in sorted(all_kernels(), key=lambda k: k.export_name):
        h.update(f"\0{k.export_name}\0{k.signature}\0".encode())
        _function_digest(k.py_func, h, seen)
        for fn in k.uses:
            _function_digest(fn, h, seen)
    return h.hexdigest()[:16]


def _function_digest(fn: Any, h: Any, seen: set[int]) -> None:
    """fn's code into h: its bytecode, constants and names (not its line numbers), its defaults, and each global it
    reads: a constant (a number, a string, a tuple, an array) by value, a module by name, a Python function by its
    own digest (once), anything else by its type."""
    if id(fn) in seen:
        h.update(f"<{fn.__module__}.{fn.__qualname__}>".encode())
        return
    seen.add(id(fn))
    h.update(f"{fn.__module__}.{fn.__qualname__}{fn.__defaults__!r}".encode())
    _code_digest(fn.__code__, h)
    for name in _global_names(fn.__code__):
        if name not in fn.__globals__:
            continue
        value = fn.__globals__[name]
        if isinstance(value, ModuleType):
            h.update(f"{name}=module {value.__name__}".encode())
        elif isinstance(value, FunctionType):
            h.update(f"{name}=".encode())
            _function_digest(value, h, seen)
        elif isinstance(value, int | float | bool | str | bytes | tuple | type(None) | np.generic):
            h.update(f"{name}={value!r}".encode())
        elif isinstance(value, np.ndarray):  # numba compiles a global array in as a constant
            h.update(f"{name}={value.dtype.str}{value.shape}".encode() + value.tobytes())
        else:
            h.update(f"{name}={type(value).__module__}.{type(value).__qualname__}".encode())


def _code_digest(code: CodeType, h: Any) -> None:
    h.update(code.co_code)
    h.update(" ".join(code.co_names + code.co_varnames).encode())
    for c in code.co_consts:
        if isinstance(c, CodeType):
            _code_digest(c, h)
        else:
            h.update(repr(sorted(map(repr, c)) if isinstance(c, frozenset) else c).encode())


def _global_names(code: CodeType) -> list[str]:
    names = list(code.co_names)
    for c in code.co_consts:
        if isinstance(c, CodeType):
            names += _global_names(c)
    return names


def module_name(build_key: str) -> str:
    return f"slipdaq_kernels_{build_key}"


def module() -> ModuleType | None:
    """The extension module of this version's kernels: loaded (built first where it is missing), once per process;
    None where it cannot be (the kernels are then numba's JIT)."""
    global _module
    if _module is _UNSET:
        _module = _find_or_build()
    return _module  # type: ignore[return-value]


def forget() -> None:
    """Look for the module again at the next module() (the tests, after changing the environment)."""
    global _module
    _module = _UNSET


def _find_or_build() -> ModuleType | None:
    if importlib.util.find_spec("numba") is None:
        return None
    try:
        name = module_name(key())
        directory = cache_dir()
        path = directory / (name + (sysconfig.get_config_var("EXT_SUFFIX") or ".so"))
        failed = directory / (name + ".failed")
        if not path.exists():
            if failed.exists():
                return None
            directory.mkdir(parents=True, exist_ok=True)
            with _locked(directory / (name + ".lock")):
                if not path.exists() and not failed.exists():
                    _build(name, path, failed)
            if not path.exists():
                return None
        return _load(name, path)
    except (OSError, ImportError, RuntimeError, subprocess.SubprocessError) as e:  # RuntimeError: no home directory
        log.debug("kernels ahead of time: not available (%s): numba's JIT", e)
        return None


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock on path while building (fcntl; without it, concurrent builds each write their own file and
    the last rename wins, the same bytes)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _build(name: str, path: Path, failed: Path) -> None:
    """Build the module in a process of its own, into a temporary directory beside path, then rename it into place;
    a failure leaves `failed` with the last lines of its output."""
    _say("compiling the kernels ahead of time, once for this version (about 10 s)", logging.INFO)
    tmp = Path(tempfile.mkdtemp(prefix=name + ".", dir=path.parent))
    try:
        env = dict(os.environ, **{AOT_ENV: "0"})  # the builder loads no kernel: never waits on this lock
        env["PYTHONPATH"] = os.pathsep.join([str(_PACKAGE_DIR.parent), *filter(None, [env.get("PYTHONPATH")])])
        done = subprocess.run([sys.executable, "-c", BUILDER, str(tmp), name], env=env, cwd=tmp,
                              capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
        built = tmp / path.name
        if done.returncode == 0 and built.exists():
            os.replace(built, path)
            _drop_stale(path)
            return
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-20:])
        failed.write_text(f"exit status {done.returncode}\n{tail}\n")
        _say(f"the kernels could not be compiled ahead of time ({failed}): numba's JIT is used instead",
             logging.WARNING)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _say(text: str, level: int) -> None:
    """A line for a person at a terminal (stderr is one: the command pauses for the build, and says why), else the
    log's."""
    if sys.stderr is not None and sys.stderr.isatty():
        print(f"slipdaq: {text}", file=sys.stderr, flush=True)
    else:
        log.log(level, "%s", text)


def _drop_stale(kept: Path) -> None:
    """Other versions' modules, markers and builds left by a killed process, not written for STALE_AFTER_S, go (a
    process that finds its version's file gone builds it again)."""
    now, own = time.time(), kept.name.split(".")[0]
    for p in kept.parent.glob("slipdaq_kernels_*"):
        with contextlib.suppress(OSError):
            if not p.name.startswith(own) and now - p.stat().st_mtime > STALE_AFTER_S:
                shutil.rmtree(p) if p.is_dir() else p.unlink()


def _load(name: str, path: Path) -> ModuleType:
    mod = sys.modules.get(name)
    if mod is None:
        loader = importlib.machinery.ExtensionFileLoader(name, str(path))
        spec = importlib.util.spec_from_file_location(name, path, loader=loader)
        assert spec is not None
        mod = importlib.util.module_from_spec(spec)
        loader.exec_module(mod)
        sys.modules[name] = mod
    return mod


def build(out_dir: Path, name: str) -> Path:
    """Compile every kernel (registry.KERNEL_MODULES) into the extension module `name` in out_dir (numba.pycc);
    its path."""
    import warnings

    kernels = all_kernels()
    if module_name(key()) != name:
        raise RuntimeError(f"the kernels' sources changed during the build of {name}")
    from numba.core.errors import NumbaPendingDeprecationWarning
    from numba.extending import register_jitable

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
        from numba.pycc import CC

        cc = CC(name)
        cc.output_dir = str(out_dir)
        for k in kernels:
            for fn in k.uses:
                register_jitable(fn)
            cc.export(k.export_name, k.signature)(k.py_func)
        cc.compile()
    return out_dir / cc.output_file

