"""The fuzzing battery's parts (tests/test_fuzz.py): real seed files, a hypothesis strategy that damages them as a
card, a crash or a careless edit would (bits flipped, bytes overwritten or zeroed, cut, inserted, deleted,
duplicated, a syntax token dropped in), a watchdog that turns a hang into a failure, and one target per reader.

A target takes a damaged input and asserts what every reader promises: it raises nothing but its documented error
(InputError and its LogError for files, ConfigError for configs and calibrations: no traceback), it returns (the
watchdog: no hang), a verb exits 0, 1 or 2 (3 from `recover` when it wrote its output with losses), and a verb that
fails leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from hypothesis import strategies as st
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.config import ConfigError, load_config
from slipdaq.decode.can_signals import SignalDecoder
from slipdaq.decode.can_wheels import DbcError, WheelDecoder
from slipdaq.decode.framing import GpsFramer
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.decode.ubx import UbxDecoder
from slipdaq.logformat.reader import config_from_log, iter_estimates, iter_raw_records, read_metadata
from slipdaq.logformat.salvage import survey
from slipdaq.offline.recover import recover
from slipdaq.records import NmeaLine
from slipdaq.sources.files import iter_can_logs, iter_nmea_log
from slipdaq.sources.read_errors import InputError
from support.paths import CONFIG, DATA, ROOT

HANG_S = 30
"""A target that has not returned after this long is hung (a bound for the watchdog, not a timing: the inputs are
at most a few hundred kB)."""

TOKENS = (b"\n", b"\r\n", b"=", b"[", b"]", b"[[", b'"', b"'", b",", b"*", b"$", b"-", b"-1", b"0", b"1e400", b"nan",
          b"inf", b"\x00", b"\xff", b"\xb5b", b"\xd3", b"#", b"{", b"}", b"99999999999999999999", b" ", b"\t", b"\\")
"""Inserted as whole tokens: they change the syntax of a text format (TOML, NMEA, candump, ASC, TRC), and \\xb5b
starts a UBX frame, \\xd3 an RTCM 3 one."""


class Hang(Exception):
    """A target ran past HANG_S."""


@contextlib.contextmanager
def watchdog(seconds: int = HANG_S) -> Iterator[None]:
    """Hang past `seconds`; logging off meanwhile (python-can's readers log a warning per line they cannot parse,
    and pytest keeps every record: thousands of inputs made gigabytes of them)."""
    def ring(signum: int, frame: Any) -> None:
        raise Hang(f"no return after {seconds} s")

    old = signal.signal(signal.SIGALRM, ring)
    signal.alarm(seconds)
    logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


KINDS = ("flip", "bytes", "zeros", "cut", "insert", "delete", "duplicate", "token")


@st.composite
def damaged(draw: st.DrawFn, seeds: dict[str, bytes], max_edits: int = 4) -> tuple[str, bytes]:
    """(seed name, its bytes with 1 to max_edits edits). Where and what from a random.Random that hypothesis seeds:
    offsets spread evenly over the file (hypothesis's own integers favour the first bytes)."""
    name = draw(st.sampled_from(sorted(seeds)))
    rng = draw(st.randoms(use_true_random=False))
    data = bytearray(seeds[name])
    for _ in range(draw(st.integers(1, max_edits))):
        kind = draw(st.sampled_from(KINDS))
        pos = rng.randrange(len(data)) if data else 0
        if kind == "flip" and data:
            data[pos] ^= 1 << rng.randrange(8)
        elif kind == "bytes":
            data[pos:pos + 1] = rng.randbytes(rng.randint(1, 16))
        elif kind == "zeros":
            n = rng.randint(1, 4096)
            data[pos:pos + n] = bytes(len(data[pos:pos + n]))
        elif kind == "cut":
            del data[pos:]
        elif kind == "insert":
            data[pos:pos] = rng.randbytes(rng.randint(1, 64))
        elif kind == "delete":
            del data[pos:pos + rng.randint(1, 256)]
        elif kind == "duplicate":
            data[pos:pos] = data[pos:pos + rng.randint(1, 256)]
        elif kind == "token":
            data[pos:pos] = rng.choice(TOKENS)
    return name, bytes(data)


def _head(path: Path, limit: int) -> bytes:
    """The file's first `limit` bytes, cut at a line end when it is longer."""
    data = path.read_bytes()
    return data if len(data) <= limit else data[:data.rfind(b"\n", 0, limit) + 1]


def can_seeds() -> dict[str, bytes]:
    """python-can's own ASC, BLF and TRC test logs and the head of a real candump log, by their names (the suffix
    picks python-can's reader)."""
    out = {p.name: p.read_bytes() for p in sorted((DATA / "python-can").iterdir()) if p.suffix in (".asc", ".blf", ".trc")}
    out["rav4.log"] = _head(DATA / "rav4-comma2k19" / "rav4_bus0.candump.log", 16_000)
    return out


def gps_seeds() -> dict[str, bytes]:
    """gpsd's captures (NMEA of twelve receivers; UBX, RTCM 3 and NMEA mixed) and a stamped NMEA log, their heads."""
    out = {p.name: _head(p, 24_000) for p in sorted((DATA / "gpsd-nmea").glob("*.log"))}
    out |= {p.name: _head(p, 24_000) for p in sorted((DATA / "gpsd-ubx-mixed").glob("*.log"))}
    out["rav4_ublox.nmea"] = _head(DATA / "rav4-comma2k19" / "rav4_ublox.nmea", 16_000)
    return out


def config_seeds() -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in [CONFIG, *sorted((ROOT / "config" / "examples").glob("*.toml"))]}


