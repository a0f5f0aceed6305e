#!/usr/bin/env python3
"""What the Foxglove live view costs the daemon: CPU of `slipdaq run` at 4 wheels x 1 kHz WPT + 20 Hz NMEA, as
CPU seconds per second of log (a fraction of one core), in three modes, interleaved round by round:

- `off`:     no live server (live.foxglove unset);
- `server`:  `live.foxglove = "127.0.0.1:PORT"`, no client;
- `client`:  the same with one Foxglove WebSocket client (in this process, foxglove.sdk.v1) subscribed to every
             topic, reading and splitting every message.

The rig is benchmarks/perf.py's CPU section (benchmarks/perf_bus.py): `slipdaq run` in a child process reads a
loopback-UDP bus that it reads as it reads SocketCAN, a sender process plays the simulator's drive on it and the NMEA
on a pseudo-terminal; the daemon's CPU time comes from /proc/PID/stat over the drive minus its first
min(2 s, 20 %) and last 0.3 s. Target: `client` at most 2 % of a core above `off`.

    .venv/bin/python -m benchmarks.foxglove_cpu [--seconds 20] [--rounds 3] [--modes off,server,client]

Prints one line per run and a markdown table of the medians (docs/performance.md, "The Foxglove live view").
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import pty
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import slipdaq  # noqa: E402
from benchmarks.perf_common import ROOT, diagnostics_of, free_udp_port, machine, median, proc_cpu_s, table
from slipdaq.config import packaged_config_path  # noqa: E402

MODES = ("off", "server", "client")
WPT_RATE_HZ = 1000.0


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Subscriber:
    """A Foxglove WebSocket client on its own thread: subscribes to every advertised channel and reads everything."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.messages = 0
        self.bytes = 0
        self.error = ""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self) -> None:
        import websockets

        deadline = time.time() + 60
        while True:
            try:
                ws = await websockets.connect(self.url, subprotocols=["foxglove.sdk.v1"], compression=None)
                break
            except OSError:
                if time.time() > deadline or self._stop.is_set():
                    self.error = "could not connect"
                    return
                await asyncio.sleep(0.1)
        next_id = 1
        header = struct.Struct("<BIQ")
        try:
            async for frame in ws:
                if isinstance(frame, str):
                    msg = json.loads(frame)
                    if msg["op"] == "advertise":
                        subs = [{"id": next_id + i, "channelId": ch["id"]} for i, ch in enumerate(msg["channels"])]
                        next_id += len(subs)
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    continue
                opcode, _sub, _t = header.unpack_from(frame)
                if opcode == 1:
                    self.messages += 1
                    self.bytes += len(frame) - header.size
                if self._stop.is_set():
                    break
        except websockets.ConnectionClosed:
            pass
        finally:
            await ws.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


@dataclass
class Run:
    mode: str
    cpu_share: float
    """CPU seconds per second of log, a fraction of one core."""
    frames_sent: int
    frames_logged: int
    lost: int
    client_messages: int = 0
    client_bytes: int = 0
    diag: dict[str, Any] = field(default_factory=dict)


