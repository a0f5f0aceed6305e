"""What the performance benchmarks share: the machine's description, tables, the simulated inputs."""

from __future__ import annotations

import contextlib
import json
import os
import platform
import socket
import statistics
import subprocess
from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import numpy as np

import slipdaq
from slipdaq.config import Config, load_config, packaged_config_path
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import SimSettings, generate

HERE = Path(__file__).resolve().parent


ROOT = HERE.parent


SKIP_S = 2.0


"""The simulator's cycle starts with 2 s at standstill: ingest data starts after it (the car moving)."""


def base_config() -> Config:
    return load_config(packaged_config_path())


def machine() -> dict[str, str]:
    model = cores = ""
    with contextlib.suppress(Exception):
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=5).stdout
        info = dict(line.split(":", 1) for line in out.splitlines() if ":" in line)
        model = info.get("Model name", "").strip()
        cores = f"{info.get('CPU(s)', '').strip()} CPUs ({info.get('Core(s) per socket', '').strip()} cores/socket, " \
                f"{info.get('Thread(s) per core', '').strip()} thread/core)"
        if info.get("Hypervisor vendor"):
            cores += f", {info['Hypervisor vendor'].strip()} VM"
    mem = ""
    with contextlib.suppress(Exception):
        kb = int(Path("/proc/meminfo").read_text().split("MemTotal:")[1].split()[0])
        mem = f"{kb / 1024 / 1024:.0f} GiB"
    import cantools
    import mcap

    versions = {"numpy": np.__version__, "python-can": can.__version__, "cantools": cantools.__version__,
                "mcap": getattr(mcap, "__version__", "?")}
    with contextlib.suppress(Exception):
        from importlib.metadata import version

        versions["mcap"] = version("mcap")
        versions["zstandard"] = version("zstandard")
    src = Path(slipdaq.__file__).resolve().parent
    rev = ""
    with contextlib.suppress(Exception):
        top = subprocess.run(["git", "-C", str(src), "rev-parse", "--show-toplevel"], capture_output=True,
                             text=True, timeout=5)
        if top.returncode == 0:
            head = subprocess.run(["git", "-C", str(src), "rev-parse", "--short", "HEAD"], capture_output=True,
                                  text=True, timeout=5).stdout.strip()
            dirty = subprocess.run(["git", "-C", str(src), "status", "--porcelain", "--", "."], capture_output=True,
                                   text=True, timeout=5).stdout.strip()
            rev = f"{head}{' + uncommitted changes in src/' if dirty else ''}"
    return {"cpu": model, "cores": cores, "memory": mem, "os": f"{platform.system()} {platform.release()}",
            "python": platform.python_version(), **versions, "slipdaq": f"{src} {rev}".strip()}


def busy_processes(min_cpu: float = 10.0) -> str:
    """Other processes using more than min_cpu % of a core (ps), as 'name NN %' items."""
    try:
        out = subprocess.run(["ps", "-eo", "pid=,pcpu=,comm="], capture_output=True, text=True, timeout=5).stdout
    except Exception:
        return ""
    items = []
    for line in out.splitlines():
        parts = line.split(None, 2)
        if len(parts) == 3 and int(parts[0]) != os.getpid() and float(parts[1]) >= min_cpu:
            items.append((float(parts[1]), parts[2]))
    return ", ".join(f"{name} {cpu:.0f} %" for cpu, name in sorted(items, reverse=True))


def median(xs: list[float]) -> float:
    return float(statistics.median(xs))


def fmt_rate(x: float) -> str:
    return f"{x:,.0f}"


def table(headers: list[str], rows: list[list[Any]]) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" if i == 0 else "---:" for i in
                                                             range(len(headers))) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def sim_items(wpt_rate_hz: float, gps_rate_hz: float, seconds: float, *, skip_s: float = SKIP_S,
              start_utc_s: float | None = None, gps_latency_s: float = 0.05, jitter_s: float = 0.0002,
              ) -> list[Any]:
    """Simulated records as python-can Messages (CAN) and NmeaLine (GPS), in arrival order, after skip_s."""
    cfg = base_config()
    settings = replace(SimSettings(), wpt_rate_hz=wpt_rate_hz, gps_rate_hz=gps_rate_hz, gps_latency_s=gps_latency_s,
                       can_jitter_s=jitter_s)
    if start_utc_s is not None:
        settings = replace(settings, start_utc_s=start_utc_s)
    items: list[Any] = []
    Message = can.Message
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=skip_s + seconds):  # type: ignore[arg-type]
        r = ev.record
        if r is None or ev.time_s < skip_s:
            continue
        if isinstance(r, CanFrame):
            items.append(Message(timestamp=r.timestamp_s, arbitration_id=r.arbitration_id, data=r.data,
                                 is_extended_id=r.is_extended_id, is_error_frame=r.is_error_frame,
                                 dlc=len(r.data)))
        elif isinstance(r, NmeaLine):
            items.append(r)
    return items


def reader_batches(items: list[Any], size: int = 256) -> list[Any]:
    """The stream as CanBusSource delivers it: runs of at most `size` consecutive frames, NMEA lines between."""
    out: list[Any] = []
    cur: list[Any] = []
    for it in items:
        if isinstance(it, can.Message):
            cur.append(it)
            if len(cur) >= size:
                out.append(cur)
                cur = []
        else:
            if cur:
                out.append(cur)
                cur = []
            out.append(it)
    if cur:
        out.append(cur)
    return out


def wheel_ids(cfg: Config) -> dict[int, str]:
    import cantools

    db = cantools.database.load_string(cfg.load_dbc_text(), database_format="dbc", strict=False)
    return {db.get_message_by_name(f"WPT_{w}").frame_id: w for w in slipdaq.WHEELS}


def diagnostics_of(log_path: Path) -> dict[str, Any]:
    from mcap.reader import make_reader

    last: dict[str, Any] = {}
    with open(log_path, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/diagnostics"], log_time_order=False):
            last = json.loads(m.data)
    return last


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
