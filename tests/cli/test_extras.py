"""The optional extras: a flag whose extra is missing stops with one line naming it, before anything is read or
written. The missing package is simulated as Python does for an absent one (sys.modules[NAME] = None: its import
raises ImportError), in a fresh interpreter running the command line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from support.paths import DATA, ROOT

LOG = DATA / "slipdaq-6641212" / "drive-fast-rows.mcap"


def run_without(module: str, argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    code = (f"import sys; sys.modules[{module!r}] = None\n"
            "from slipdaq.cli import main\n"
            f"sys.exit(main({argv!r}))\n")
    env = os.environ | {"PYTHONPATH": str(ROOT / "src")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


@pytest.mark.parametrize("verb", ["report", "batch"])
def test_png_without_matplotlib_names_the_extra(verb: str, tmp_path: Path) -> None:
    out = tmp_path / "out"
    run = run_without("matplotlib", [verb, str(LOG), "-o", str(out), "--png"], tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.strip().splitlines() == ["slipdaq: --png needs matplotlib: pip install 'slipdaq[png]'"]
    assert not out.exists()


@pytest.mark.slow
def test_report_without_png_needs_no_matplotlib(tmp_path: Path) -> None:
    """The default report draws in the browser: it runs to the end with matplotlib missing."""
    out = tmp_path / "out"
    run = run_without("matplotlib", ["report", str(LOG), "-o", str(out), "--live"], tmp_path)
    assert run.returncode == 0, run.stderr
    assert (out / "index.html").is_file()
