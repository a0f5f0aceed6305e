"""sources/candump.py against python-can's CanutilsLogReader: the same frames, every field, from plain and odd lines
(extended IDs, CAN FD, remote and error frames, numeric channels, directions, odd spacing and line ends), however the
text is cut into chunks; a line python-can cannot read raises what python-can raises there, after the same frames."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from slipdaq.records import CanFrameBatch
from slipdaq.sources import candump
from slipdaq.sources.candump import CandumpError, iter_candump
from support.paths import DATA

PLAIN = [b"(1767225600.000066) can0 310#E0B1FFFF00000000 R\n", b"(1767225600.000372) can1 12345678#0102 T\n",
         b"(1767225600.000400) can0 7FF#\n", b"(1767225600.000500) vcan0 001#8d00100100820100\n",
         b"(1767225600.000600) can0 9FFFFFFF#11 r\n", b"(1767225600.000700) can0 FFF#AABBCC t\n"]
ODD = [b"(1767225600.001000) can0 123##1AABB\n", b"(1767225600.001100) can0 123##3" + b"00" * 64 + b" T\n",
       b"(1767225600.001200) can0 123#R\n", b"(1767225600.001300) can0 12345678#R8 R\n",
       b"(1767225600.001400) can0 20000080#0000000000000000\n", b"(1767225600.001500) can0 20000001#01\n",
       b"(1767225600.001600) 0 123#01\n", b"(1767225600.001700) 00 123#02\n", b"(1767225600.001800) can0 12345#03\n",
       b"(1767225600.001900) can0 123#ABC\n", b"(1767225600.002000) can0 123#00112233445566778899\n",
       b"(1767225600.002100)\tcan0 123#04\n", b"(1767225600.002200) can0 123#05 R\r\n", b"\n", b"   \n",
       b"(1767225600.002300)  can0   123#06  \n", b"(1767225600.002400) can0 123#07\r(1767225600.0025) can0 1#08\n",
       b"(1767225601) can0 0x1#09\n", b"(1.5e9) can0 123#0A\n", b"(1767225600.002600) can0 123#0B"]


def frames_of(batches: list[CanFrameBatch]) -> list[tuple]:
    """Every field of every frame, the channel by its name."""
    if not batches:
        return []
    b = CanFrameBatch.concat(batches)
    names = [b.channels[i] for i in b.channel.tolist()]
    return list(zip(b.timestamp_s.tolist(), b.arbitration_id.tolist(), b.flags.tolist(), b.dlc.tolist(),
                    [b.payload(i) for i in range(len(b))], names))


def python_can(path: Path) -> list[tuple]:
    msgs = list(can.CanutilsLogReader(str(path)))
    return frames_of([CanFrameBatch.from_frames(msgs, [m.timestamp for m in msgs])] if msgs else [])


@pytest.mark.parametrize("chunk", [1 << 20, 7, 100])
@pytest.mark.parametrize("lines", [PLAIN, ODD, PLAIN + ODD[:-1] + PLAIN[::-1], ODD[:-1] + PLAIN,
                                   [x.replace(b"\n", b"\r\n") for x in PLAIN * 3]],
                         ids=["plain", "odd", "mixed", "odd-then-plain", "crlf"])
def test_the_frames_python_can_reads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int,
                                     lines: list[bytes]) -> None:
    monkeypatch.setattr(candump, "CHUNK_BYTES", chunk)
    path = tmp_path / "x.log"
    path.write_bytes(b"".join(lines))
    expected = python_can(path)
    assert len(expected) > 5
    assert frames_of(list(iter_candump(path))) == expected


@pytest.mark.parametrize("odd", [b"(1767225600.000066) can0 310#E0B1FFFF00000000 X\n",
                                 b"(1767225600.000066) can0 310$E0B1FFFF00000000 R\n",
                                 b"(1767225600.000066) can0 310#E0B1FFFF0000000g R\n",
                                 b"(17672a5600.000066) can0 310#E0B1FFFF00000000 R\n",
                                 b"(1767225600.000066) can1 310#E0B1FFFF00000000 R\n",
                                 b"(1767225600.000066) can0 310#E0B1FFFF00000000 t\n",
                                 b"(1767225600.000066) can0 310#E0B1FFFF00000000  \n",
                                 b"(1767225600.000066) can0 310#E0B1FFFF0000000000\n",
                                 b"(1767225600.000066) can00 20000080#E0B1FFFF00 R\n",
                                 b"(176722560.0000066) can0 310#E0B1FFFF00000000 R\n",
                                 b"(0000000000.000000) can0 310#E0B1FFFF00000000 R\n"])
@pytest.mark.parametrize("where", [0, 1, 500, 999])
def test_one_line_laid_out_otherwise_among_many_of_its_length(tmp_path: Path, odd: bytes, where: int) -> None:
    """Lines of one length are read as rows of a table: a line of that length in another form or layout is read
    as python-can reads it (or fails as it fails there)."""
    lines = [b"(17672256%02d.%06d) can0 3%02X#%016X R\n" % (i // 1000, i * 997 % 10**6, i % 4, i * 7919 % 2**64)
             for i in range(1000)]
    assert {len(x) for x in lines} == {len(odd)}
    lines[where] = odd
    path = tmp_path / "x.log"
    path.write_bytes(b"".join(lines))
    table = candump._table(path.read_bytes())
    assert table is not None and table[1].sum() >= len(lines) - 1  # the others: read as a table
    try:
        expected = python_can(path)
    except Exception as e:
        with pytest.raises(CandumpError) as ours:
            list(iter_candump(path))
        assert str(ours.value.error) == str(e) and ours.value.frames_before == where
        return
    assert frames_of(list(iter_candump(path))) == expected


def test_lines_of_a_few_layouts_are_read_as_rows(tmp_path: Path) -> None:
    """The table path itself (not the regular expression's) gives python-can's frames."""
    lines = [b"(17672256%02d.%06d) can%d %s#%s T\n" % (i // 1000, i * 997 % 10**6, i % 2 * 3,
                                                      b"%03X" % (i % 7) if i % 3 else b"%08X" % (i * 7919 % 2**29),
                                                      b"%02X" % (i % 256) * (i % 9 if i % 3 else 8))
             for i in range(3000)]
    text = b"".join(lines)
    table = candump._table(text)
    assert table is not None and table[1].all()
    path = tmp_path / "x.log"
    path.write_bytes(text)
    assert frames_of(list(iter_candump(path))) == python_can(path)


def test_stamps_equal_floats_of_their_text(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    lines = []
    for width in (1, 3, 6, 9):  # fraction digits
        for whole in rng.integers(0, 10**9, 300).tolist():
            frac = int(rng.integers(0, 10**width))
            lines.append(b"(%d.%0*d) can0 123#00\n" % (whole, width, frac))
    path = tmp_path / "x.log"
    path.write_bytes(b"".join(lines))
    got = CanFrameBatch.concat(list(iter_candump(path))).timestamp_s.tolist()
    assert got == [float(x[1 : x.index(b")")]) for x in lines]


def test_python_cans_own_logs_written_as_candump(tmp_path: Path) -> None:
    path = tmp_path / "all.log"
    with can.Logger(str(path)) as writer:
        for src in sorted((DATA / "python-can").iterdir()):
            if src.suffix in (".asc", ".blf", ".trc"):
                for m in can.LogReader(str(src)):
                    writer.on_message_received(m)
    expected = python_can(path)
    assert len(expected) > 100
    got = list(iter_candump(path))
    assert frames_of(got) == expected
    assert all(b.data.dtype == np.uint8 for b in got)


@pytest.mark.parametrize("bad", [b"(1767225600.250000) can0 XYZ#00\n", b"(1767225600.250000) can0\n",
                                 b"(abc) can0 123#00\n", b"(1767225600.250000) can0 123#0G\n"])
def test_a_line_python_can_cannot_read_raises_its_error_after_the_frames_before(tmp_path: Path, bad: bytes) -> None:
    path = tmp_path / "bad.log"
    path.write_bytes(b"".join(PLAIN * 20) + bad + b"".join(PLAIN))
    with pytest.raises(Exception) as theirs:
        list(can.CanutilsLogReader(str(path)))
    with pytest.raises(CandumpError) as ours:
        list(iter_candump(path))
    assert type(ours.value.error) is type(theirs.value) and str(ours.value.error) == str(theirs.value)
    assert ours.value.frames_before == len(PLAIN) * 20


def test_bytes_that_are_not_text_fail_as_in_python_can(tmp_path: Path) -> None:
    path = tmp_path / "latin1.log"
    path.write_bytes(b"".join(PLAIN) + b"(1767225600.250000) can0 31\xff#00\n")
    with pytest.raises(UnicodeDecodeError):
        list(iter_candump(path))


@pytest.mark.parametrize("seed", range(8))
def test_merge_by_time_gives_heapq_merge_frame_by_frame(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Batches of frames (stamps out of order, equal to the other streams' at times) merged with record streams, in
    any place among them:
    the frames and records in heapq.merge's order, whatever the batches' and slices' sizes."""
    import heapq
    import random

    from slipdaq.records import CanFrame, NmeaLine
    from slipdaq.sources import files

    rng = random.Random(seed)
    monkeypatch.setattr(files, "MERGE_RUN_FRAMES", rng.choice((1, 3, 50, 4096)))
    stamps = [round(rng.uniform(0, 10), 1) for _ in range(rng.randint(0, 300))]
    if seed % 2:
        stamps.sort()
    frames = [CanFrame(t, i, b"") for i, t in enumerate(stamps)]
    cuts = sorted(rng.sample(range(1, len(frames)), min(5, max(len(frames) - 1, 0)))) if len(frames) > 1 else []
    batches = [CanFrameBatch.from_frames(frames[a:b]) for a, b in zip([0, *cuts], [*cuts, len(frames)])]
    batches.insert(rng.randint(0, len(batches)), CanFrameBatch.from_columns([], [], [], []))
    nmea = [NmeaLine(t, f"n{i}") for i, t in enumerate(sorted(round(rng.uniform(0, 10), 1) for _ in range(30)))]
    other = [NmeaLine(t, f"o{i}") for i, t in enumerate(sorted(round(rng.uniform(0, 10), 1) for _ in range(10)))]

    def key(r: object) -> tuple:
        return ("can", r.timestamp_s, r.arbitration_id) if isinstance(r, CanFrame) else (r.line, r.timestamp_s)

    k = seed % 3  # the frames' stream first, second or third
    streams: list[list] = [nmea, other]
    expected = [key(r) for r in heapq.merge(*streams[:k], frames, *streams[k:], key=lambda r: r.timestamp_s)]
    got = []
    for item in files.merge_by_time(*map(iter, streams[:k]), iter(batches), *map(iter, streams[k:])):
        got += [key(f) for f in item.frames()] if isinstance(item, CanFrameBatch) else [key(item)]
    assert got == expected


def test_numbered_channels_as_python_can_names_them(tmp_path: Path) -> None:
    """python-can makes a numeric channel an int ("007" gives 7): the table takes only the numbers it gives back as
    written, the others are python-can's."""
    lines = [b"(1767225600.%06d) %s 123#0011 R\n" % (i, (b"0", b"7", b"12", b"007")[i % 4]) for i in range(400)]
    path = tmp_path / "x.log"
    path.write_bytes(b"".join(lines))
    table = candump._table(path.read_bytes())
    assert table is not None and table[1].sum() == 300
    assert frames_of(list(iter_candump(path))) == python_can(path)
