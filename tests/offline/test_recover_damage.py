"""Damaged logs: `slipdaq recover` keeps every message of every chunk that checks out, past a damaged chunk
(skipped: its extent is in its header) or damaged bytes (reading resynchronises on the next record that parses), says
what each damaged byte range held (log time, messages by topic from the message index) and exits 3 when it wrote
its output with losses, 0 when nothing was lost, 1 when nothing could be recovered; `export`, `replay`, `report`,
`batch` and the library readers fail (exit 1) with one line naming the damaged bytes and `recover`, and the tear
too on a torn log.

The logs are real slipdaq logs (the simulator's records through the pipeline, 128 KiB chunks), damaged here at
offsets the mcap library's summary gives (its chunk indexes), and every output is read back with the mcap library.
"""

from __future__ import annotations

import os
import re
import struct
from collections import Counter
from pathlib import Path

import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from slipdaq.cli import main
from slipdaq.logformat.damage import fmt_time
from slipdaq.logformat.durable import TRAILER
from slipdaq.logformat.errors import LogError
from slipdaq.logformat.reader import iter_estimates, iter_raw_records
from slipdaq.logformat.salvage import DamageError, ScanResult, survey
from support.sim_logs import chunked_log

Msg = tuple[str, int, bytes]


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished 30 s log of about 20 chunks."""
    log = chunked_log(tmp_path_factory.mktemp("damage"), 30.0, 131072, seed=5)
    assert len(chunks(log)) >= 10
    return log


def chunks(path: Path) -> list:  # type: ignore[type-arg]
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def messages(path: Path) -> list[Msg]:
    """Every message, in file order, as the mcap library reads it (it checks every chunk's CRC)."""
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data)
                for _, c, m in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False)]


def chunk_messages(path: Path, index) -> list[Msg]:  # type: ignore[no-untyped-def]
    """The messages of one chunk of the undamaged log (through its chunk index)."""
    with open(path, "rb") as f:
        topics = {c.id: c.topic for c in make_reader(f).get_summary().channels.values()}  # type: ignore[union-attr]
        f.seek(index.chunk_start_offset + 9)
        chunk = Chunk.read(ReadDataStream(f))
    return [(topics[r.channel_id], r.log_time, r.data) for r in breakup_chunk(chunk, validate_crc=True)
            if isinstance(r, Message)]


def without(msgs: list[Msg], gone: list[Msg]) -> list[Msg]:
    left = Counter(gone)
    out = []
    for m in msgs:
        if left[m]:
            left[m] -= 1
        else:
            out.append(m)
    assert not +left, "the chunk's messages are all in the log"
    return out


def damaged(src: Path, dst: Path, *, flip: tuple[int, ...] = (), cut: int | None = None) -> Path:
    data = bytearray(src.read_bytes())
    for off in flip:
        data[off] ^= 0xFF
    dst.write_bytes(bytes(data[:cut]))
    return dst


def middle(index) -> tuple[int, ...]:  # type: ignore[no-untyped-def]
    """Four bytes in the middle of a chunk (its compressed data)."""
    mid = index.chunk_start_offset + index.chunk_length // 2
    return tuple(range(mid, mid + 4))


def unfinished(src: Path, dst: Path) -> Path:
    """The log as a killed daemon leaves it: its data, then the provisional trailer (no summary)."""
    data = src.read_bytes()
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)  # the footer's first field
    data_end = summary_start - 13  # the data end record before the summary
    assert data[data_end] == 0x0F
    dst.write_bytes(data[:data_end] + TRAILER)
    return dst


def cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    got = capsys.readouterr()
    assert "Traceback" not in got.err
    return rc, got.out, got.err


def assert_in_log_time_order(path: Path) -> None:
    times = [t for _, t, _ in messages(path)]
    assert times == sorted(times)


# ---- recover ----

