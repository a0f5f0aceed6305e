"""Helpers for the reliability tests (tests/test_reliability_*.py): simulated records, fault injectors, a `slipdaq
run` child process fed through a real pseudo-terminal, a small tmpfs."""

from __future__ import annotations

import contextlib
import functools
import math
import os
import pty
import shutil
import subprocess
import sys
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from slipdaq.config import load_config
from slipdaq.records import CanFrame, NmeaLine, RawRecord
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG, ROOT

# ---- records ----

@functools.lru_cache(maxsize=8)
def _sim_records(duration_s: float, wpt_rate_hz: float, gps_rate_hz: float, start_count: int, seed: int
                 ) -> tuple[RawRecord, ...]:
    cfg = load_config(CONFIG)
    settings = SimSettings(wpt_rate_hz=wpt_rate_hz, gps_rate_hz=gps_rate_hz, start_count=start_count, seed=seed)
    return tuple(ev.record for ev in generate(cfg, "cycle", "paved", settings, duration_s=duration_s)
                 if ev.record is not None)


def sim_records(duration_s: float = 8.0, wpt_rate_hz: float = 100.0, gps_rate_hz: float = 10.0,
                start_count: int = 2**32 - 20000, seed: int = 1) -> list[RawRecord]:
    """The simulator's raw records of an accelerate-cruise-brake cycle (CAN frames near the counter's wrap)."""
    return list(_sim_records(duration_s, wpt_rate_hz, gps_rate_hz, start_count, seed))


def nmea(body: str) -> str:
    cs = 0
    for ch in body.encode():
        cs ^= ch
    return f"${body}*{cs:02X}"


# ---- a UART at the wrong baud rate ----

def uart_misread(data: bytes, tx_baud: int, rx_baud: int, idle_bits: int = 0) -> bytes:
    """The bytes a UART at rx_baud reads from data sent 8N1 at tx_baud (framing errors read as 0x00, as Linux does
    without IGNPAR/PARMRK)."""
    bits: list[int] = [1] * 10  # idle line before the first start bit
    for byte in data:
        bits += [0] + [(byte >> i) & 1 for i in range(8)] + [1] + [1] * idle_bits
    bits += [1] * 20
    n_bits = len(bits)

    def level(t: float) -> int:
        i = int(t * tx_baud)
        return bits[i] if i < n_bits else 1

    out = bytearray()
    step = 1.0 / (16 * rx_baud)  # the receiver looks for the start bit's edge at 16 times its rate
    t = 0.0
    i = 1
    while True:
        i = max(i, math.ceil(t * tx_baud), 1)
        while i < n_bits and not (bits[i - 1] == 1 and bits[i] == 0):  # the line falls only at a bit boundary
            i += 1
        if i >= n_bits:
            break
        t = math.ceil((i / tx_baud) / step) * step  # the first sample after the edge
        i += 1
        if level(t + 0.5 / rx_baud) != 0:  # a glitch, not a start bit
            continue
        value = sum(level(t + (1.5 + k) / rx_baud) << k for k in range(8))
        out.append(value if level(t + 9.5 / rx_baud) == 1 else 0)
        t += 9.5 / rx_baud
    return bytes(out)


# ---- a GPS that can be unplugged and plugged back, behind a stable symlink ----

class ReplugGps:
    """A pseudo-terminal GPS behind the symlink `link`: unplug() closes it and removes the link, plug() makes a new
    pseudo-terminal (at a new path) and points the link to it. write() drops data while unplugged."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.paths: list[str] = []
        self.master: int | None = None
        self.slave: int | None = None
        self.plug()

    def _open(self) -> tuple[int, int, str]:
        m, s = pty.openpty()
        tty.setraw(s)
        os.set_blocking(m, False)
        return m, s, os.ttyname(s)

    def plug(self, spare: tuple[int, int, str] | None = None) -> str:
        m, s, path = spare or self._open()
        self.master, self.slave = m, s
        self.paths.append(path)
        tmp = self.link.with_name(self.link.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(path)
        tmp.replace(self.link)
        return path

    def prepare(self) -> tuple[int, int, str]:
        """A new pseudo-terminal made while the old one is still open (so that its path is a new one)."""
        return self._open()

    def unplug(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        for fd in (self.master, self.slave):
            if fd is not None:
                os.close(fd)
        self.master = self.slave = None

    def write(self, data: bytes) -> int:
        if self.master is None:
            return len(data)
        try:
            return os.write(self.master, data)
        except (BlockingIOError, OSError):
            return len(data)

    def close(self) -> None:
        self.unplug()


# ---- `slipdaq run` as a child process ----

@dataclass
class DaemonProcess:
    """`slipdaq run` on python-can's virtual bus (so no CAN traffic: it is in-process only), GPS on a real pty."""

    tmp: Path
    proc: subprocess.Popen[str] | None = None
    master: int = -1
    slave: int = -1
    written: list[tuple[float, str]] = field(default_factory=list)
    """(time.time() after the write, line) of every line written to the GPS port."""

    def start(self, extra_config: str = "") -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        port = os.ttyname(self.slave)
        (self.tmp / "wpt.dbc").write_text((ROOT / "config" / "wpt.dbc").read_text())
        (self.tmp / "slipdaq.toml").write_text(
            CONFIG.read_text().replace('interface = "socketcan"', 'interface = "virtual"')
            .replace('"/dev/ttyUSB0"', f'"{port}"') + extra_config)
        self.proc = subprocess.Popen([sys.executable, "-m", "slipdaq", "run", "--log-dir", str(self.tmp / "logs")],
                                     cwd=self.tmp, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not self.logs():
            assert self.proc.poll() is None, self.proc.communicate()
            time.sleep(0.05)
        assert self.logs(), "no log file appeared"
        time.sleep(0.7)  # the daemon opens the port (which flushes its input) right after creating the log

    def logs(self) -> list[Path]:
        return sorted((self.tmp / "logs").glob("*.mcap")) if (self.tmp / "logs").exists() else []

    def write_lines(self, lines: list[str], rate_hz: float) -> None:
        for line in lines:
            os.write(self.master, (line + "\r\n").encode())
            self.written.append((time.time(), line))
            time.sleep(1.0 / rate_hz)

    def signal(self, sig: int) -> tuple[str, str]:
        assert self.proc is not None
        self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=30)
        return out, err

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate(timeout=30)
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def gps_lines(seconds: float, rate_hz: float = 20.0) -> list[str]:
    """NMEA lines of the simulator (RMC, GGA, VTG per epoch) for `seconds` of driving."""
    return [r.line for r in sim_records(seconds, wpt_rate_hz=0.0, gps_rate_hz=rate_hz) if isinstance(r, NmeaLine)]


# ---- a small file system that fills up ----

@contextlib.contextmanager
def small_tmpfs(where: Path, size: str = "1M") -> Iterator[Path]:
    """A tmpfs of `size` mounted at where (root only); the test is skipped when it cannot be mounted."""
    where.mkdir(parents=True, exist_ok=True)
    if shutil.which("mount") is None:
        pytest.skip("no mount command")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size},mode=0777", "tmpfs", str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {r.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], capture_output=True)


def fill(directory: Path, leave_bytes: int) -> Path:
    """A filler file that leaves about leave_bytes free on directory's file system."""
    st = os.statvfs(directory)
    free = st.f_bavail * st.f_frsize
    filler = directory / "filler.bin"
    with open(filler, "wb") as f:
        f.write(b"\0" * max(free - leave_bytes, 0))
    return filler


def can_frames(records: list[RawRecord]) -> list[CanFrame]:
    return [r for r in records if isinstance(r, CanFrame)]
