#!/usr/bin/env python3
"""The maneuvers' summaries of a replay in a second process (offline.summaries) against at once, in one process
(imports and kernels warm), interleaved rounds: wall time, the main thread's CPU time (what the wall time comes to
when the second core is free), the whole process's CPU time and the summary process's; and the start of the second
process alone (fork, one job, stop). The two logs written are compared byte for byte (the run's time excepted).

--report: `slipdaq report`'s make_report of the log two-pass instead, its maneuvers decided and summarized beside the
second pass (DetectorFeed) against after it (summaries.MIN_RAW_RECORDS set past the log's count); the reports'
summary.json compared (its time of generation excepted).

    python -m benchmarks.summary_process RAW [--rounds 5] [--report]

RAW: a raw log (`python -m benchmarks.replay_process` and `benchmarks.report_long` write one into --work).
"""

from __future__ import annotations

import argparse
import io
import json
import resource
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path


def _cpu(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw", type=Path)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--report", action="store_true", help="make_report two-pass, not replay")
    a = ap.parse_args()

    import gc

    from slipdaq import compiled
    from slipdaq.logformat.reader import config_from_log, iter_raw_batches
    from slipdaq.offline import summaries
    from slipdaq.offline.run import process
    from slipdaq.offline.summaries import SummaryProcess
    from slipdaq.report.build import make_report
    from slipdaq.sinks.mcap_log import McapLogSink

    compiled.prepare()
    gc.freeze()
    config = config_from_log(a.raw)
    out = Path(tempfile.mkdtemp(prefix="summary-process-"))
    meta = {"created_utc": "-"}
    least = summaries.MIN_RAW_RECORDS

    def run(beside: bool) -> tuple[float, float, float, float]:
        path = out / ("beside.mcap" if beside else "at-once.mcap")
        w0, m0, s0, c0 = time.perf_counter(), time.thread_time(), _cpu(resource.RUSAGE_SELF), \
            _cpu(resource.RUSAGE_CHILDREN)
        if a.report:
            summaries.MIN_RAW_RECORDS = least if beside else 10**12
            make_report([a.raw], path.with_suffix(""), two_pass=True, summaries_beside=True)
        else:
            with SummaryProcess() if beside else _Nothing() as process_:
                sink = McapLogSink(path, config, mode="replay", metadata=meta)
                try:
                    process(config, iter_raw_batches(a.raw), [sink], stream=io.StringIO(), summaries=process_)
                finally:
                    sink.close()
        return (time.perf_counter() - w0, time.thread_time() - m0, _cpu(resource.RUSAGE_SELF) - s0,
                _cpu(resource.RUSAGE_CHILDREN) - c0)

    run(False)
    got: dict[bool, list[tuple[float, float, float, float]]] = {False: [], True: []}
    for r in range(a.rounds):
        for beside in ((False, True) if r % 2 == 0 else (True, False)):
            got[beside].append(run(beside))
            w, m, s, c = got[beside][-1]
            print(f"  round {r + 1} {'beside' if beside else 'at once'}: {w:.2f} s wall, main thread {m:.2f} s, "
                  f"process {s:.2f} s, summary process {c:.2f} s", flush=True)
    if a.report:
        same = _summary(out / "beside") == _summary(out / "at-once")
    else:
        same = (out / "beside.mcap").read_bytes() == (out / "at-once.mcap").read_bytes()
    starts = []
    for _ in range(7):
        w0, s0, c0 = time.perf_counter(), _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
        with SummaryProcess() as sp:
            sp.submit(int, 1).result()
        starts.append((time.perf_counter() - w0, _cpu(resource.RUSAGE_SELF) - s0 + _cpu(resource.RUSAGE_CHILDREN) - c0))
    what = "report" if a.report else "replay"
    print(f"\n{what} of {a.raw.name} in process, {a.rounds} interleaved rounds, medians; threads at the end: "
          f"{threading.active_count()}\n")
    print("| summaries | wall | main thread CPU | process CPU | summary process CPU | all CPU |\n|---|---:|---:|---:|---:|---:|")
    for beside, rows in got.items():
        med = [statistics.median(x[i] for x in rows) for i in range(4)]
        print(f"| {'in a second process' if beside else 'at once'} | {med[0]:.2f} s | {med[1]:.2f} s | {med[2]:.2f} s "
              f"| {med[3]:.2f} s | {med[2] + med[3]:.2f} s |")
    print(f"\nthe {'reports' if a.report else 'logs'} the same: {same}")
    print(f"second process started, one job, stopped: {1e3 * statistics.median(w for w, _ in starts):.1f} ms wall, "
          f"{1e3 * statistics.median(c for _, c in starts):.1f} ms CPU (medians of 7)")
    shutil.rmtree(out)
    return 0 if same else 1


def _summary(report: Path) -> dict[str, object]:
    js = json.loads((report / "summary.json").read_bytes())
    js.pop("generated_utc")
    return js  # type: ignore[no-any-return]


class _Nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


if __name__ == "__main__":
    sys.exit(main())
