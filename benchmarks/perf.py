#!/usr/bin/env python3
"""Performance benchmarks (issue 7): ingest, replay, latency and CPU of slipdaq, and a profile of the ingest path.
Prints markdown tables; --write also puts them in docs/performance.md (between the perf:begin/perf:end markers).
Not a test: nothing here asserts a target.

    .venv/bin/python benchmarks/perf.py [--quick] [--replay-minutes N] [--only SECTIONS] [--write]

Sections (in this order): ingest, replay, latency, cpu, profile.
- ingest:  python-can Messages built in memory first (simulator, 4 WPT messages at 2000 Hz each + 20 Hz NMEA);
           then, interleaved, `rounds` times: slipdaq's live path minus the driver (reader batches of up to 256
           frames, as CanBusSource hands them on for a bus read through python-can: to_frames(msgs) ->
           Pipeline.process_can_batch -> McapLogSink, every frame logged, NMEA lines in arrival order, file closed),
           the same frame by frame (to_frame -> Pipeline.process), and python-can's can.Logger writing the same
           frames to .blf and to .asc. Median frames/s and the ratios.
- replay:  a raw log of N minutes of 4 x 500 Hz + 20 Hz NMEA (written with McapLogSink.on_raw), then
           `slipdaq replay RAW -o OUT` in this process (slipdaq.cli.main). Frames/s and times real time.
- latency: run_daemon in this process on python-can's virtual bus, a sender thread at 4 x 1 kHz + NMEA at 20 Hz on
           a pseudo-terminal; see docs/performance.md for the definition. p50/p99.
- cpu:     `slipdaq run` (slipdaq.cli.main in a child process) reading a loopback-UDP bus that carries SocketCAN
           frames with kernel stamps and that slipdaq reads as it reads SocketCAN (benchmarks/perf_bus.py), the
           sender in another process; the daemon's CPU time from /proc/PID/stat over the run. At 4 x 1 kHz and at
           9,000 frames/s, with the default can.read_interval_s and with 0 (every frame read as it comes); also
           its latency (same definition). --cpu-profile DIR records the daemon with py-spy.
- profile: py-spy (sampling, if installed; else cProfile) of the ingest loop, time by category.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import math
import os
import platform
import pty
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import tty
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import can
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import slipdaq  # noqa: E402
from slipdaq.config import Config, load_config, packaged_config_path  # noqa: E402
from slipdaq.records import CanFrame, NmeaLine  # noqa: E402
from slipdaq.sim.emit import SimSettings, generate  # noqa: E402

SECTIONS = ("ingest", "replay", "latency", "cpu", "profile")
SKIP_S = 2.0
"""The simulator's cycle starts with 2 s at standstill: ingest data starts after it (the car moving)."""


# ---- helpers ------------------------------------------------------------------------------------------------
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


# ---- 1. ingest ----------------------------------------------------------------------------------------------
def ingest_slipdaq(cfg: Config, items: list[Any], path: Path, *, status_sink: bool = False) -> float:
    """Seconds for: to_frame + Pipeline.process for every item, finish, close (construction not timed)."""
    from slipdaq.pipeline import Pipeline
    from slipdaq.sinks.mcap_log import McapLogSink
    from slipdaq.sources.can_bus import to_frame

    sink = McapLogSink(path, cfg, mode="bench")
    sinks: list[Any] = [sink]
    if status_sink:
        from slipdaq.sinks.status import StatusSink

        sinks.append(StatusSink())
    pipeline = Pipeline(cfg, sinks)
    Message = can.Message
    process = pipeline.process
    t0 = time.perf_counter()
    for it in items:
        if type(it) is Message:
            process(to_frame(it))
        else:
            process(it)
    pipeline.finish()
    sink.close()
    return time.perf_counter() - t0


def ingest_batched(cfg: Config, batches: list[Any], path: Path) -> float:
    """Seconds for what the live source and pipeline do per reader wake-up: to_frames(msgs) (a CanFrameBatch from
    48 frames on, else CanFrames) -> Pipeline.process_can_batch, NMEA lines through Pipeline.process; finish, close."""
    from slipdaq.pipeline import Pipeline
    from slipdaq.sinks.mcap_log import McapLogSink
    from slipdaq.sources.can_bus import to_frames

    sink = McapLogSink(path, cfg, mode="bench")
    pipeline = Pipeline(cfg, [sink])
    process, process_can_batch = pipeline.process, pipeline.process_can_batch
    t0 = time.perf_counter()
    for b in batches:
        if type(b) is list:
            process_can_batch(to_frames(b))
        else:
            process(b)
    pipeline.finish()
    sink.close()
    return time.perf_counter() - t0


