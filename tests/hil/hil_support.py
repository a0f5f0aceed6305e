"""Shared parts of the HIL tests: skip logic, configs, the processes under test and their output, log reading.

Every program runs as its own process and they talk only over vcan0 and pseudo-terminals: `slipdaq run` (the
daemon), `slipdaq simulate`, `tools/replay/replay_bus.py` (each forked, already imported, by zygote.py: see there
why) and the standard-library `wpt_sender.py` (executed). Each process's stdout and stderr lines are kept with the
wall-clock time the test read them (`Proc.lines`), which is how the tests time what a process reports.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, NamedTuple

from wpt_sender import Drive, read_nmea, write_nmea  # noqa: F401  (the sender's file formats, re-exported)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PY = sys.executable
CHANNEL = "vcan0"
IDS = (0x310, 0x311, 0x312, 0x313)


def can_unavailable_reason() -> str | None:
    """Why SocketCAN tests cannot run here (None when they can): no AF_CAN in the kernel, or no vcan0."""
    if not hasattr(socket, "AF_CAN"):
        return "no socket.AF_CAN on this platform"
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as e:
        if e.errno == errno.EAFNOSUPPORT:
            return "kernel has no SocketCAN (errno 97); run tests/hil/run_vm.sh"
        raise
    if not os.path.exists(f"/sys/class/net/{CHANNEL}"):
        return f"no {CHANNEL} interface; run tests/hil/run_vm.sh"
    return None


# ---- reporting figures past pytest's capture ----

_pytest_config: Any = None
RESULTS: list[str] = []
"""Every figure reported in this session, in order."""


def bind_pytest(config: Any) -> None:
    """Let report() print past pytest's output capture (call from a fixture with `pytestconfig`)."""
    global _pytest_config
    _pytest_config = config


def report(text: str) -> None:
    """A measured figure: printed to the terminal even under pytest's capture (so it shows in the VM's output)."""
    RESULTS.append(text)
    capman = _pytest_config.pluginmanager.getplugin("capturemanager") if _pytest_config is not None else None
    with capman.global_and_fixture_disabled() if capman is not None else contextlib.nullcontext():
        print(f"hil: {text}", flush=True)


# ---- configs ----

def write_config(directory: Path, gps_port: str, latency: str = "0.0") -> Path:
    """The example config on vcan0 with the GPS on gps_port, the DBC copied beside it.

    GPS latency is fixed at 0 by default: the traffic sources send NMEA with zero latency on the same clock as their
    CAN frames. With latency '"auto"' the daemon finds it itself: the sentences' UTC is not the time they are sent
    (the simulator's drive is dated 2026-01-01), so to the daemon the host clock is months off UTC, as in a car
    without network time, and the latency must come from the wheels.
    """
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "wpt.dbc").write_text((ROOT / "config" / "wpt.dbc").read_text())
    text = (ROOT / "config" / "slipdaq.toml").read_text()
    text = text.replace('channel = "can0"', f'channel = "{CHANNEL}"').replace('"/dev/ttyUSB0"', f'"{gps_port}"')
    text = re.sub(r"^latency_s = .*$", f"latency_s = {latency}", text, count=1, flags=re.M)
    assert 'interface = "socketcan"' in text and f'"{gps_port}"' in text and f"latency_s = {latency}" in text
    path = directory / "slipdaq.toml"
    path.write_text(text)
    return path


# ---- processes ----

