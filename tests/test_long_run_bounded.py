"""A day's run keeps what it keeps at its start: the maneuver detector's and the live pipeline's retained state
(the length of every container they hold, followed through their attributes) is the same after a long stretch of a
repeating drive as after a short one, but for containers bounded by construction (a deque with a maxlen)."""

from __future__ import annotations

import io
import math
import platform
import subprocess
import sys
from collections import deque
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import slipdaq
from slipdaq.config import load_config
from slipdaq.maneuver.detector import ANCHOR_KEYS, ANCHOR_WINDOWS, AnchorRing, ManeuverDetector, _anchor
from slipdaq.maneuver.record import Maneuver
from slipdaq.offline.run import batched, read_ahead
from slipdaq.pipeline import Pipeline
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.vehicle import speed_profile
from slipdaq.sinks.mcap_log import McapLogSink
from slipdaq.sinks.status import MANEUVERS_KEPT, StatusSink, print_maneuvers
from support.paths import CONFIG

LOG_INDEX = ".log._writer._chunk_indexes"
"""The one that grows by design: the MCAP summary's chunk index, a 207-byte record per chunk (1 MB of messages) that
the file's summary needs at its end; a log rotated by size or duration (RotationPolicy) starts a new one."""
LOG_BUFFER = ".log._writer._stream._pending"
"""Bytes written and not committed yet: bounded by the commit (every second live, every 1 MB offline)."""
LOG_CHUNK = ".log._writer._finished.indexes[]"
"""The message index of the chunk being compressed: its messages per channel, bounded by the chunk's size (1 MB)."""
_ATOMS = (str, bytes, int, float, bool, type(None), type, np.generic)


def container_sizes(root: object, depth: int = 8, items: int = 3) -> dict[str, tuple[int, bool]]:
    """path -> (largest length of a container found there, bounded by construction: a deque with a maxlen), over
    root's attributes, and the first `items` items of each container, to `depth` levels."""
    out: dict[str, tuple[int, bool]] = {}
    seen: set[int] = set()
    stack: list[tuple[str, Any, int]] = [("", root, 0)]
    while stack:
        path, o, d = stack.pop()
        if id(o) in seen or d > depth or isinstance(o, _ATOMS) or callable(o) and not hasattr(o, "__dict__"):
            continue
        seen.add(id(o))
        if isinstance(o, np.ndarray | bytearray):
            n, bounded = len(o), False
        elif isinstance(o, list | tuple | set | frozenset | deque | dict):
            n, bounded = len(o), isinstance(o, deque) and o.maxlen is not None
            for k, v in list(o.items() if isinstance(o, dict) else enumerate(o))[:items]:
                stack.append((f"{path}[{k!r}]" if isinstance(o, dict) and isinstance(k, str) else f"{path}[]", v,
                              d + 1))
        else:
            attrs = getattr(o, "__dict__", None) or {k: getattr(o, k, None)
                                                     for c in type(o).__mro__ for k in getattr(c, "__slots__", ())}
            stack.extend((f"{path}.{k}", v, d + 1) for k, v in attrs.items())
            continue
        old = out.get(path, (0, True))
        out[path] = (max(old[0], n), old[1] and bounded)
    return out


def grown(before: dict[str, tuple[int, bool]], after: dict[str, tuple[int, bool]], slack: int = 40
          ) -> dict[str, tuple[int, int]]:
    """The containers that grew by more than a quarter and `slack` entries, and are not bounded by construction."""
    return {p: (before.get(p, (0, True))[0], n) for p, (n, bounded) in after.items()
            if not bounded and n > 1.25 * before.get(p, (0, True))[0] + slack}


def _drive_rows(n: int) -> list[tuple[dict[str, Any], dict[str, float]]]:
    """n estimate rows at 10 Hz of a repeating drive (standstill, accelerate, a short cruise with a lone brake and a
    lone accelerate row of noise, cruise, brake), each with a high-rate row at its time."""
    cycle = ["standstill"] * 20 + ["accelerate"] * 60 + ["cruise"] * 7 + ["brake", "accelerate"] + \
        ["cruise"] * 30 + ["brake"] * 30
    out = []
    for i in range(n):
        t = 0.1 * i
        phase = cycle[i % len(cycle)]
        sign = {"accelerate": 1.0, "brake": -1.0}.get(phase, 0.0)
        slip = 0.0004 * ((i * 7919) % 11 - 5) + 0.02 * sign * ((i % 13) + 1) / 13
        row = {"time_s": t, "phase": phase, "speed_mps": 0.0 if phase == "standstill" else 15.0, "window_s": 0.5}
        for w in ("FL", "FR", "RL", "RR"):
            row[f"slip_{w}"] = None if phase == "standstill" else slip
            row[f"force_{w}_n"] = 1500.0 * sign * ((i % 13) + 1) / 13 + 20.0 * ((i * 31) % 7 - 3)
        out.append((row, {"time_s": t, "speed_mps": row["speed_mps"], "accel_mps2": 3.0 * sign}))
    return out