def ingest_logger(msgs: list[can.Message], path: Path) -> float:
    logger = can.Logger(str(path))
    t0 = time.perf_counter()
    for m in msgs:
        logger.on_message_received(m)
    logger.stop()
    return time.perf_counter() - t0


@dataclass
class IngestResult:
    frames: int
    nmea: int
    seconds_of_data: float
    rates: dict[str, list[float]] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)


def run_ingest(a: argparse.Namespace, tmp: Path) -> IngestResult:
    cfg = base_config()
    items = sim_items(2000.0, 20.0, a.ingest_seconds)
    msgs = [m for m in items if isinstance(m, can.Message)]
    batches = reader_batches(items)
    res = IngestResult(len(msgs), len(items) - len(msgs), a.ingest_seconds)
    variants: list[tuple[str, Any]] = [
        ("slipdaq, reader batches of up to 256 (to_frames -> Pipeline.process_can_batch -> McapLogSink)",
         lambda p: ingest_batched(cfg, batches, p)),
        ("slipdaq, frame by frame (to_frame -> Pipeline.process -> McapLogSink)",
         lambda p: ingest_slipdaq(cfg, items, p)),
        ("python-can can.Logger -> .blf", lambda p: ingest_logger(msgs, p)),
        ("python-can can.Logger -> .asc", lambda p: ingest_logger(msgs, p)),
    ]
    exts = ["mcap", "mcap", "blf", "asc"]
    print(f"ingest: {len(msgs):,} frames + {res.nmea} NMEA lines ({a.ingest_seconds:g} s of 4 x 2000 Hz + 20 Hz), "
          f"{a.rounds} interleaved rounds", flush=True)
    for r in range(a.rounds):
        for (name, fn), ext in zip(variants, exts):
            path = tmp / f"ingest-{r}-{len(res.rates.get(name, []))}-{abs(hash(name)) % 10000}.{ext}"
            dt = fn(path)
            res.rates.setdefault(name, []).append(len(msgs) / dt)
            res.sizes[name] = path.stat().st_size
            path.unlink()
            print(f"  round {r + 1}: {name}: {fmt_rate(len(msgs) / dt)} frames/s", flush=True)
    return res


def ingest_table(res: IngestResult) -> str:
    names = list(res.rates)
    slip = median(res.rates[names[0]])
    blf = median(res.rates[next(n for n in names if n.endswith(".blf"))])
    asc = median(res.rates[next(n for n in names if n.endswith(".asc"))])
    rows = []
    for n in names:
        m = median(res.rates[n])
        rows.append([n, fmt_rate(m), f"{min(res.rates[n]):,.0f}–{max(res.rates[n]):,.0f}", f"{m / 9000:.2f}×",
                     f"{m / blf:.3f}", f"{m / asc:.3f}", f"{res.sizes[n] / res.frames:.1f}"])
    head = (f"{res.frames:,} CAN frames ({res.seconds_of_data:g} s of 4 WPT messages × 2000 Hz) + {res.nmea} NMEA "
            f"lines (20 Hz RMC+GGA+VTG), median of {len(res.rates[names[0]])} interleaved rounds; frames/s counts CAN "
            f"frames only (python-can's loggers get no NMEA). Targets: ≥ 150,000 frames/s and ≥ the BLF logger.\n\n")
    t = table(["path", "frames/s (median)", "range", "× saturated bus (9,000/s)", "ratio to BLF", "ratio to ASC",
               "file bytes/frame"], rows)
    verdict = (f"\n\nslipdaq / BLF = {slip / blf:.3f}, slipdaq / ASC = {slip / asc:.3f}; slipdaq "
               f"{'meets' if slip >= 150000 and slip >= blf else 'misses'} the ingest target.")
    return head + t + verdict


# ---- 2. replay ----------------------------------------------------------------------------------------------
@dataclass
class ReplayResult:
    minutes: float
    frames: int
    nmea: int
    produce_s: float
    replay_s: float | None = None