def run_once(mode: str, seconds: float, tmp: Path) -> Run:
    import tomllib

    import tomli_w

    work = Path(tempfile.mkdtemp(dir=tmp, prefix=f"{mode}-"))
    master, slave = pty.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    port = free_udp_port()
    pkg = packaged_config_path()
    conf = tomllib.loads(pkg.read_text())
    conf["can"].update({"interface": "slipdaq_bench_udp", "channel": f"127.0.0.1:{port}",
                        "dbc": str((pkg.parent / conf["can"].get("dbc", "wpt.dbc")).resolve())})
    conf["gps"]["port"] = os.ttyname(slave)
    conf.setdefault("log", {})["dir"] = str(work / "logs")
    live_port = free_tcp_port()
    if mode != "off":
        conf["live"] = {"foxglove": f"127.0.0.1:{live_port}"}
    cfg_path = work / "slipdaq.toml"
    cfg_path.write_text(tomli_w.dumps(conf))
    start = round(time.time() + 1.5 * seconds * (4 * WPT_RATE_HZ + 100) / 30000.0 + 4.0, 2)
    py = sys.executable
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(slipdaq.__file__).resolve().parents[1]), str(ROOT)] +
                                        ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    sender = subprocess.Popen(
        [py, "-m", "benchmarks.perf_bus", "sender", "--port", str(port), "--nmea-fd", str(master),
         "--wpt-rate-hz", str(WPT_RATE_HZ), "--gps-rate-hz", "20", "--duration", str(seconds),
         "--start-wall", str(start)], pass_fds=[master], stdout=subprocess.PIPE, text=True, env=env)
    out_file = open(work / "daemon.out", "w")
    daemon = subprocess.Popen([py, "-m", "benchmarks.perf_bus", "daemon", "--config", str(cfg_path), "--log-dir",
                               str(work / "logs")], stdout=out_file, stderr=subprocess.STDOUT, env=env)
    client = None
    try:
        deadline = time.time() + 60
        while not list((work / "logs").glob("*.mcap")):
            if daemon.poll() is not None or time.time() > deadline:
                out_file.flush()
                raise SystemExit(f"slipdaq run did not start: {(work / 'daemon.out').read_text()[-2000:]}")
            time.sleep(0.05)
        if mode == "client":
            client = Subscriber(f"ws://127.0.0.1:{live_port}")
        first = sender.stdout.readline().split()  # type: ignore[union-attr]
        if not first or first[0] != "start":
            raise SystemExit(f"the sender failed: {first}")
        start = float(first[1])
        t_a = start + min(2.0, 0.2 * seconds)
        time.sleep(max(0.0, t_a - time.time()))
        cpu_a, wall_a = proc_cpu_s(daemon.pid), time.time()
        time.sleep(max(0.0, start + seconds - 0.3 - time.time()))
        cpu_b, wall_b = proc_cpu_s(daemon.pid), time.time()
        stats = json.loads(sender.communicate(timeout=seconds + 120)[0].strip().splitlines()[-1])
        time.sleep(0.5)
        if client is not None:
            client.stop()
        daemon.send_signal(signal.SIGTERM)
        daemon.wait(timeout=60)
    finally:
        for p in (sender, daemon):
            if p.poll() is None:
                p.kill()
                p.wait()
        out_file.close()
        os.close(master)
        os.close(slave)
    log_path = next((work / "logs").glob("*.mcap"))
    diag = diagnostics_of(log_path)
    run = Run(mode, (cpu_b - cpu_a) / (wall_b - wall_a), stats["frames"], int(diag.get("can_frames", 0)),
              sum((diag.get("lost_frames") or {}).values()), client.messages if client else 0,
              client.bytes if client else 0, {k: v for k, v in diag.items() if k.startswith("live_")})
    if client is not None and client.error:
        raise SystemExit(f"the Foxglove client failed: {client.error}")
    shutil.rmtree(work, ignore_errors=True)
    return run


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="length of each drive (default 20)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of every mode, interleaved (default 3)")
    ap.add_argument("--modes", default=",".join(MODES), help="comma-separated, of: " + ", ".join(MODES))
    a = ap.parse_args()
    modes = [m for m in a.modes.split(",") if m]
    if any(m not in MODES for m in modes):
        ap.error(f"--modes: one of {', '.join(MODES)}")
    tmp = Path(tempfile.mkdtemp(prefix="foxglove-cpu-"))
    runs: dict[str, list[Run]] = {m: [] for m in modes}
    try:
        for r in range(a.rounds):
            order = modes[r % len(modes):] + modes[:r % len(modes)]  # each mode first in turn
            for mode in order:
                run = run_once(mode, a.seconds, tmp)
                runs[mode].append(run)
                print(f"round {r + 1} {mode:>6}: CPU {100 * run.cpu_share:.2f} % of a core; frames "
                      f"{run.frames_sent:,} sent, {run.frames_logged:,} logged, {run.lost} lost; client "
                      f"{run.client_messages:,} messages, {run.client_bytes / 1e6:.1f} MB; {run.diag}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    off = runs.get("off")
    rows = []
    for mode in modes:
        rs = runs[mode]
        share = median([r.cpu_share for r in rs])
        paired = median([r.cpu_share - o.cpu_share for r, o in zip(rs, off)]) if off and mode != "off" else None
        rows.append([mode, f"{100 * share:.2f} %", " / ".join(f"{100 * r.cpu_share:.2f}" for r in rs),
                     "—" if paired is None else f"{100 * paired:+.2f} %",
                     f"{median([r.client_messages / a.seconds for r in rs]):,.0f}" if mode == "client" else "—",
                     f"{median([r.client_bytes / a.seconds / 1e3 for r in rs]):,.0f}" if mode == "client" else "—",
                     f"{sum(r.lost for r in rs)}", f"{max(r.diag.get('live_dropped_messages', 0) for r in rs)}"])
    m = machine()
    print(f"\n4 x {WPT_RATE_HZ:g} Hz WPT + 20 Hz NMEA, {a.seconds:g} s drives, {a.rounds} interleaved rounds; "
          f"{m['cpu']}, {m['cores']}; python {m['python']}\n")
    print(table(["mode", "CPU, median (s per s of log, % of one core)", "each round", "vs off, median of the rounds' "
                 "differences", "client messages/s",
                 "client kB/s", "frames lost", "live_dropped_messages"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