def test_the_detector_keeps_the_same_after_20000_rows_as_after_5000() -> None:
    rows = _drive_rows(20_000)
    det = ManeuverDetector(None)
    sizes = []
    decided = 0
    for i, (row, fast) in enumerate(rows, 1):
        # what a pipeline does: the decided maneuvers go, the detector keeps none of them
        decided += len(det.add_estimate(row)) + len(det.add_fast([fast]))
        if i in (5_000, 20_000):
            sizes.append(container_sizes(det))
    assert decided > 350  # accelerate, cruise, brake of each cycle: every one decided as it ends
    assert grown(*sizes) == {}


def retained_bytes(root: object) -> int:
    """sys.getsizeof of everything reachable from root through attributes and container items (a numpy array's
    data counted where it owns it)."""
    total = 0
    seen: set[int] = set()
    stack: list[Any] = [root]
    while stack:
        o = stack.pop()
        if id(o) in seen or isinstance(o, type) or callable(o) and not hasattr(o, "__dict__"):
            continue
        seen.add(id(o))
        total += sys.getsizeof(o)
        if isinstance(o, dict):
            stack.extend(o.keys())
            stack.extend(o.values())
        elif isinstance(o, list | tuple | set | frozenset | deque):
            stack.extend(o)
        elif not isinstance(o, _ATOMS + (np.ndarray, bytearray)):
            attrs = getattr(o, "__dict__", None) or {k: getattr(o, k, None)
                                                     for c in type(o).__mro__ for k in getattr(c, "__slots__", ())}
            stack.extend(attrs.values())
    return total


def test_the_detector_holds_as_many_bytes_while_its_anchors_fill_as_once_they_are_full() -> None:
    """The cruise anchors are arrays allocated once (AnchorRing): they hold the same bytes after 2 000 rows (about 490
    anchors) as after 20 000 (the latest 1000), and the whole detector the same within its open event's rows and
    high-rate rows (a deque of the rows' dicts grew by about 200 kB)."""
    rows = _drive_rows(20_000)
    det = ManeuverDetector(None)
    held = {}
    for i, (row, fast) in enumerate(rows, 1):
        det.add_estimate(row)
        det.add_fast([fast])
        if i in (2_000, 20_000):
            held[i] = (len(det._anchors), retained_bytes(det._anchors), retained_bytes(det))
    assert held[2_000][0] < ANCHOR_WINDOWS // 2 and held[20_000][0] == ANCHOR_WINDOWS
    assert held[20_000][1] == held[2_000][1]
    assert held[20_000][2] - held[2_000][2] < 100_000, held


def test_the_anchor_ring_gives_back_the_latest_rows_values() -> None:
    """AnchorRing.rows() is what the latest ANCHOR_WINDOWS rows' ANCHOR_KEYS were, value for value and bit for bit
    (None stays None, NaN stays NaN), oldest first, before and after it wraps."""
    ring, reference = AnchorRing(), deque(maxlen=ANCHOR_WINDOWS)
    rng = np.random.default_rng(3)
    for i in range(2 * ANCHOR_WINDOWS + 37):
        row = {k: float(rng.normal()) * 10 ** int(rng.integers(-12, 6)) for k in ANCHOR_KEYS} | {"time_s": 0.1 * i}
        row[ANCHOR_KEYS[i % len(ANCHOR_KEYS)]] = None
        row[ANCHOR_KEYS[(i * 7) % len(ANCHOR_KEYS)]] = math.nan if i % 5 == 0 else -0.0 if i % 5 == 1 else row.get(
            ANCHOR_KEYS[(i * 7) % len(ANCHOR_KEYS)])
        ring.add(row)
        reference.append(_anchor(row))
        if i in (10, ANCHOR_WINDOWS - 1, ANCHOR_WINDOWS, 2 * ANCHOR_WINDOWS + 36):
            got = ring.rows()
            assert len(got) == len(reference)
            assert [{k: None if v is None else np.float64(v).tobytes() for k, v in r.items()} for r in got] == \
                [{k: None if v is None else np.float64(v).tobytes() for k, v in r.items()} for r in reference]


PROBE = """
import sys
import numpy as np
from slipdaq.allocator import fix_malloc_thresholds
if sys.argv[1] == "fixed":
    assert fix_malloc_thresholds()
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096
grids = np.ones(3 << 20)  # a summary's 24 MB of model grids, freed
del grids
before = rss()
grid = np.ones(1 << 20)  # the next summary's 8 MB, freed
del grid
print(rss() - before)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's malloc")
def test_a_freed_array_goes_back_to_the_system_with_the_threshold_fixed() -> None:
    """A process of the slipdaq command (allocator.fix_malloc_thresholds) gives an 8 MB array's memory back when it
    is freed, after a 24 MB one was freed before; with glibc's dynamic threshold the resident set keeps it."""
    def kept(mode: str) -> int:
        return int(subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True,
                                  env={"PYTHONPATH": str(Path(slipdaq.__file__).parents[1]),
                                       "OPENBLAS_NUM_THREADS": "1"}).stdout)

    assert kept("fixed") < 1 << 20
    assert kept("dynamic") >= 6 << 20  # what the fixed threshold prevents