class Proc:
    """A process whose stdout (stderr merged) is read by a thread, line by line, with the time each line was read."""

    def __init__(self, name: str, stream: IO[str]) -> None:
        self.name = name
        self.lines: list[tuple[float, str]] = []
        self._cv = threading.Condition()
        self._stream = stream
        self._reader = threading.Thread(target=self._read, name=f"read-{name}", daemon=True)
        self._reader.start()

    # implemented by subclasses
    @property
    def pid(self) -> int:
        raise NotImplementedError

    def poll(self) -> int | None:
        raise NotImplementedError

    def _read(self) -> None:
        for line in self._stream:
            with self._cv:
                self.lines.append((time.time(), line.rstrip("\n")))
                self._cv.notify_all()
        with self._cv:
            self._cv.notify_all()

    def output(self) -> str:
        with self._cv:
            return "\n".join(line for _, line in self.lines)

    def wait_line(self, pattern: str, timeout_s: float, since: int = 0) -> tuple[float, re.Match[str]]:
        """(read time, match) of the first line from index `since` matching the regex; AssertionError on timeout."""
        rx = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        with self._cv:
            i = since
            while True:
                while i < len(self.lines):
                    t, line = self.lines[i]
                    if m := rx.search(line):
                        return t, m
                    i += 1
                left = deadline - time.monotonic()
                if left <= 0 or (self.poll() is not None and not self._reader.is_alive()):
                    raise AssertionError(f"{self.name}: no line matching {pattern!r} within {timeout_s:.0f} s; "
                                         f"exit {self.poll()}; output:\n{self.output()[-4000:]}")
                self._cv.wait(min(left, 0.5))

    def wait(self, timeout_s: float) -> int:
        deadline = time.monotonic() + timeout_s
        while (rc := self.poll()) is None:
            if time.monotonic() > deadline:
                raise AssertionError(f"{self.name} still running after {timeout_s:.0f} s; output:\n"
                                     f"{self.output()[-4000:]}")
            time.sleep(0.1)
        self._reader.join(timeout=30)
        return rc

    def signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def kill(self) -> None:
        """Last resort in a finally: this process only, by its pid."""
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGCONT)
                os.kill(self.pid, signal.SIGKILL)
            with contextlib.suppress(AssertionError):
                self.wait(30)


class ExecProc(Proc):
    """A program executed with subprocess.Popen."""

    def __init__(self, name: str, argv: Sequence[str], cwd: Path | None = None,
                 pass_fds: Sequence[int] = ()) -> None:
        self.popen = subprocess.Popen(
            list(argv), cwd=cwd or ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            text=True, bufsize=1, env=os.environ | {"PYTHONUNBUFFERED": "1"}, pass_fds=tuple(pass_fds),
        )
        assert self.popen.stdout is not None
        super().__init__(name, self.popen.stdout)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def poll(self) -> int | None:
        return self.popen.poll()


class Zygote:
    """zygote.py: imports slipdaq once, then forks already-imported processes on request (see zygote.py)."""

    def __init__(self) -> None:
        self._sock, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.proc = ExecProc("zygote", [PY, str(HERE / "zygote.py"), str(theirs.fileno())], pass_fds=[theirs.fileno()])
        theirs.close()
        self._lock = threading.Lock()
        self.started_s = time.time()
        self.ready_s: float | None = None

    def wait_ready(self, timeout_s: float = 900.0) -> float:
        """Seconds the zygote needed for its imports."""
        if self.ready_s is None:
            self.ready_s = self.proc.wait_line(r"^zygote: ready", timeout_s)[0]
        return self.ready_s - self.started_s

    def exit_code(self, pid: int) -> int | None:
        with self.proc._cv:
            for _, line in self.proc.lines:
                if line.startswith(f"exited {pid} "):
                    return int(line.split()[2])
        return None

    def spawn(self, name: str, kind: str, argv: Sequence[str], *, cwd: Path | None = None, go: str | None = None,
              delay_s: float = 0.0, nice: int = 0) -> ZygoteChild:
        """kind "slipdaq": slipdaq.cli.main(argv) (= `slipdaq ARGV`); "script": argv[0] run as __main__; nice: the
        child's scheduling priority (absolute; kept where not permitted)."""
        self.wait_ready()
        r, w = os.pipe()
        request = {"kind": kind, "argv": list(argv), "cwd": str(cwd or ROOT), "go": go, "delay": delay_s,
                   "nice": nice}
        with self._lock:
            socket.send_fds(self._sock, [json.dumps(request).encode()], [w])
            pid = json.loads(self._sock.recv(4096))["pid"]
        os.close(w)
        return ZygoteChild(name, self, pid, os.fdopen(r, "r", buffering=1))

    def close(self) -> None:
        self._sock.close()
        with contextlib.suppress(AssertionError):
            self.proc.wait(30)
        self.proc.kill()


