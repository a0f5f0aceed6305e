#!/usr/bin/env python3
"""The fleet's cost per log: `fleet.process_log` (one Dask task: two-pass, summary, the report's plots, Parquet) for
one drive, this tree against a base revision (and --also others), side by side in one run. Figures for
docs/performance.md.

One log (the simulator's `cycle` on paved, --seconds long) is made once by the base revision's code (so that all can
read it). Then one worker process per revision, each warmed up by one task (imports, numba's kernels), runs the task
in turns: per round each once, the next round in the reverse order (interleaved, so that a busy spell of the machine
falls on all). The table shows the medians; this tree's task is also broken down into its
parts (one extra run each, in its worker). `matplotlib` says whether the task imported it.

    python -m benchmarks.report_cost --base 71b87b2 [--also HEAD] [--seconds 15] [--rounds 9] [--write]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

from benchmarks.base_revision import ROOT, add_base_argument, resolve, unpack
from benchmarks.doc_block import machine, write_block

DOC = ROOT / "docs" / "performance.md"
BEGIN, END = "<!-- report-cost:begin -->", "<!-- report-cost:end -->"

MAKE_LOG = """
import os, sys
from pathlib import Path
from slipdaq.config import load_config, packaged_config_path
from slipdaq.offline.run import process_to_log
from slipdaq.report.labels import labels_metadata
from slipdaq.sim.emit import SimSettings, generate
cfg = load_config(packaged_config_path())
records = (ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(seed=1), duration_s=float(sys.argv[2]))
           if ev.record is not None)
with open(os.devnull, "w") as quiet:
    process_to_log(cfg, records, Path(sys.argv[1]), "import", stream=quiet, metadata=labels_metadata({"road": "paved"}))
"""

WORKER = """
import io, json, os, sys, time
from pathlib import Path
from slipdaq.fleet.batch import Job, process_log
log = sys.argv[1]
job = Job(log, "drive", "0" * 16, os.path.abspath(log))
r = process_log(job)
assert r.error is None, r.error

def parts():
    from slipdaq.report.build import read_log
    from slipdaq.report.labels import labels_of
    from slipdaq.report.page_data import log_page
    from slipdaq.report.summary import summarize_log
    from slipdaq.export.parquet_file import write_parquet
    t = [time.perf_counter()]
    data = read_log(log, two_pass=True, progress=io.StringIO()); t.append(time.perf_counter())
    s = summarize_log(data.rows, data.metadata, data.diagnostics, path=log, name="drive", labels=labels_of(data.metadata),
                      fast=data.fast, sensors=data.sensors); t.append(time.perf_counter())
    log_page(s, data.fast); t.append(time.perf_counter())
    write_parquet(data.rows, Path(os.environ["OUT"]) / "x.parquet", log_name="drive", labels={}); t.append(time.perf_counter())
    return dict(zip(("two-pass estimation (read_log)", "summary (maneuvers)", "page plots (log_page)", "Parquet"),
                    (b - a for a, b in zip(t, t[1:]))))

print(json.dumps({"ready": True}), flush=True)
for line in sys.stdin:
    if line.strip() == "parts":
        print(json.dumps({"parts": parts()}), flush=True)
        continue
    t0 = time.perf_counter()
    r = process_log(job)
    dt = time.perf_counter() - t0
    assert r.error is None, r.error
    print(json.dumps({"s": dt, "matplotlib": "matplotlib" in sys.modules}), flush=True)
"""


class Worker:
    def __init__(self, src: Path, log: Path, work: Path, numba_cache: Path) -> None:
        env = os.environ | {"PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(numba_cache), "PYTHONDONTWRITEBYTECODE": "1",
                            "OUT": str(work)}
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER, str(log)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, env=env)
        assert json.loads(self._line())["ready"]

    def _line(self) -> str:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("worker died")
        return line

    def ask(self, what: str) -> dict:
        assert self.proc.stdin is not None
        self.proc.stdin.write(what + "\n")
        self.proc.stdin.flush()
        return json.loads(self._line())

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--also", action="append", default=[], metavar="REV", help="another revision to time (repeatable)")
    ap.add_argument("--seconds", type=float, default=15.0, help="the drive's length (default 15)")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--write", action="store_true", help=f"put the table into {DOC.name}")
    a = ap.parse_args()
    base = resolve(a.base)
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          check=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "src"], capture_output=True, text=True,
                           check=True).stdout.strip()
    this = f"{head}{' + working tree' if dirty else ''}"
    with tempfile.TemporaryDirectory(prefix="slipdaq-report-cost-") as tmp:
        work = Path(tmp)
        base_src = unpack(base, work / "base")
        log = work / "drive.mcap"
        env = os.environ | {"PYTHONPATH": str(base_src), "NUMBA_CACHE_DIR": str(work / "numba-base"),
                            "PYTHONDONTWRITEBYTECODE": "1"}
        subprocess.run([sys.executable, "-c", MAKE_LOG, str(log), str(a.seconds)], check=True, env=env)
        names = {"base": f"base {base} (PNGs, matplotlib)"}
        sides = {"base": Worker(base_src, log, work, work / "numba-base")}
        for i, rev in enumerate(a.also):
            short = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], capture_output=True,
                                   text=True, check=True).stdout.strip()
            names[f"also{i}"] = f"{rev} {short} (as committed)"
            sides[f"also{i}"] = Worker(unpack(short, work / f"also{i}"), log, work, work / f"numba-also{i}")
        names["this"] = f"this tree {this} (plots drawn in the browser)"
        sides["this"] = Worker(ROOT / "src", log, work, work / "numba-this")
        times: dict[str, list[float]] = {k: [] for k in sides}
        mpl: dict[str, bool] = {}
        try:
            for r in range(a.rounds):
                for k in (list(sides) if r % 2 == 0 else list(sides)[::-1]):
                    got = sides[k].ask("run")
                    times[k].append(got["s"])
                    mpl[k] = got["matplotlib"]
                print(f"round {r + 1}: " + ", ".join(f"{k} {v[-1]:.3f} s" for k, v in times.items()), flush=True)
            parts = sides["this"].ask("parts")["parts"]
        finally:
            for w in sides.values():
                w.close()
    med = {k: statistics.median(v) for k, v in times.items()}
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    def per_round(k: str) -> str:
        r = [b / x for b, x in zip(times["base"], times[k])]
        return f"{statistics.median(r):.2f}× ({min(r):.2f}–{max(r):.2f})"

    rows = [f"| {name} | {med[k]:.3f} s | {min(times[k]):.3f}–{max(times[k]):.3f} s | {med['base'] / med[k]:.2f}× | "
            f"{per_round(k)} | {'yes' if mpl[k] else 'no'} |" for k, name in names.items()]
    also = "".join(f" --also {rev}" for rev in a.also)
    block = textwrap.dedent(f"""\
        **Run.** `python -m benchmarks.report_cost --base {base}{also} --seconds {a.seconds:g} --rounds {a.rounds} --write` —
        {when}; one {a.seconds:g} s drive (`cycle`, paved), `fleet.process_log` in a warm worker per revision,
        interleaved; {machine()}.

        | `fleet.process_log`, one log | median | range | base ÷ it (medians) | base ÷ it per round | imports matplotlib |
        |---|---:|---:|---:|---:|---|
        """) + "\n".join(rows) + "\n\nThis tree's task by part (one run):\n\n| part | time |\n|---|---:|\n" + "\n".join(
        f"| {k} | {v * 1000:.0f} ms |" for k, v in parts.items())
    print(block)
    if a.write:
        write_block(DOC, BEGIN, END, "The fleet's cost per log", block)
        print(f"written to {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
