"""A report's passes fed by processes that read and decode the log (offline.first_pass_feed.FedPasses): the same
rows as passes that read and decode it themselves, with the first pass's items kept for the second and with a log too
long to keep (the second pass fed by a process of its own, forked at the start and waiting until then): either way
the run's process calls no wheel decoder and reads no message of the log. A feed that fails ends the run with its
error, and a run that fails leaves no process behind, also one still waiting for its pass."""

from __future__ import annotations

import io
import pickle
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from slipdaq.config import load_config
from slipdaq.logformat.reader import raw_batches, raw_record_count
from slipdaq.offline import first_pass_feed, run
from slipdaq.offline.run import Rows, process_to_log, two_pass_rows
from slipdaq.offline.summaries import MIN_RAW_RECORDS
from slipdaq.sim.emit import SimSettings, generate
from support.forks import FORKS, children, failing_in_a_child, made_here
from support.paths import CONFIG
from support.sim_logs import FIXED_META


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """45 s of the braking drive, its frames jittered and its lines late, as a run records it: a log worth processes
    beside the run."""
    cfg = load_config(CONFIG)
    settings = SimSettings(seed=11, gps_latency_s=0.047, can_jitter_s=0.0003)
    records = [e.record for e in generate(cfg, "brake", "paved", settings, duration_s=45.0) if e.record is not None]
    path = tmp_path_factory.mktemp("fed") / "drive.mcap"
    process_to_log(cfg, iter(records), path, "import", metadata=FIXED_META, stream=io.StringIO(), total=len(records))
    assert (raw_record_count(path) or 0) >= MIN_RAW_RECORDS
    return path


def _rows(log: Path, monkeypatch: pytest.MonkeyPatch, *, maneuvers: bool) -> tuple[Rows, dict[str, int], int]:
    """two_pass_rows, with the calls of the wheel decoder and the log's reader made in this process, and the
    processes forked."""
    before = len(FORKS)
    with made_here(monkeypatch) as here:
        rows = two_pass_rows(log, stream=io.StringIO(), maneuvers=maneuvers)
    assert rows is not None and children() == []
    return rows, here, len(FORKS) - before


def _same(a: Rows, b: Rows) -> None:
    """The same rows, bit for bit (a NaN the same as a NaN)."""
    assert len(a.rows) == len(b.rows) > 200 and len(a.fast) == len(b.fast) > 1000
    for x, y in ((a.rows, b.rows), (a.sensors, b.sensors), (a.diagnostics, b.diagnostics), (list(a.fast), list(b.fast))):
        assert pickle.dumps(x) == pickle.dumps(y)


@pytest.mark.parametrize("kept", [True, False])
def test_fed_passes_give_the_rows_of_passes_that_decode(log: Path, monkeypatch: pytest.MonkeyPatch,
                                                        kept: bool) -> None:
    """Kept: the first pass fed, the second takes its items and calls again. Not kept (a log past FEED_BYTES): the
    second pass fed again, by a process of its own."""
    own, here, forks = _rows(log, monkeypatch, maneuvers=False)
    assert here["decode_batch"] > 0 and here["messages"] > 0 and forks == 0
    if not kept:
        monkeypatch.setattr(first_pass_feed, "FEED_BYTES", 0)
    fed, here, forks = _rows(log, monkeypatch, maneuvers=True)
    assert here == {"decode_batch": 0, "messages": 0}
    assert forks == (2 if kept else 3)  # the feeds' processes and the summaries'
    _same(fed, own)
    assert fed.maneuvers and any(m.phase == "brake" for m in fed.maneuvers)


def test_a_feed_that_fails_ends_the_run_with_its_error(log: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(run, "log_decoder", lambda _: failing_in_a_child(raw_batches, 300))
    with pytest.raises(ValueError, match="cannot be decoded") as raised:
        two_pass_rows(log, stream=io.StringIO(), maneuvers=True)
    assert "in the feed's process" in "".join(raised.value.__notes__)
    assert children() == []


def test_a_run_that_fails_leaves_no_feed_behind(log: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The first pass fails after a few runs, the feed waiting to send more: it ends with the run."""
    process = run.process

    def failing(config: Any, records: Any, *args: Any, **kwargs: Any) -> Any:
        def some() -> Any:
            for k, r in enumerate(records):
                if k == 2000:
                    raise RuntimeError("the first pass failed")
                yield r
        return process(config, some(), *args, **kwargs)

    monkeypatch.setattr(run, "process", failing)
    before = len(FORKS)
    with pytest.raises(RuntimeError, match="first pass failed"):
        two_pass_rows(log, stream=io.StringIO(), maneuvers=True)
    assert len(FORKS) - before == 2 and children() == []


def test_a_run_that_fails_leaves_no_waiting_feed_behind(log: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A log too long to keep: the second pass's feed, forked at the start, waits; the first pass fails."""
    monkeypatch.setattr(first_pass_feed, "FEED_BYTES", 0)
    process = run.process

    def failing(config: Any, records: Any, *args: Any, **kwargs: Any) -> Any:
        for k, _ in enumerate(records):
            if k == 2000:
                raise RuntimeError("the first pass failed")
        return process(config, records, *args, **kwargs)

    monkeypatch.setattr(run, "process", failing)
    before = len(FORKS)
    with pytest.raises(RuntimeError, match="first pass failed"):
        two_pass_rows(log, stream=io.StringIO(), maneuvers=True)
    assert len(FORKS) - before == 3 and children() == []


def test_a_second_feed_that_fails_ends_the_run_with_its_error(log: Path, monkeypatch: pytest.MonkeyPatch,
                                                             tmp_path: Path) -> None:
    """A log too long to keep, its second pass's feed failing (a decoding that fails in a process beside the run once
    the first pass is over): the run's error, no process left."""
    monkeypatch.setattr(first_pass_feed, "FEED_BYTES", 0)
    over = tmp_path / "first pass over"
    first_pass = run.first_pass

    def first_then_mark(*args: Any, **kwargs: Any) -> Any:
        got = first_pass(*args, **kwargs)
        over.touch()
        return got

    failing = failing_in_a_child(raw_batches, 300)

    def decode(messages: Any) -> Iterator[Any]:
        return (failing if over.exists() else raw_batches)(messages)

    monkeypatch.setattr(run, "first_pass", first_then_mark)
    monkeypatch.setattr(run, "log_decoder", lambda _: decode)
    with pytest.raises(ValueError, match="cannot be decoded") as raised:
        two_pass_rows(log, stream=io.StringIO(), maneuvers=True)
    assert "in the feed's process" in "".join(raised.value.__notes__)
    assert children() == []