class ZygoteChild(Proc):
    def __init__(self, name: str, zygote: Zygote, pid: int, stream: IO[str]) -> None:
        self.zygote = zygote
        self._pid = pid
        super().__init__(name, stream)

    @property
    def pid(self) -> int:
        return self._pid

    def poll(self) -> int | None:
        return self.zygote.exit_code(self._pid)


# ---- the daemon ----

_STATUS = re.compile(r"\| can \d+ fr/s \((\d+) frames, lost (\d+)\b")  # then maybe error classes, reader errors
_WRITTEN = re.compile(r"log written: (\S+) \((\d+) CAN frames, (\d+) NMEA lines, (\d+) estimates, (\d+) lost frames, "
                      r"(\d+) bad sentences\)")


@dataclass
class DaemonResult:
    log: Path
    can_frames: int
    nmea_lines: int
    estimates: int
    lost_frames: int
    bad_sentences: int
    output: str


DAEMON_NICE = -5
"""The daemon under test runs ahead of the traffic sources and the test process in the guest: when the emulated
machine has less CPU than they all want, the sources fall late (measured and judged around), not the daemon."""


class Daemon:
    """`slipdaq run --config C --log-dir D` on vcan0, its own process at nice DAEMON_NICE (root only); a status line
    every 5 s (stdout is a pipe)."""

    def __init__(self, zygote: Zygote, config: Path, log_dir: Path, name: str = "daemon") -> None:
        self.log_dir = log_dir
        self.proc = zygote.spawn(name, "slipdaq", ["run", "--config", str(config), "--log-dir", str(log_dir)],
                                 cwd=config.parent, nice=DAEMON_NICE)

    @property
    def go(self) -> str:
        """A glob for launching traffic sources: the daemon's log exists, so its CAN socket is bound and read."""
        return str(self.log_dir / "*.mcap")

    @property
    def pid(self) -> int:
        return self.proc.pid

    def wait_log_open(self, timeout_s: float = 300.0) -> Path:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if logs := sorted(self.log_dir.glob("*.mcap")):
                return logs[0]
            if self.proc.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"daemon: no log in {self.log_dir} after {timeout_s:.0f} s; exit {self.proc.poll()}; "
                             f"output:\n{self.proc.output()[-4000:]}")

    def status_points(self) -> list[tuple[float, int]]:
        """(read time, CAN frames processed) of every status line so far."""
        with self.proc._cv:
            return [(t, int(m.group(1))) for t, line in self.proc.lines if (m := _STATUS.search(line))]

    def wait_frames(self, expected: int, timeout_s: float, stall_lines: int = 3) -> int:
        """Until a status line reports `expected` CAN frames processed, or the count stayed the same for
        `stall_lines` lines in a row (nothing more is coming), or the timeout. Returns the last count seen."""
        deadline = time.monotonic() + timeout_s
        last, same, seen = -1, 0, 0
        while time.monotonic() < deadline and self.proc.poll() is None:
            points = self.status_points()
            if len(points) != seen:
                seen = len(points)
                n = points[-1][1]
                if n >= expected:
                    return n
                same = same + 1 if n == last else 0
                last = n
                if same >= stall_lines:
                    return n
            time.sleep(0.5)
        return last

    def stop(self, timeout_s: float = 600.0) -> DaemonResult:
        """SIGINT (the daemon finishes its log) and the counts of its last line."""
        self.proc.signal(signal.SIGINT)
        rc = self.proc.wait(timeout_s)
        out = self.proc.output()
        assert rc == 0, f"daemon exited {rc}:\n{out[-4000:]}"
        assert "Traceback" not in out, out[-4000:]
        m = _WRITTEN.search(out)
        assert m, out[-4000:]
        frames, lines, estimates, lost, bad = (int(m.group(i)) for i in range(2, 7))
        return DaemonResult(Path(m.group(1)), frames, lines, estimates, lost, bad, out)