def test_the_pipeline_keeps_the_same_after_a_long_drive_as_after_a_short_one(tmp_path: Path) -> None:
    """The simulator's cycle drive (2 accelerations and 2 stops a minute) at 50 Hz per wheel into the pipeline with the
    log and the live view as sinks: every container the same size after 24 cycles (about 340 s) as after 6, but the
    log's chunk index (LOG_INDEX) and its uncommitted bytes (LOG_BUFFER, bounded by the commit)."""
    cfg = load_config(CONFIG)
    settings = replace(SimSettings(), wpt_rate_hz=50.0, gps_rate_hz=10.0, gps_latency_s=0.05, seed=5)
    log = McapLogSink(tmp_path / "long.mcap", cfg, "import")
    status = StatusSink()
    p = Pipeline(cfg, [log, status])
    sizes = []
    period_s = speed_profile("cycle", "paved").period_s
    assert period_s is not None
    marks = [6 * period_s + 3.0, 24 * period_s + 3.0]  # at the same point of the cycle
    t0 = None
    records = (e.record for e in generate(cfg, "cycle", "paved", settings, marks[-1] + 60.0) if e.record is not None)
    for run in read_ahead(batched(records)):
        p.process_all(run)
        assert p.last_time_s is not None
        t0 = p.last_time_s if t0 is None else t0
        if marks and p.last_time_s - t0 >= marks[0]:
            marks.pop(0)
            sizes.append(container_sizes(p))
    p.finish()
    log.close()
    assert p.maneuver_count >= 2 * 24  # an acceleration and a stop a cycle, decided as each ends
    assert [p for p in grown(*sizes) if not p.endswith((LOG_INDEX, LOG_BUFFER, LOG_CHUNK))] == []
    assert max(n for p, (n, _) in sizes[-1].items() if p.endswith(LOG_BUFFER)) <= 2 << 20



def test_the_live_view_keeps_the_latest_maneuvers_and_prints_each_once() -> None:
    """A day's maneuvers: the view keeps the latest MANEUVERS_KEPT and counts them all; the status stream prints
    each maneuver not printed yet once."""
    view = StatusSink()
    n = 3 * MANEUVERS_KEPT
    for i in range(1, n + 1):
        view.on_maneuver(Maneuver(i, "accelerate", 0.0, 5.0, 0.0, 60.0, None, True, (), None, None, None, None, None,
                                  None, 5.0), float(i))
    assert len(view.maneuvers) == MANEUVERS_KEPT and view.maneuvers[-1].index == n and view.maneuvers_seen == n
    view.maneuvers_printed = n - 5  # the stream has printed all but the last 5
    out = io.StringIO()
    print_maneuvers(view, out)
    print_maneuvers(view, out)
    assert [int(line.split()[1][1:]) for line in out.getvalue().splitlines()] == list(range(n - 4, n + 1))


FRAGMENTS = """
import sys
import threading
from slipdaq.allocator import fix_malloc_thresholds, release_free_memory
assert fix_malloc_thresholds()
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096
kept = []
def fill():  # 40 MB of 2 kB blocks; every 16th lives on among the freed ones
    blocks = [bytes(2000) for _ in range(20_000)]
    kept.extend(blocks[::16])
thread = threading.Thread(target=fill)  # as a live run's threads allocate
thread.start()
thread.join()
fill()
before = rss()
released = release_free_memory() if sys.argv[1] == "release" else None
print(before - rss(), released)
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's malloc")
def test_the_free_pages_among_blocks_in_use_go_back_to_the_system() -> None:
    """allocator.release_free_memory (what the live daemon calls every RELEASE_EVERY_S) gives back the free pages
    between blocks still in use, what a thread freed too; without it the resident set keeps them."""
    def run(mode: str) -> tuple[int, str]:
        out = subprocess.run([sys.executable, "-c", FRAGMENTS, mode], capture_output=True, text=True, check=True,
                             env={"PYTHONPATH": str(Path(slipdaq.__file__).parents[1])}).stdout.split()
        return int(out[0]), out[1]

    given_back, released = run("release")
    assert released == "True" and given_back >= 16 << 20  # 2 x 40 MB filled, 15/16 of it freed (25 MB measured)
    kept_back, _ = run("keep")
    assert kept_back < 4 << 20  # what the release gives back stays resident without it
