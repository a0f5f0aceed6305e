"""CPU of `slipdaq run` reading a loopback-UDP bus (benchmarks/perf_bus.py) fed by a sender process."""

from __future__ import annotations

import argparse
import json
import os
import pty
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tty
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import slipdaq
from benchmarks.perf_common import ROOT, base_config, diagnostics_of, free_udp_port, proc_cpu_s, table
from benchmarks.perf_latency import Latency, analyse_latency
from slipdaq.config import packaged_config_path


@dataclass
class CpuResult:
    label: str
    rate_hz: float
    seconds: float
    cpu_share: float
    frames_sent: int
    frames_logged: int
    lost: int
    latency: Latency | None
    sender: dict[str, Any]


def run_cpu(a: argparse.Namespace, tmp: Path, total_rate_hz: float, label: str,
            read_interval_s: float | None = None) -> CpuResult:
    """`slipdaq run` on the loopback rig at total_rate_hz + 20 Hz NMEA; read_interval_s overrides can.read_interval_s."""
    import tomllib

    import tomli_w

    seconds = a.cpu_seconds
    work = Path(tempfile.mkdtemp(dir=tmp, prefix="cpu-"))
    master, slave = pty.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    port = free_udp_port()
    pkg = packaged_config_path()
    conf = tomllib.loads(pkg.read_text())
    conf["can"].update({"interface": "slipdaq_bench_udp", "channel": f"127.0.0.1:{port}",
                        "dbc": str((pkg.parent / conf["can"].get("dbc", "wpt.dbc")).resolve())})
    if read_interval_s is not None:
        conf["can"]["read_interval_s"] = read_interval_s
    conf["gps"]["port"] = os.ttyname(slave)
    conf.setdefault("log", {})["dir"] = str(work / "logs")
    cfg_path = work / "slipdaq.toml"
    cfg_path.write_text(tomli_w.dumps(conf))
    probe_path = work / "probe.json"
    gen_estimate_s = seconds * (total_rate_hz + 100) / 30000.0
    start = round(time.time() + 1.5 * gen_estimate_s + 4.0, 2)
    py = sys.executable
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(slipdaq.__file__).resolve().parents[1]), str(ROOT)] +
                                        ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    who = "`slipdaq run`"
    print(f"cpu: {label}: {who} in a child process, sender in another, {seconds:g} s...", flush=True)
    sender = subprocess.Popen(
        [py, "-m", "benchmarks.perf_bus", "sender", "--port", str(port), "--nmea-fd", str(master),
         "--wpt-rate-hz", str(total_rate_hz / 4), "--gps-rate-hz", "20", "--duration", str(seconds),
         "--start-wall", str(start)], pass_fds=[master], stdout=subprocess.PIPE, text=True, env=env)
    out_file = open(work / "daemon.out", "w")
    child = ["daemon"]
    daemon = subprocess.Popen(
        [py, "-m", "benchmarks.perf_bus", *child, "--config", str(cfg_path), "--log-dir", str(work / "logs"),
         "--probe", str(probe_path)], stdout=out_file, stderr=subprocess.STDOUT, env=env)
    try:
        deadline = time.time() + 60
        while not list((work / "logs").glob("*.mcap")):
            if daemon.poll() is not None or time.time() > deadline:
                out_file.flush()
                raise SystemExit(f"slipdaq run did not start: {(work / 'daemon.out').read_text()[-2000:]}")
            time.sleep(0.05)
        warm = min(2.0, 0.2 * seconds)
        first = sender.stdout.readline().split()  # type: ignore[union-attr]
        if not first or first[0] != "start":
            raise SystemExit(f"the sender failed: {first}")
        start = float(first[1])  # later than planned when generating took longer than the lead
        t_a = start + warm
        time.sleep(max(0.0, t_a - time.time()))
        if getattr(a, "cpu_profile", None) and shutil.which("py-spy", path=str(Path(py).parent)):
            Path(a.cpu_profile).mkdir(parents=True, exist_ok=True)
            out = Path(a.cpu_profile) / f"daemon-{int(total_rate_hz)}hz.txt"
            subprocess.Popen([str(Path(py).parent / "py-spy"), "record", "--pid", str(daemon.pid), "-r", "1000",
                              "-d", str(max(1, int(start + seconds - 0.5 - time.time()))), "-f", "raw", "-o", str(out)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        cpu_a, wall_a = proc_cpu_s(daemon.pid), time.time()
        t_b = start + seconds - 0.3
        time.sleep(max(0.0, t_b - time.time()))
        cpu_b, wall_b = proc_cpu_s(daemon.pid), time.time()
        stats = json.loads(sender.communicate(timeout=seconds + 120)[0].strip().splitlines()[-1])
        time.sleep(0.5)
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
    share = (cpu_b - cpu_a) / (wall_b - wall_a) * 100.0
    log_path = next((work / "logs").glob("*.mcap"))
    probe = json.loads(probe_path.read_text()) if probe_path.exists() else []
    cfg = base_config()
    frame_ms, trig_ms, by_nmea, n, notes = analyse_latency(log_path, probe, cfg)
    diag = diagnostics_of(log_path)
    frames_logged = int(diag.get("can_frames", 0))
    lost = sum((diag.get("lost_frames") or {}).values())
    lat = Latency(f"{who}, {label}", n, frame_ms, trig_ms, by_nmea, frames_logged, lost, seconds, notes)
    shutil.rmtree(work, ignore_errors=True)
    print(f"  CPU {share:.1f} % of one core; {stats['frames']:,} frames sent, {frames_logged:,} logged, {lost} lost; "
          f"latency p50 {lat.pct(frame_ms, 50)} ms p99 {lat.pct(frame_ms, 99)} ms", flush=True)
    return CpuResult(f"{who}, {label}", total_rate_hz, seconds, share, stats["frames"], frames_logged, lost, lat,
                     stats)


def cpu_table(cpus: list[CpuResult]) -> str:
    rows = []
    for c in cpus:
        kept = c.frames_logged + c.lost >= c.frames_sent * 0.999
        rows.append([c.label, f"{c.seconds:g} s", f"{c.cpu_share:.1f} %", f"{c.frames_sent:,}", f"{c.frames_logged:,}",
                     f"{c.lost}", "yes" if kept else "**no**", f"{c.sender.get('max_late_s', 0) * 1e3:.1f} ms"])
    return (table(["load", "measured over", "CPU, % of one core", "frames sent", "frames logged", "lost (Seq gaps)",
                   "kept up", "sender's worst lateness"], rows) +
            "\n\n\"kept up\": every frame sent was logged or counted lost by the time the sender had stopped 0.5 s "
            "earlier. A daemon that does not keep up is saturated: its CPU share is then what the scheduler gave it "
            "on this shared machine, not what the load needs. Target: ≤ 10 % of a core at 4 × 1 kHz.")