# ---- traffic sources ----

def start_replay_bus(zygote: Zygote, log: Path, gps_link: str, *, go: str, delay_s: float = 1.0,
                     name: str = "replay_bus") -> ZygoteChild:
    """`python tools/replay/replay_bus.py LOG --interface socketcan --channel vcan0 --gps-link L`, started when
    `go` matches a file (plus delay_s)."""
    return zygote.spawn(name, "script", [str(ROOT / "tools" / "replay" / "replay_bus.py"), str(log),
                                         "--interface", "socketcan", "--channel", CHANNEL, "--gps-link", gps_link],
                        go=go, delay_s=delay_s)


def start_sender(rate_hz: float, duration_s: float, *, go: str, delay_s: float = 1.0, record: Path | None = None,
                 then_burst: int = 0, burst_rate_hz: float = 0.0, drive: Path | None = None,
                 nmea: Path | None = None, gps_link: str | None = None, nmea_record: Path | None = None,
                 gps_reader_pid: int | None = None, mti: Path | None = None, mti_link: str | None = None,
                 name: str = "wpt_sender") -> ExecProc:
    """wpt_sender.py: WPT frames at rate_hz per wheel for duration_s, then optionally `then_burst` more frames at
    burst_rate_hz per wheel; with `drive`, each frame's PulseCount is the drive's count at the moment it is sent;
    with `nmea`, those lines on a pseudo-terminal linked at gps_link; with `mti`, an MTi's messages (`T HEX` lines)
    on another, linked at mti_link. It starts when `go` matches a file and (with gps_reader_pid) that process has
    the pseudo-terminals open, plus delay_s."""
    argv = [PY, str(HERE / "wpt_sender.py"), "--go", go, "--delay", f"{delay_s:g}", "--channel", CHANNEL,
            "--rate-hz", f"{rate_hz:g}", "--duration", f"{duration_s:g}"]
    for flag, value in (("--record", record), ("--drive", drive), ("--nmea", nmea), ("--gps-link", gps_link),
                        ("--nmea-record", nmea_record), ("--gps-reader-pid", gps_reader_pid), ("--mti", mti),
                        ("--mti-link", mti_link)):
        if value is not None:
            argv += [flag, str(value)]
    if then_burst:
        argv += ["--then-burst", str(then_burst), "--burst-rate-hz", f"{burst_rate_hz:g}"]
    return ExecProc(name, argv)


_PROGRESS = re.compile(r"^sender: at ([\d.]+) sent (\d+) failed (\d+) nmea (\d+)")


@dataclass(frozen=True)
class SenderProgress:
    at_s: float
    """The sender's time.time() when it printed the line."""
    sent: int
    failed: int
    nmea: int


def sender_progress(proc: Proc) -> list[SenderProgress]:
    """Every progress line wpt_sender.py has printed so far (one each 0.25 s)."""
    with proc._cv:
        return [SenderProgress(float(m.group(1)), int(m.group(2)), int(m.group(3)), int(m.group(4)))
                for _, line in proc.lines if (m := _PROGRESS.match(line))]


def wait_progress(proc: Proc, done: Callable[[list[SenderProgress]], bool], timeout_s: float) -> bool:
    """Until done(progress so far) holds (True), the sender has ended or the timeout (False)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if done(sender_progress(proc)):
            return True
        if proc.poll() is not None:
            return done(sender_progress(proc))
        time.sleep(0.05)
    return False


def sender_result(proc: Proc, timeout_s: float) -> dict[str, Any]:
    """The JSON summary line wpt_sender.py prints at its end."""
    proc.wait(timeout_s)
    for _, line in reversed(proc.lines):
        if line.startswith("{"):
            return json.loads(line)
    raise AssertionError(f"{proc.name}: no result line:\n{proc.output()[-4000:]}")


class SentFrame(NamedTuple):
    can_id: int
    n: int
    """The frame's index per wheel (PulseCount without --drive, Seq = n mod 256)."""
    t_before: float
    t_after: float
    """time.time() just before and just after its send(): the kernel's receive stamp lies between them."""
    count: int | None
    """PulseCount with --drive: the drive's count at t_before."""


