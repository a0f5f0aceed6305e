"""The command's start: python-can imported without asammdf for the verbs that read no file through python-can."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import pytest

from slipdaq.__main__ import PYTHON_CAN_MF4_VERBS, verb_of

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