def _expect(allowed: tuple[type[BaseException], ...], fn: Callable[[], Any]) -> Any:
    """fn(), or None when it raises one of `allowed` (anything else propagates: a crash)."""
    try:
        return fn()
    except allowed:
        return None


def cli(argv: list[Any], statuses: set[int]) -> int:
    """main(argv) under the watchdog, stdout and stderr swallowed; its exit status must be one of `statuses` and
    its stderr must not hold a traceback."""
    out, err = io.StringIO(), io.StringIO()
    with watchdog(), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in argv])
    assert rc in statuses, f"exit {rc}: {err.getvalue()}"
    assert "Traceback" not in err.getvalue()
    return rc


def left(d: Path) -> list[str]:
    return sorted(os.listdir(d))


# ---- the targets ----

def mcap_readers(path: Path, work: Path) -> None:
    """The MCAP reader, the salvage scan and recover (library): LogError (InputError) or ConfigError only; recover
    writes a finished file the mcap library reads whole, or nothing."""
    with watchdog():
        _expect((InputError,), lambda: survey(path))
        _expect((InputError,), lambda: list(iter_raw_records(path)))
        _expect((InputError,), lambda: list(iter_estimates(path)))
        _expect((InputError,), lambda: read_metadata(path))
        _expect((InputError, ConfigError, DbcError), lambda: config_from_log(path))
        out = work / "recovered.mcap"
        rep = _expect((InputError,), lambda: recover([path], out))
    if rep is None:
        assert not out.exists()
        return
    with open(out, "rb") as f:
        got = sum(1 for _ in make_reader(f, validate_crcs=True).iter_messages(log_time_order=False))
    assert got == rep.messages
    out.unlink()


def mcap_verbs(path: Path, work: Path, replay: bool) -> None:
    """`recover` exits 0, 1 or 3, `export` 0 or 1, `replay` 0, 1 or 2 (a damaged stored config); a failure leaves
    only the input."""
    before = left(work)
    rc = cli(["recover", path, "-o", work / "r.mcap"], {0, 1, 3})
    assert (rc == 1) == (left(work) == before)
    (work / "r.mcap").unlink(missing_ok=True)
    if cli(["export", path, "--csv", work / "e.csv", "--allow-empty"], {0, 1}) == 1:
        assert left(work) == before
    (work / "e.csv").unlink(missing_ok=True)
    if replay:
        if cli(["replay", path, "-o", work / "p.mcap", "--no-calibration", "--allow-empty"], {0, 1, 2}) != 0:
            assert left(work) == before
        (work / "p.mcap").unlink(missing_ok=True)


def report_verb(path: Path, work: Path) -> None:
    """`report --live` exits 0 or 1; a failure leaves only the input."""
    before = left(work)
    if cli(["report", path, "-o", work / "rep", "--live"], {0, 1}) == 1:
        assert left(work) == before


def gps_decoders(data: bytes, pieces: list[int]) -> None:
    """The GPS framer (the bytes in pieces of the given sizes, as a serial port hands them over) and the NMEA and UBX
    decoders on what it frames: no exception at all."""
    framer, nmea, ubx = GpsFramer(), NmeaDecoder(), UbxDecoder()
    records = []
    with watchdog():
        pos, t = 0, 1.7e9
        for n in pieces:
            records += framer.feed(data[pos:pos + n], t)
            pos, t = pos + n, t + 0.01
        records += framer.feed(data[pos:], t)
        records += framer.flush()
        for r in records:
            if isinstance(r, NmeaLine):
                nmea.decode(r)
            else:
                ubx.decode(r)


def nmea_log(path: Path) -> None:
    """The NMEA log import wrapper: InputError only."""
    with watchdog():
        _expect((InputError,), lambda: list(iter_nmea_log(path)))


def can_log(path: Path) -> None:
    """The CAN log import wrappers (python-can's candump, ASC, BLF and TRC readers): InputError only."""
    with watchdog():
        _expect((InputError,), lambda: list(iter_can_logs([path])))


def config_file(path: Path) -> None:
    """A config (TOML, with its DBCs beside it): loaded and its DBC decoders built, ConfigError (a DBC that is not
    there, too) or DbcError only."""
    with watchdog():
        cfg = _expect((ConfigError,), lambda: load_config(path))
        if cfg is not None:
            _expect((ConfigError, DbcError), lambda: (WheelDecoder(cfg), SignalDecoder(cfg)))  # as `slipdaq`'s


def calibration_file(path: Path) -> None:
    """`slipdaq calibration show PATH`: 0, or 2 with one line (a CalibrationError is a ConfigError)."""
    cli(["calibration", "show", path, "--config", CONFIG], {0, 2})
