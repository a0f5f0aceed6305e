"""A two-pass run reads and decodes its log once (offline.read_once.ReadOnce): the second pass gets the first pass's
items, kept while the messages they came from stay within KEEP_BYTES, or the log read and decoded again; `replay
--two-pass` writes the same log either way, its decoders played back from the first pass's tape (offline.decoder_tape)
or not."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.logformat.reader import iter_raw_messages
from slipdaq.offline import decoder_tape, read_once
from slipdaq.offline.run import items_of, log_decoder
from slipdaq.records import CanFrameBatch
from support.forks import FORKS
from support.sim_logs import chunked_log


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """50 s of the cycle drive in small chunks: more raw records than a log's process needs (MIN_RAW_RECORDS)."""
    return chunked_log(tmp_path_factory.mktemp("read-once"), 50.0, 65536, seed=3)


def _plain(item: Any) -> Any:
    """An item in a form == compares: a batch of frames as its arrays' bytes."""
    if isinstance(item, CanFrameBatch):
        return (item.timestamp_s.tobytes(), item.arbitration_id.tobytes(), item.flags.tobytes(), item.dlc.tobytes(),
                item.data.tobytes(), item.channel.tobytes(), item.channels)
    return item


def test_the_second_pass_gets_the_items_kept_or_the_log_read_again(log: Path) -> None:
    decode = items_of(log_decoder(log))
    expected = [_plain(item) for item in decode(iter_raw_messages(log))]
    size = sum(len(m[-1]) for m in iter_raw_messages(log))
    for keep, reads_wanted in ((size, [True]), (size - 1, [True, False]), (0, [True, False])):
        log_reads: list[bool] = []

        def read(scan: bool, log_reads: list[bool] = log_reads) -> Any:
            log_reads.append(scan)
            return iter_raw_messages(log)

        kept = read_once.ReadOnce(read, decode, keep)
        first = list(kept.first())
        assert [_plain(item) for item in first] == expected
        second = list(kept.second())
        assert [_plain(item) for item in second] == expected
        assert log_reads == reads_wanted, keep
        assert kept.tape.complete == (keep == size)  # no tape played to a log read again
        same = [a is b for a, b in zip(first, second, strict=True) if isinstance(a, CanFrameBatch)]
        assert all(same) if keep == size else not any(same)  # the first pass's own, or decoded again


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(channel.topic, m.log_time, m.data) for _, channel, m in make_reader(f).iter_messages()]


def test_a_two_pass_replay_is_the_same_kept_decoded_again_or_read_again(log: Path, tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole input kept with its decoders' tape (the default); the tape past its budget (the second pass
    decodes); a log a byte too long to keep, read and decoded again: the same messages (the log written apart, as a
    replay of this many records does)."""
    size = sum(len(m[-1]) for m in iter_raw_messages(log))
    outs = []
    budgets = ((read_once.KEEP_BYTES, decoder_tape.TAPE_BYTES), (read_once.KEEP_BYTES, 1),
               (size - 1, decoder_tape.TAPE_BYTES))
    for k, (keep, tape) in enumerate(budgets):
        monkeypatch.setattr(read_once, "KEEP_BYTES", keep)
        monkeypatch.setattr(decoder_tape, "TAPE_BYTES", tape)
        outs.append(tmp_path / f"out-{k}.mcap")
        before = len(FORKS)
        assert main(["replay", str(log), "-o", str(outs[-1]), "--two-pass", "--no-calibration"]) == 0
        assert len(FORKS) - before == 2  # the log's process and the summaries'
    first = _messages(outs[0])
    assert len(first) > 1000
    for out in outs[1:]:
        assert _messages(out) == first, out