def read_sent(record: Path) -> list[SentFrame]:
    """wpt_sender.py --record: every frame sent, in order."""
    out = []
    for line in record.read_text().splitlines():
        f = line.split(",")
        out.append(SentFrame(int(f[0]), int(f[1]), float(f[2]), float(f[3]), int(f[4]) if len(f) > 4 else None))
    return out


def read_nmea_record(record: Path) -> list[tuple[int, float, float]]:
    """wpt_sender.py --nmea-record: (line index, time before, time after) of every NMEA line written, in order."""
    out = []
    for line in record.read_text().splitlines():
        a, b, c = line.split(",")
        out.append((int(a), float(b), float(c)))
    return out


def write_drive(path: Path, truth: Sequence[Any], pulses_per_rev: int, start_count: int) -> None:
    """The --drive file of wpt_sender.py: each wheel's pulses since the start, angle / 2 pi * pulses_per_rev, at the
    times of the truth samples (slipdaq.sim.vehicle.TruthSample, every 10 ms: interpolating linearly between them
    misses a count by under 0.1 pulse)."""
    from slipdaq import WHEELS

    samples = [t for i, t in enumerate(truth) if i == 0 or t.time_s > truth[i - 1].time_s]
    Drive.save(path, start_count, [t.time_s for t in samples],
               [[t.wheels[w].angle_rad / (2 * math.pi) * pulses_per_rev for t in samples] for w in WHEELS])


def cruise_nmea(rate_hz: float, duration_s: float, speed_mps: float = 20.0) -> list[tuple[float, str]]:
    """(time, sentence) of a receiver's RMC, GGA and VTG at rate_hz over duration_s, driving at a constant speed
    (slipdaq.sim.emit's sentences: cheap, no vehicle model to integrate)."""
    from slipdaq.sim.emit import SimSettings, gps_epoch_lines
    from slipdaq.sim.vehicle import TruthSample

    settings = SimSettings()
    out = []
    for k in range(int(duration_s * rate_hz)):
        t = k / rate_hz
        state = TruthSample(t, speed_mps, 0.0, 0.0, speed_mps * t, {})
        out += [(t, line) for line in gps_epoch_lines(state, speed_mps, settings)]
    return out


@dataclass
class LinkChange:
    before_s: float
    """time.time() just before `ip link set` was started."""
    seen_s: float
    """The first time /sys/class/net/vcan0/flags showed the new state (polled every 0.5 ms while `ip` ran)."""
    after_s: float
    """Just after `ip` exited."""


def link(state: str) -> LinkChange:
    """`ip link set vcan0 up|down`, with the moment the kernel's interface flags changed.

    `ip` itself takes up to a second in the VM (a process start under emulation), so its start and end times only
    bracket the change; polling IFF_UP in sysfs while it runs pins the change down to about a millisecond."""
    want_up = state == "up"
    flags = Path(f"/sys/class/net/{CHANNEL}/flags")
    t0 = time.time()
    proc = subprocess.Popen(["ip", "link", "set", CHANNEL, state])
    seen = None
    while seen is None:
        if bool(int(flags.read_text(), 16) & 0x1) == want_up:
            seen = time.time()
        elif proc.poll() is not None:
            time.sleep(0.001)  # ip has exited: the flags must show it now
            if bool(int(flags.read_text(), 16) & 0x1) != want_up:
                raise AssertionError(f"ip link set {CHANNEL} {state}: exit {proc.returncode}, flags {flags.read_text()}")
        else:
            time.sleep(0.0005)
    assert proc.wait(60) == 0
    return LinkChange(t0, seen, time.time())


