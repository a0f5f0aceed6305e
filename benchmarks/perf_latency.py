"""Latency: frame to estimate, run_daemon on python-can's virtual bus; p50/p99."""

from __future__ import annotations

import argparse
import asyncio
import io
import json
import math
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from benchmarks.perf_common import SKIP_S, diagnostics_of, sim_items, table, wheel_ids
from slipdaq.config import Config


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