@pytest.mark.parametrize("which", ["first", "middle", "last"])
def test_recover_keeps_every_message_outside_a_damaged_chunk(log: Path, tmp_path: Path, which: str,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Bytes flipped inside one chunk (the first holds the channel definitions: they come from the summary): every
    other chunk's messages are written, in order; the report names the chunk's bytes, its log time and its messages
    by topic (the message index's count equals the chunk's); exit status 3."""
    cs = chunks(log)
    c = cs[{"first": 0, "middle": len(cs) // 2, "last": -1}[which]]
    bad = damaged(log, tmp_path / "bad.mcap", flip=middle(c))
    rc, out, _ = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 3, out
    lost = chunk_messages(log, c)
    assert messages(tmp_path / "fixed.mcap") == without(messages(log), lost)
    assert_in_log_time_order(tmp_path / "fixed.mcap")
    line = next(x for x in out.splitlines() if "damaged:" in x)
    assert f"bytes {c.chunk_start_offset}-{c.chunk_start_offset + c.chunk_length} " in line
    assert f"log time {fmt_time(c.message_start_time)} to {fmt_time(c.message_end_time)} UTC" in line
    by_topic = Counter(t for t, _, _ in lost)
    assert f"{len(lost)} messages lost (" + ", ".join(f"{t} {n}" for t, n in sorted(by_topic.items())) in line
    assert f"lost by the file's statistics: {len(lost)} of {len(messages(log))} messages" in out
    assert "exit status 3" in out


def test_recover_of_a_clean_log_exits_0_and_changes_nothing(log: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = cli(["recover", log, "-o", tmp_path / "same.mcap"], capsys)
    assert rc == 0 and "damaged" not in out and "losses" not in out
    assert messages(tmp_path / "same.mcap") == messages(log)


def test_damaged_chunks_of_an_unfinished_log_are_counted_by_their_message_index(
        log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No summary (a killed daemon's file): two damaged chunks, each named, counted from the message index records
    after it and timed by it; the rest written; exit 3."""
    cs = chunks(log)
    plain = unfinished(log, tmp_path / "plain.mcap")
    bad = damaged(plain, tmp_path / "bad.mcap", flip=middle(cs[3]) + middle(cs[7]))
    rc, out, _ = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 3 and "not finished" in out
    lost = chunk_messages(log, cs[3]) + chunk_messages(log, cs[7])
    assert messages(tmp_path / "fixed.mcap") == without(messages(log), lost)
    for c in (cs[3], cs[7]):
        n = len(chunk_messages(log, c))
        assert re.search(rf"bytes {c.chunk_start_offset}-{c.chunk_start_offset + c.chunk_length} .*"
                         rf"{n} messages lost \(.*from the message index\)", out), out


def test_a_damaged_chunk_header_resynchronises_on_the_next_record(log: Path, tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """The chunk's opcode and length both damaged (its extent unknown) and its content too: reading goes on at the
    next record that parses (its message index), every other chunk kept."""
    c = chunks(log)[5]
    head = tuple(range(c.chunk_start_offset, c.chunk_start_offset + 9))
    bad = damaged(log, tmp_path / "bad.mcap", flip=head + middle(c))
    rc, out, _ = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 3
    assert messages(tmp_path / "fixed.mcap") == without(messages(log), chunk_messages(log, c))
    assert f"bytes {c.chunk_start_offset}-{c.chunk_start_offset + c.chunk_length} (no valid record" in out


@pytest.mark.parametrize("finished", [True, False])
def test_a_damaged_header_of_a_sound_chunk_loses_nothing(log: Path, tmp_path: Path, finished: bool,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Only the chunk's opcode byte flipped: its content checks out against its CRC (its extent from the summary, or
    from its own length without one), so every message is kept and read; exit 0."""
    src = log if finished else unfinished(log, tmp_path / "plain.mcap")
    c = chunks(log)[4]
    bad = damaged(src, tmp_path / "bad.mcap", flip=(c.chunk_start_offset,))
    rc, out, _ = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 0, out
    assert messages(tmp_path / "fixed.mcap") == messages(log)
    assert "read all the same" in out
    assert len(list(iter_estimates(bad))) == len(list(iter_estimates(log)))


@pytest.mark.parametrize("where", ["message index", "summary"])
def test_damaged_indexes_lose_nothing(log: Path, tmp_path: Path, where: str,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Bytes flipped in a message index record, or in the summary (its CRC fails): every message is read and
    recovered (the indexes are written anew), exit 0; the readers read it whole."""
    c = chunks(log)[2]
    size = log.stat().st_size
    at = min(c.message_index_offsets.values()) + 10 if where == "message index" else size - 200
    bad = damaged(log, tmp_path / "bad.mcap", flip=(at, at + 1, at + 2, at + 3))
    rc, out, _ = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 0, out
    assert messages(tmp_path / "fixed.mcap") == messages(log)
    assert ("nothing lost" if where == "message index" else "fails its CRC check") in out
    assert list(iter_raw_records(bad)) == list(iter_raw_records(log))


def test_nothing_recoverable_is_exit_1_and_no_output(log: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A log torn inside its first chunk: no message can be read: exit 1, one line, nothing written."""
    c = chunks(log)[0]
    bad = damaged(log, tmp_path / "bad.mcap", cut=c.chunk_start_offset + c.chunk_length // 2)
    rc, out, err = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 1 and "nothing could be recovered" in err and err.count("\n") == 1
    assert sorted(os.listdir(tmp_path)) == ["bad.mcap"]


# ---- the readers ----

@pytest.mark.parametrize("verb", ["export", "replay", "report", "batch"])
def test_readers_name_the_damaged_bytes_and_recover(log: Path, tmp_path: Path, verb: str,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """A finished log with a damaged middle chunk: exit 1, one line naming its bytes and `slipdaq recover`, never
    'at its start'; no output left behind."""
    if verb == "batch":
        pytest.importorskip("distributed")
    c = chunks(log)[len(chunks(log)) // 2]
    bad = damaged(log, tmp_path / "bad.mcap", flip=middle(c))
    out = tmp_path / "out"
    argv = {"export": ["export", bad, "--csv", f"{out}.csv"], "replay": ["replay", bad, "-o", f"{out}.mcap"],
            "report": ["report", bad, "-o", out], "batch": ["batch", bad, "-o", out, "--workers", "1"]}[verb]
    rc, _, err = cli(argv, capsys)
    assert rc == 1, err
    line = err if verb != "batch" else next(x for x in err.splitlines() if "failed:" in x) + "\n"
    assert line.count("\n") == 1, err
    assert f"damaged at bytes {c.chunk_start_offset}-{c.chunk_start_offset + c.chunk_length} " in line
    assert f"`slipdaq recover {bad} -o FIXED.mcap`" in line and "at its start" not in line
    if verb != "batch":
        assert sorted(os.listdir(tmp_path)) == ["bad.mcap"]


def test_a_torn_log_with_damage_says_both(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Damage in chunk 3 and the file cut inside a later chunk: the readers name the damage and the tear (exit 1);
    recover keeps everything between them (exit 3)."""
    cs = chunks(log)
    c, torn = cs[2], cs[-3]
    bad = damaged(log, tmp_path / "bad.mcap", flip=middle(c), cut=torn.chunk_start_offset + 1000)
    rc, _, err = cli(["export", bad, "--csv", tmp_path / "e.csv"], capsys)
    assert rc == 1 and err.count("\n") == 1
    assert f"damaged at bytes {c.chunk_start_offset}-{c.chunk_start_offset + c.chunk_length} " in err
    assert f"torn at byte {torn.chunk_start_offset} " in err and "slipdaq recover" in err
    with pytest.raises(DamageError) as e:
        list(iter_raw_records(bad))
    assert isinstance(e.value, LogError) and str(e.value) in err
    rc, out, _ = cli(["recover", bad, "-o", tmp_path / "fixed.mcap"], capsys)
    assert rc == 3
    lost = [m for x in cs[cs.index(torn):] + [c] for m in chunk_messages(log, x)]
    assert messages(tmp_path / "fixed.mcap") == without(messages(log), lost)
    assert f"torn: bytes {torn.chunk_start_offset}-{bad.stat().st_size} " in out


def test_a_torn_log_alone_is_read_to_its_tear(log: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A tear without damage is what a power loss leaves: the readers read up to it (a note, exit 0)."""
    torn = chunks(log)[-3]
    bad = damaged(log, tmp_path / "bad.mcap", cut=torn.chunk_start_offset + 1000)
    res = ScanResult(bad)
    assert len(list(iter_raw_records(bad, res))) > 0 and res.torn_at == torn.chunk_start_offset
    rc, _, err = cli(["export", bad, "--csv", tmp_path / "e.csv"], capsys)
    assert rc == 0 and "was not finished" in err


def test_survey_lists_the_damage_the_readers_name(log: Path, tmp_path: Path) -> None:
    c = chunks(log)[6]
    bad = damaged(log, tmp_path / "bad.mcap", flip=middle(c))
    res = survey(bad)
    (d,) = res.damaged
    assert (d.start, d.end, d.tail, d.loses_data) == (c.chunk_start_offset, c.chunk_start_offset + c.chunk_length,
                                                      False, True)
    assert d.lost_messages == len(chunk_messages(log, c)) and res.lossy and res.finished
    assert (d.first_ns, d.last_ns) == (c.message_start_time, c.message_end_time)