def proc_state(pid: int) -> str:
    """The state letter in /proc/PID/stat (R running, S sleeping, T stopped, ...)."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    return stat[stat.rindex(")") + 2]


# ---- logs ----

@dataclass
class LogContent:
    """A log's raw records: CAN frames per arbitration id in log order as (timestamp, payload); NMEA lines."""

    by_id: dict[int, list[tuple[float, bytes]]] = field(default_factory=dict)
    nmea: list[tuple[float, str]] = field(default_factory=list)

    @property
    def total(self) -> int:
        return sum(len(v) for v in self.by_id.values())

    def stamps(self) -> list[float]:
        return sorted(t for v in self.by_id.values() for t, _ in v)


def read_log(path: Path) -> LogContent:
    from slipdaq.logformat.reader import iter_raw_records
    from slipdaq.records import CanFrame

    out = LogContent()
    for r in iter_raw_records(path):
        if isinstance(r, CanFrame):
            out.by_id.setdefault(r.arbitration_id, []).append((r.timestamp_s, r.data))
        else:
            out.nmea.append((r.timestamp_s, r.line))
    return out


def seq_gaps(frames: Iterable[tuple[float, bytes]]) -> int:
    """Frames missing by the Seq byte (bit 56): the sum of (b - a - 1) mod 256 over consecutive frames."""
    seqs = [d[7] for _, d in frames]
    return sum((b - a - 1) % 256 for a, b in zip(seqs, seqs[1:]))


def pulse_count(data: bytes) -> int:
    """A WPT frame's PulseCount (wpt_sender.py without --drive: the frame's index per wheel)."""
    return int.from_bytes(data[:4], "little")


def diagnostics(path: Path) -> list[dict[str, Any]]:
    from slipdaq.logformat.reader import iter_topic

    return [d for _, _, d in iter_topic(path, ("/diagnostics",))]


FIT_REL_TOL = 1e-6
"""The fitted stiffness (cx_fit_*) is summed over wheel samples in the batches they were read in: live and replay
split them differently and differ in the last digits (measured up to 3e-9 relative)."""


def replay_differences(log: Path, out: Path) -> list[str]:
    """`slipdaq replay` of a live log (with the config stored in it) against the live estimates in it: what differs
    (empty: the same estimates, every field equal, cx_fit_* within FIT_REL_TOL). What the daemon computed from what
    it received, checked against the offline path on the same records, whatever the timing they came with."""
    import io

    from slipdaq.cli import main
    from slipdaq.logformat.reader import iter_estimates

    with contextlib.redirect_stdout(io.StringIO()):
        rc = main(["replay", str(log), "-o", str(out)])
    if rc != 0:
        return [f"slipdaq replay exited {rc}"]
    live, offline = list(iter_estimates(log)), list(iter_estimates(out))
    diffs = [] if len(live) == len(offline) else [f"{len(live)} live estimates, {len(offline)} replayed"]
    for k, (a, b) in enumerate(zip(live, offline)):
        for key in sorted(set(a) | set(b)):
            x, y = a.get(key), b.get(key)
            if x == y or (key.startswith("cx_fit_") and isinstance(x, float) and isinstance(y, float)
                          and math.isclose(x, y, rel_tol=FIT_REL_TOL)):
                continue
            diffs.append(f"estimate {k} at {a['time_s']:.3f}: {key} live {x!r}, replayed {y!r}")
    return diffs


def finished(path: Path) -> bool:
    """The MCAP file has its summary (the daemon finished it)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return summary is not None and summary.statistics is not None


def percentile(values: Sequence[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, max(0, int(round(q / 100 * (len(s) - 1)))))]


def rate_while_backlogged(points: list[tuple[float, int]], backlog: list[int], at_least: int = 500) -> float | None:
    """Frames per second the daemon processed between status lines while at least `at_least` frames were waiting
    at both ends (it was reading as fast as it could): its throughput. points: (time, frames processed)."""
    pairs = [(points[i], points[i + 1]) for i in range(len(points) - 1)
             if backlog[i] >= at_least and backlog[i + 1] >= at_least and points[i + 1][0] > points[i][0]]
    if not pairs:
        return None
    return sum(b[1] - a[1] for a, b in pairs) / sum(b[0] - a[0] for a, b in pairs)
