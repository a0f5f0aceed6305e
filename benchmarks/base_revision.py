"""The base revision a benchmark compares this tree against: given on the command line, by default the merge base
of HEAD with main (what a branch changes); its `src` and `config` unpacked from git for PYTHONPATH; the sides run in
turns (in_turns), each as a program under its own slipdaq (under, side_json)."""

from __future__ import annotations

import argparse
import compileall
import io
import json
import os
import subprocess
import sys
import tarfile
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def merge_base(branch: str = "main") -> str:
    """The merge base of HEAD with `branch`, abbreviated; HEAD itself when there is none."""
    got = subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", branch], capture_output=True, text=True)
    rev = got.stdout.strip() if got.returncode == 0 else "HEAD"
    return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], capture_output=True, text=True,
                          check=True).stdout.strip()


def add_base_argument(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--base", default=None, metavar="REV",
                    help="the revision to compare against (default: the merge base of HEAD with main)")


def resolve(rev: str | None) -> str:
    return rev if rev else merge_base()


def unpack(rev: str, dest: Path) -> Path:
    """`git archive REV src config` into dest (once); returns dest/src, to put on PYTHONPATH. Both trees' modules are
    byte-compiled (byte_compile), so that neither side of a comparison compiles its sources at each start."""
    if not (dest / "src").is_dir():
        dest.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src", "config"], check=True,
                                 capture_output=True).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(dest, filter="data")
    byte_compile(dest / "src", ROOT / "src")
    return dest / "src"


def byte_compile(*srcs: Path) -> None:
    """Each tree's .pyc files written where they are missing or out of date. With PYTHONDONTWRITEBYTECODE set, an
    unpacked base would otherwise compile every module from source at each start (about 0.15 s a process), which a
    tree whose .pyc files an earlier run wrote does not pay."""
    for src in srcs:
        compileall.compile_dir(str(src), quiet=1)


def side_env(src: Path) -> dict[str, str]:
    """The environment of a process that runs with the slipdaq of src (a tree's src/ or an unpacked revision's): src,
    then this repository (its benchmarks), on the path."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(src), str(ROOT)]))


def under(src: Path, benchmark_file: str, *args: str) -> tuple[list[str], dict[str, str]]:
    """The command and environment that run a benchmark module (by its file's name) as a program with the slipdaq of
    src: `python -m benchmarks.NAME ARGS` in side_env(src)."""
    return [sys.executable, "-m", f"benchmarks.{Path(benchmark_file).stem}", *args], side_env(src)


def in_turns(sides: Collection[str], rounds: int) -> Iterator[tuple[int, str]]:
    """(round, side) for every side in every round, the sides' order reversed every other round: drift in the
    machine's speed then weighs on each side alike."""
    for r in range(rounds):
        for side in list(sides) if r % 2 == 0 else list(sides)[::-1]:
            yield r, side


def side_json(src: Path, benchmark_file: str, *args: str, cwd: Path | None = None) -> Any:
    """A benchmark module run as a program under src's slipdaq (`under`), its last line of output read as JSON."""
    cmd, env = under(src, benchmark_file, *args)
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True, cwd=cwd).stdout
    return json.loads(out.strip().splitlines()[-1])
