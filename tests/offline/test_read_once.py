"""A two-pass run reads its log once (offline.run.ReadOnce): the second pass gets the messages the first pass read,
kept while their data stays within KEEP_BYTES, or reads a longer log again; `replay --two-pass` writes the same log
either way."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.logformat.reader import iter_raw_messages
from slipdaq.offline import run
from support.forks import FORKS
from support.sim_logs import chunked_log


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """50 s of the cycle drive in small chunks: more raw records than a log's process needs (MIN_RAW_RECORDS)."""
    return chunked_log(tmp_path_factory.mktemp("read-once"), 50.0, 65536, seed=3)


def test_the_second_pass_gets_the_messages_kept_or_read_again(log: Path) -> None:
    every = list(iter_raw_messages(log))
    size = sum(len(m[-1]) for m in every)
    for keep, reads_wanted in ((size, [True]), (size - 1, [True, False]), (0, [True, False])):
        reads: list[bool] = []

        def read(scan: bool, reads: list[bool] = reads) -> Any:
            reads.append(scan)
            return iter_raw_messages(log)

        messages = run.ReadOnce(read, keep)
        assert list(messages.first()) == every
        assert list(messages.second()) == every
        assert reads == reads_wanted, keep


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(channel.topic, m.log_time, m.data) for _, channel, m in make_reader(f).iter_messages()]


def test_a_two_pass_replay_is_the_same_kept_or_read_again(log: Path, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole log kept (the default), and a log a byte too long to keep: the same messages (the log written
    apart, as a replay of this many records does)."""
    size = sum(len(m[-1]) for m in iter_raw_messages(log))
    outs = []
    for k, keep in enumerate((run.KEEP_BYTES, size - 1)):
        monkeypatch.setattr(run, "KEEP_BYTES", keep)
        outs.append(tmp_path / f"out-{k}.mcap")
        before = len(FORKS)
        assert main(["replay", str(log), "-o", str(outs[-1]), "--two-pass", "--no-calibration"]) == 0
        assert len(FORKS) - before == 2  # the log's process and the summaries'
    first = _messages(outs[0])
    assert len(first) > 1000
    assert _messages(outs[1]) == first