def write_raw_log(cfg: Config, minutes: float, path: Path) -> tuple[int, int, float]:
    """A raw-only slipdaq log of `minutes` of 4 x 500 Hz + 20 Hz NMEA: (frames, NMEA lines, seconds to write)."""
    from slipdaq.sinks.mcap_log import McapLogSink

    t0 = time.perf_counter()
    sink = McapLogSink(path, cfg, mode="bench-raw")
    settings = replace(SimSettings(), wpt_rate_hz=500.0, gps_rate_hz=20.0, gps_latency_s=0.05, can_jitter_s=0.0002)
    frames = nmea = 0
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=minutes * 60.0):  # type: ignore[arg-type]
        r = ev.record
        if r is None:
            continue
        sink.on_raw(r)
        if isinstance(r, CanFrame):
            frames += 1
        else:
            nmea += 1
    sink.close()
    return frames, nmea, time.perf_counter() - t0


def run_replay(a: argparse.Namespace, tmp: Path) -> ReplayResult:
    from slipdaq.cli import main as slipdaq_main

    cfg = base_config()
    raw = tmp / "replay-raw.mcap"
    print(f"replay: writing a {a.replay_minutes:g}-minute raw log (4 x 500 Hz + 20 Hz NMEA)...", flush=True)
    frames, nmea, produce_s = write_raw_log(cfg, a.replay_minutes, raw)
    res = ReplayResult(a.replay_minutes, frames, nmea, produce_s)
    print(f"  {frames:,} frames, {nmea:,} NMEA lines, {raw.stat().st_size / 1e6:.1f} MB, written in {produce_s:.0f} s;"
          f" timing `slipdaq replay`...", flush=True)
    out = tmp / "replay-out.mcap"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        t0 = time.perf_counter()
        rc = slipdaq_main(["replay", str(raw), "-o", str(out)])
        res.replay_s = time.perf_counter() - t0
    if rc != 0:
        raise SystemExit(f"slipdaq replay failed with exit status {rc}")
    print(f"  slipdaq replay: {res.replay_s:.1f} s = {fmt_rate(frames / res.replay_s)} frames/s", flush=True)
    out.unlink()
    raw.unlink()
    return res


def replay_table(res: ReplayResult) -> str:
    real_s = res.minutes * 60.0
    rows = [["`slipdaq replay`", f"{res.minutes:g} min", f"{res.frames:,}",
             f"{res.replay_s:.1f} s", fmt_rate(res.frames / res.replay_s), f"{real_s / res.replay_s:.1f}×",
             f"{res.replay_s * 60 / res.minutes / 60:.1f} min"]]
    head = (f"Raw log: 4 WPT messages × 500 Hz + 20 Hz NMEA from the simulator's cycle (written in "
            f"{res.produce_s:.0f} s, not timed). Replay time includes reading, decode, estimator and writing the new "
            f"log. The last column is the measured rate expressed per hour of log (the 60-minute figure is only "
            f"measured when --replay-minutes 60). Target: ≥ 500,000 frames/s, an hour of 4 × 500 Hz in < 15 s.\n\n")
    t = table(["replay", "log", "frames", "wall time", "frames/s", "× real time", "time per hour of log"], rows)
    return head + t


# ---- latency: shared analysis -----------------------------------------------------------------------------------
@dataclass
class Latency:
    label: str
    n: int
    frame_ms: list[float]
    trigger_ms: list[float]
    released_by_nmea: int
    frames: int
    lost: int
    duration_s: float
    notes: list[str] = field(default_factory=list)

    def pct(self, xs: list[float], q: float) -> str:
        return f"{np.percentile(xs, q):.2f}" if xs else "—"


def _latency_core(items: list[tuple[float, dict[str, Any], dict[str, int], str, float]],
                  arrays: dict[str, np.ndarray]) -> tuple[list[float], list[float], int, list[str]]:
    """items: (write time, estimate fields, frames of each wheel processed before it, releasing record's kind and
    timestamp). Returns (frame -> estimate ms, releasing record -> estimate ms, released by NMEA, notes)."""
    frame_ms: list[float] = []
    trig_ms: list[float] = []
    by_nmea = skipped = 0
    for wall, d, counts, kind, t_rel in items:
        if d.get("source", "gps") != "gps":
            skipped += 1
            continue
        half = 0.5 * d["window_s"]
        lat = d.get("gps_latency_s") or 0.0
        horizon = d["time_s"] + (max(half, lat) if d.get("latency_source") != "fixed" else half)
        newest = -math.inf
        for w, arr in arrays.items():
            a = arr[:counts[w]]
            j = int(np.searchsorted(a, horizon, side="left"))
            if j < len(a):
                newest = max(newest, float(a[j]))
        if math.isfinite(newest):
            frame_ms.append((wall - newest) * 1e3)
        trig_ms.append((wall - t_rel) * 1e3)
        by_nmea += kind == "nmea"
    notes = [f"{skipped} wheel-clock estimates (GPS lost) left out"] if skipped else []
    missing = len(items) - skipped - len(frame_ms)
    if missing:
        notes.append(f"{missing} estimates were written before any frame past their window's end had been processed "
                     f"(the daemon was behind on CAN while NMEA, stamped when read, was not)")
    return frame_ms, trig_ms, by_nmea, notes


