"""`slipdaq batch` when a worker process dies in the middle of a task (killed, out of memory, a crash in a library):
the task is given to another worker once; a log whose worker dies again is reported failed, with what happened,
while the other logs finish. The deaths are real: a worker preload (tests/batch_killer.py) ends the worker's process
when it starts the task of a log named `doomed` (every time) or `flaky` (the first time)."""

from __future__ import annotations

import shutil
from pathlib import Path

import dask
import pytest
from test_fleet_batch import _batch, _check_outputs, logs  # noqa: F401  (the fixture)

pytest.importorskip("distributed")
KILLER = Path(__file__).parents[1] / "support" / "batch_killer.py"


@pytest.mark.parametrize("killer", ["doomed", "flaky"])
def test_a_dead_worker_is_retried_once_then_the_log_fails(killer: str, logs: dict[str, Path],  # noqa: F811
                                                          tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """One log that kills its worker (each time, or the first time only) among three that do not. (A death also
    counts against a task that waited on the same worker; with one killer that happens at most once to a log, which
    the retry absorbs.)"""
    d = tmp_path / "logs"
    d.mkdir()
    chosen = {"paved-1": "paved-1", "sand-1": "sand-1", killer: "paved-2", "sand-2": "sand-2"}
    for name, source in chosen.items():
        shutil.copy(logs[source], d / f"{name}.mcap")
    tally = tmp_path / "tally"
    tally.mkdir()
    monkeypatch.setenv("SLIPDAQ_TEST_KILL_DIR", str(tally))
    out = tmp_path / "fleet"
    with dask.config.set({"distributed.worker.preload": [str(KILLER)]}):
        rc, err, stdout = _batch([*(str(d / f"{n}.mcap") for n in chosen), "-o", str(out), "--workers", "2"], capsys)
    assert (tally / killer).read_text().count("attempt") == 2  # tried, and retried once
    names = {p.name.rsplit("-", 1)[0] for p in (out / "estimates").iterdir()}
    if killer == "doomed":
        assert rc == 1, err
        assert "3 processed, 0 up to date, 1 failed" in stdout
        failed = [line for line in err if "FAILED" in line]
        assert len(failed) == 1 and "doomed.mcap" in failed[0] and "worker died" in failed[0], err
        assert names == {"paved-1", "sand-1", "sand-2"}
    else:  # died once, done on the retry
        assert rc == 0, err
        assert "4 processed, 0 up to date, 0 failed" in stdout
        assert names == {"paved-1", "sand-1", "sand-2", "flaky"}