def analyse_latency(log_path: Path, probe: list[list[float]], cfg: Config) -> tuple[list[float], list[float], int,
                                                                                    int, list[str]]:
    """Per estimate: (write time - arrival of the newest CAN frame it depends on, write time - arrival of the record
    whose processing released it), in ms; see docs/performance.md for the definition."""
    from mcap.reader import make_reader

    ids = wheel_ids(cfg)
    times: dict[str, list[float]] = {w: [] for w in ids.values()}
    estimates: list[tuple[dict[str, Any], dict[str, int], tuple[str, float]]] = []
    last: tuple[str, float] = ("none", math.nan)
    batched = False
    with open(log_path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(topics=["/can/raw", "/nmea/raw", "/estimate"],
                                                      log_time_order=False):
            if ch.message_encoding == "cdr":
                batched = True
                break
            d = json.loads(m.data)
            if ch.topic == "/can/raw":
                w = ids.get(d["id"])
                if w is not None and not d["extended"]:
                    times[w].append(d["timestamp_s"])
                last = ("can", d["timestamp_s"])
            elif ch.topic == "/nmea/raw":
                last = ("nmea", d["timestamp_s"])
            else:
                estimates.append((d, {w: len(v) for w, v in times.items()}, last))
    if batched:
        times, estimates = _batched_log_estimates(log_path, ids)
    notes: list[str] = []
    if len(probe) != len(estimates):
        notes.append(f"probe saw {len(probe)} estimates, the log has {len(estimates)}: matched by order")
    items = []
    for (wall, time_s), (d, counts, (kind, t_rel)) in zip(probe, estimates):
        if d["time_s"] != time_s:
            notes.append("probe and log estimates out of step")
            break
        items.append((wall, d, counts, kind, t_rel))
    frame_ms, trig_ms, by_nmea, more = _latency_core(items, {w: np.asarray(v) for w, v in times.items()})
    return frame_ms, trig_ms, by_nmea, len(estimates), notes + more


def _batched_log_estimates(log_path: Path, ids: dict[int, str]) -> tuple[dict[str, list[float]], list[Any]]:
    """analyse_latency for the batched format: a batch may be written after an estimate its frames released, so the
    releasing record comes from the estimate's log time (the releasing record's timestamp): an NMEA line with that
    time (its can_index: the frames before it), else the CAN frame with that time."""
    from mcap.reader import make_reader

    from slipdaq.logformat.cdr import decode_can_batch

    cols: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    lines: dict[int, tuple[float, int]] = {}
    raw_estimates: list[tuple[int, dict[str, Any]]] = []
    with open(log_path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(topics=["/can/raw", "/nmea/raw", "/estimate"],
                                                      log_time_order=False):
            if ch.topic == "/can/raw":
                _first, b = decode_can_batch(m.data)
                cols.append((b.timestamp_s.copy(), b.arbitration_id.copy(), b.flags.copy()))
            elif ch.topic == "/nmea/raw":
                d = json.loads(m.data)
                lines[m.log_time] = (d["timestamp_s"], d.get("can_index", 0))
            else:
                raw_estimates.append((m.log_time, json.loads(m.data)))
    ts = np.concatenate([c[0] for c in cols]) if cols else np.empty(0)
    fid = np.concatenate([c[1] for c in cols]) if cols else np.empty(0, dtype=np.uint32)
    flags = np.concatenate([c[2] for c in cols]) if cols else np.empty(0, dtype=np.uint8)
    ns = np.maximum(np.round(ts * 1e9), 0).astype(np.int64)
    wheel_of = {w: (fid == i) & (flags == 0) for i, w in ids.items()}
    cum = {w: np.concatenate(([0], np.cumsum(sel))) for w, sel in wheel_of.items()}
    times = {w: ts[sel].tolist() for w, sel in wheel_of.items()}
    last_index: dict[int, int] = {}
    for i, v in enumerate(ns.tolist()):
        last_index[v] = i
    estimates = []
    for log_time, d in raw_estimates:
        if log_time in lines:
            t_rel, k = lines[log_time]
            kind = "nmea"
        else:
            i = last_index.get(log_time)
            if i is None:
                continue
            t_rel, k, kind = float(ts[i]), i + 1, "can"
        estimates.append((d, {w: int(c[k]) for w, c in cum.items()}, (kind, t_rel)))
    return times, estimates


def diagnostics_of(log_path: Path) -> dict[str, Any]:
    from mcap.reader import make_reader

    last: dict[str, Any] = {}
    with open(log_path, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/diagnostics"], log_time_order=False):
            last = json.loads(m.data)
    return last


class EstimateProbe:
    """Records time.time() after McapLogSink.on_estimate has handed each estimate to the MCAP writer."""

    def __init__(self) -> None:
        self.rows: list[list[float]] = []
        self._orig = None

    def __enter__(self) -> EstimateProbe:
        from slipdaq.sinks.mcap_log import McapLogSink

        orig = self._orig = McapLogSink.on_estimate
        rows = self.rows

        def on_estimate(sink, estimate, log_time_s):  # type: ignore[no-untyped-def]
            orig(sink, estimate, log_time_s)
            rows.append([time.time(), estimate.time_s])

        McapLogSink.on_estimate = on_estimate  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        from slipdaq.sinks.mcap_log import McapLogSink

        McapLogSink.on_estimate = self._orig  # type: ignore[method-assign]


# ---- 3. latency on the virtual bus, in process ----------------------------------------------------------------
def run_latency_virtual(a: argparse.Namespace, tmp: Path) -> Latency:
    from slipdaq.live.daemon import open_bus, run_daemon
    from slipdaq.live.demo import demo_config
    from slipdaq.live.simulate import PtyGps

    seconds = a.latency_seconds
    gen_estimate_s = (seconds + SKIP_S) * 4060 / 35000.0
    start = round(time.time() + 2.0 * gen_estimate_s + 2.0, 2)  # generous: generating is slower on a busy machine
    print(f"latency (virtual bus, in process): generating {seconds:g} s of 4 x 1 kHz + 20 Hz NMEA...", flush=True)
    # GPS latency 0 in the simulator: the NMEA of the epoch at a window's end arrives with the frames of that time
    items = sim_items(1000.0, 20.0, seconds, skip_s=SKIP_S, start_utc_s=start - SKIP_S, gps_latency_s=0.0)
    gps = PtyGps()
    channel = f"slipdaq-perf-{os.getpid()}"
    cfg = demo_config(gps.path, channel)
    log_path = tmp / "latency-virtual.mcap"
    notes: list[str] = []
    late = start - time.time()
    if late < 0.5:
        notes.append(f"generation ran {0.5 - late:.1f} s past the planned start: NMEA UTC off by that much")
        shift = 0.5 - late
    else:
        shift = 0.0
    sent = [0]

    def sender(bus: can.BusABC) -> None:
        t_start = start + shift
        for it in items:
            t_due = t_start + (it.timestamp if isinstance(it, can.Message) else it.timestamp_s) - (start - SKIP_S) \
                - SKIP_S
            dt = t_due - time.time()
            if dt > 0.0003:
                time.sleep(dt - 0.0001)
            if isinstance(it, can.Message):
                bus.send(can.Message(arbitration_id=it.arbitration_id, data=it.data,
                                     is_extended_id=it.is_extended_id))
                sent[0] += 1
            else:
                gps.write((it.line + "\r\n").encode("ascii"))

    async def main() -> Any:
        stop = asyncio.Event()
        with open_bus(cfg) as daemon_bus, can.Bus(interface="virtual", channel=channel) as sim_bus:
            th = threading.Thread(target=sender, args=(sim_bus,), daemon=True)

            async def stopper() -> None:
                await asyncio.sleep(max(0.0, start + shift - time.time()))
                th.start()
                await asyncio.to_thread(th.join)
                await asyncio.sleep(0.5)
                stop.set()

            task = asyncio.create_task(stopper())
            result = await run_daemon(cfg, daemon_bus, log_path, stop=stop, status_stream=io.StringIO())
            await task
            return result

    try:
        with EstimateProbe() as probe:
            result = asyncio.run(main())
    finally:
        gps.close()
    frame_ms, trig_ms, by_nmea, n, more = analyse_latency(log_path, probe.rows, cfg)
    diag = diagnostics_of(log_path)
    log_path.unlink()
    lat = Latency("`run_daemon` in process, virtual bus, sender thread, 4 × 1 kHz + 20 Hz NMEA", n, frame_ms, trig_ms, by_nmea,
                  result.can_frames, sum((diag.get("lost_frames") or {}).values()), seconds, notes + more)
    print(f"  {n} estimates; newest frame -> estimate p50 {lat.pct(frame_ms, 50)} ms, p99 {lat.pct(frame_ms, 99)} ms",
          flush=True)
    return lat


# ---- 4. CPU (and latency) of `slipdaq run` in a child process ------------------------------------------------------
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


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


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
    env["PYTHONPATH"] = os.pathsep.join([str(Path(slipdaq.__file__).resolve().parents[1]), str(HERE)] +
                                        ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    who = "`slipdaq run`"
    print(f"cpu: {label}: {who} in a child process, sender in another, {seconds:g} s...", flush=True)
    sender = subprocess.Popen(
        [py, str(HERE / "perf_bus.py"), "sender", "--port", str(port), "--nmea-fd", str(master),
         "--wpt-rate-hz", str(total_rate_hz / 4), "--gps-rate-hz", "20", "--duration", str(seconds),
         "--start-wall", str(start)], pass_fds=[master], stdout=subprocess.PIPE, text=True, env=env)
    out_file = open(work / "daemon.out", "w")
    child = ["daemon"]
    daemon = subprocess.Popen(
        [py, str(HERE / "perf_bus.py"), *child, "--config", str(cfg_path), "--log-dir", str(work / "logs"),
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


def latency_table(lats: list[Latency]) -> str:
    rows = []
    for lt in lats:
        rows.append([lt.label, f"{lt.n}", lt.pct(lt.frame_ms, 50), lt.pct(lt.frame_ms, 99),
                     f"{max(lt.frame_ms):.2f}" if lt.frame_ms else "—", lt.pct(lt.trigger_ms, 50),
                     lt.pct(lt.trigger_ms, 99), f"{100 * lt.released_by_nmea / max(lt.n, 1):.0f} %",
                     f"{lt.frames:,} / {lt.lost}"])
    t = table(["run", "estimates", "frame → estimate p50 ms", "p99 ms",
               "max ms", "releasing record → estimate p50 ms", "p99 ms", "released by NMEA", "frames / lost"], rows)
    notes = [f"- {lt.label}: {n}" for lt in lats for n in lt.notes]
    return t + ("\n\n" + "\n".join(notes) if notes else "") + "\n\nTarget: frame → estimate p99 ≤ 2 ms."


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


# ---- 5. profile -------------------------------------------------------------------------------------------------
PROFILE_RULES: list[tuple[str, tuple[str, ...]]] = [
    # by module (file path in the stack), innermost match first: no names of private functions here
    ("estimator: readiness (estimator/readiness.py kernel)", ("estimator/readiness.py",)),
    ("estimator: GPS latency (estimator/latency.py)", ("estimator/latency.py",)),
    ("estimator: samples into the rings (SeriesRing)", ("estimator/ring.py",)),
    ("estimator: window maths (gps_track, windows, force, radius, stiffness, slip)", ("estimator/",)),
    ("decode: wheel frames (can_wheels, wheel_unwrap kernel, cantools)",
     ("decode/can_wheels.py", "decode/wheel_unwrap.py", "cantools")),
    ("decode: GPS (nmea, ubx, framing, pynmea2)", ("decode/", "pynmea2")),
    ("compiled kernels: numba dispatch", ("numba", "slipdaq/compiled.py")),
    ("log: estimates, fixes, diagnostics to JSON", ("logformat/json_codec.py", "json/")),
    ("log: CDR batches (logformat/cdr.py)", ("logformat/cdr.py",)),
    ("log: mcap Writer.add_message, chunks, zstd", ("mcap/", "zstandard")),
    ("log: McapLogSink and the log writer", ("sinks/mcap_log.py", "logformat/")),
    ("pipeline (dispatch, counters, decode ahead)", ("slipdaq/pipeline.py",)),
    ("source: to_frames and records (can.Message -> CanFrameBatch columns)", ("sources/", "slipdaq/records.py")),
    ("benchmark driver loop", ("benchmarks/perf.py",)),
]


def categorise(stack: str) -> str:
    frames = stack.split(";")
    for f in reversed(frames):
        for name, pats in PROFILE_RULES:
            if any(p in f for p in pats):
                return name
    return "other"


def profile_target(seconds: float) -> None:
    """Child of the profile section: the ingest loop of the current design, under py-spy."""
    import slipdaq.pipeline  # noqa: F401  (imports outside the profiled loop)
    import slipdaq.sinks.mcap_log  # noqa: F401
    import slipdaq.sources.can_bus  # noqa: F401

    cfg = base_config()
    batches = reader_batches(sim_items(2000.0, 20.0, seconds))
    tmp = Path(tempfile.mkdtemp())

    def ingest_loop() -> None:
        ingest_batched(cfg, batches, tmp / "p.mcap")

    ingest_loop()
    shutil.rmtree(tmp, ignore_errors=True)


def run_profile(a: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    pyspy = shutil.which("py-spy") or (str(Path(sys.executable).parent / "py-spy")
                                       if (Path(sys.executable).parent / "py-spy").exists() else None)
    seconds = a.profile_seconds
    print(f"profile: ingest loop over {seconds:g} s of 4 x 2000 Hz data, "
          f"{'py-spy (sampling, 1 kHz)' if pyspy else 'cProfile (py-spy not installed)'}...", flush=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(slipdaq.__file__).resolve().parents[1]), str(HERE)] +
                                        ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if pyspy:
        raw = tmp / "pyspy.txt"
        proc = subprocess.run([pyspy, "record", "-r", "1000", "-f", "raw", "-o", str(raw), "--",
                               sys.executable, str(HERE / "perf.py"), "_profile-target", str(seconds)],
                              capture_output=True, text=True, env=env)
        if proc.returncode == 0 and raw.exists():
            counts: Counter[str] = Counter()
            total = 0
            for line in raw.read_text().splitlines():
                stack, _, n = line.rpartition(" ")
                if "ingest_loop" not in stack or any(x in stack for x in (
                        "_find_and_load", "Pipeline.__init__", "McapLogSink.__init__")):
                    continue  # imports and construction are not the ingest path
                counts[categorise(stack)] += int(n)
                total += int(n)
            raw.unlink()
            return {"tool": "py-spy 1 kHz sampling", "total": total, "counts": counts}
        print(f"  py-spy failed ({proc.stderr.strip()[-200:]}); using cProfile", flush=True)
    import cProfile
    import pstats

    cfg = base_config()
    batches = reader_batches(sim_items(2000.0, 20.0, seconds))
    pr = cProfile.Profile()
    pr.enable()
    ingest_batched(cfg, batches, tmp / "p.mcap")
    pr.disable()
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(15)
    return {"tool": "cProfile", "text": s.getvalue()}


def profile_table(prof: dict[str, Any]) -> str:
    if "counts" not in prof:
        return "```\n" + prof["text"][-4000:] + "\n```"
    total = prof["total"]
    rows = [[name, f"{100 * n / total:.1f} %"] for name, n in prof["counts"].most_common()]
    return (f"{prof['tool']}, {total:,} samples inside the ingest loop; each sample goes to the innermost frame that "
            f"matches a category (so numpy called by the estimator counts as estimator).\n\n" +
            table(["where the time goes (current design, ingest path)", "share"], rows))


# ---- main ---------------------------------------------------------------------------------------------------------
def write_doc(block: str) -> None:
    doc = ROOT / "docs" / "performance.md"
    begin, end = "<!-- perf:begin -->", "<!-- perf:end -->"
    text = doc.read_text() if doc.exists() else f"# Performance\n\n{begin}\n{end}\n"
    if begin not in text or end not in text:
        text += f"\n{begin}\n{end}\n"
    pre, rest = text.split(begin, 1)
    _, post = rest.split(end, 1)
    doc.write_text(f"{pre}{begin}\n{block}\n{end}{post}")
    print(f"wrote the tables to {doc}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_profile-target":
        profile_target(float(argv[1]))
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes, < 1 minute (a smoke run, not the figures)")
    ap.add_argument("--only", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}")
    ap.add_argument("--replay-minutes", type=float, default=None,
                    help="minutes of 4 x 500 Hz log to replay (default 60, the issue's definition; --quick 0.25)")
    ap.add_argument("--ingest-seconds", type=float, default=None, help="seconds of 4 x 2000 Hz data (default 6)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the ingest comparison (default 3)")
    ap.add_argument("--latency-seconds", type=float, default=None, help="default 20")
    ap.add_argument("--cpu-seconds", type=float, default=None, help="seconds per CPU run (default 20)")
    ap.add_argument("--profile-seconds", type=float, default=None, help="default 3")
    ap.add_argument("--read-intervals-ms", type=lambda v: [float(x) for x in v.split(",")], default=None,
                    metavar="MS,MS,...", help="cpu section: instead of its default loads, 4 x 1 kHz with each of these "
                                              "can.read_interval_s in turn (e.g. 20,0,20,0,20,50)")
    ap.add_argument("--cpu-profile", default=None, metavar="DIR",
                    help="with the cpu section: py-spy record the daemon over its sending window into DIR "
                         "(raw collapsed stacks, one file per run; the CPU share then includes py-spy's pauses)")
    ap.add_argument("--tmp-dir", default=None, help="where the logs are written (default: the system's temp dir)")
    ap.add_argument("--write", action="store_true", help="also write the tables into docs/performance.md")
    a = ap.parse_args(argv)
    q = a.quick
    a.replay_minutes = a.replay_minutes if a.replay_minutes is not None else (0.25 if q else 60.0)
    a.ingest_seconds = a.ingest_seconds if a.ingest_seconds is not None else (0.75 if q else 6.0)
    a.latency_seconds = a.latency_seconds if a.latency_seconds is not None else (3.0 if q else 20.0)
    a.cpu_seconds = a.cpu_seconds if a.cpu_seconds is not None else (4.0 if q else 20.0)
    a.profile_seconds = a.profile_seconds if a.profile_seconds is not None else (0.5 if q else 3.0)
    only = [s.strip() for s in a.only.split(",") if s.strip()]
    bad = [s for s in only if s not in SECTIONS]
    if bad:
        ap.error(f"unknown section(s) {bad}: choose from {SECTIONS}")
    started = time.time()
    load0 = os.getloadavg()
    busy0 = busy_processes()
    mach = machine()
    cmd = "python benchmarks/perf.py " + " ".join(argv)
    print(f"slipdaq performance benchmarks — {cmd.strip()}", flush=True)
    out: list[str] = []
    with tempfile.TemporaryDirectory(dir=a.tmp_dir, prefix="slipdaq-perf-") as td:
        tmp = Path(td)
        if "ingest" in only:
            ingest = run_ingest(a, tmp)
            out.append("### 1. Ingest (live path minus the driver)\n\n" + ingest_table(ingest))
        if "replay" in only:
            rep = run_replay(a, tmp)
            out.append("### 2. Replay\n\n" + replay_table(rep))
        lats: list[Latency] = []
        cpus: list[CpuResult] = []
        if "latency" in only:
            lats.append(run_latency_virtual(a, tmp))
        if "cpu" in only:
            loads = [(4000.0, "4 × 1 kHz + 20 Hz NMEA"), (9000.0, "9,000 frames/s (4 × 2250 Hz) + 20 Hz NMEA")]
            default_s = Config().can.read_interval_s
            if a.quick:
                loads = loads[:1]
            if a.read_intervals_ms:  # these intervals in turn at 4 x 1 kHz (repeats and alternations show the spread)
                for ms in a.read_intervals_ms:
                    cpus.append(run_cpu(a, tmp, 4000.0, f"{loads[0][1]}, read interval {ms:g} ms",
                                        read_interval_s=ms / 1e3))
            else:
                for rate, label in loads:
                    cpus.append(run_cpu(a, tmp, rate, f"{label}, read interval {default_s * 1e3:g} ms (default)"))
                if not a.quick:  # the same without pacing: every frame read as it comes
                    for rate, label in loads:
                        cpus.append(run_cpu(a, tmp, rate, f"{label}, read interval 0 (every frame)",
                                            read_interval_s=0.0))
            lats += [c.latency for c in cpus if c.latency is not None]
        if lats:
            out.append("### 3. Latency\n\n" + latency_table(lats))
        if cpus:
            out.append("### 4. CPU of `slipdaq run`\n\n" + cpu_table(cpus))
        if "profile" in only:
            out.append("### 5. Profile of the ingest path\n\n" + profile_table(run_profile(a, tmp)))
    elapsed = time.time() - started
    load1 = os.getloadavg()
    head = ("**Machine.** " + "; ".join(f"{k}: {v}" for k, v in mach.items() if v) +
            f".\n\n**Command.** `{cmd.strip()}` — {elapsed / 60:.1f} min, run "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n\n**Load.** 1-minute load average "
            f"{load0[0]:.2f} at the start, {load1[0]:.2f} at the end, on {os.cpu_count()} CPUs" +
            (f"; other processes busy at the start: {busy0}" if busy0 else "") + ".")
    block = head + "\n\n" + "\n\n".join(out)
    print("\n" + block)
    if a.write:
        write_doc(block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
