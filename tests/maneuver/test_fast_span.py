"""The high-rate rows a maneuver takes, as columns: the estimator's batches, its records and a log's dicts give the same
arrays, bit for bit; a span holds the rows inside its bounds; rows let go are gone."""

from __future__ import annotations

import math
import random
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.maneuver.detector import ManeuverDetector
from slipdaq.maneuver.fast_span import FastRowsHeld, FastSpan
from slipdaq.records.fast_rows import FastSlipBatch


def _batches(n_fixes: int, seed: int = 3) -> list[FastSlipBatch]:
    """n_fixes batches of 1-6 rows, every wheel, some slips undefined."""
    rng = random.Random(seed)
    out, t = [], 100.0
    for _ in range(n_fixes):
        k = rng.randint(1, 6)
        times = [t + 0.01 * i + rng.random() * 1e-3 for i in range(k)]
        t = times[-1] + 0.01
        out.append(FastSlipBatch(times, [rng.uniform(0, 30) for _ in range(k)], [rng.gauss(0, 3) for _ in range(k)],
                                 [rng.choice(("imu", "gps")) for _ in range(k)], WHEELS,
                                 {w: [None if rng.random() < 0.2 else rng.gauss(0, 0.1) for _ in range(k)]
                                  for w in WHEELS},
                                 {w: [rng.uniform(0, 30) for _ in range(k)] for w in WHEELS}))
    return out


def _same(a: FastSpan, b: FastSpan) -> None:
    for x, y in [(a.time_s, b.time_s), (a.speed_mps, b.speed_mps), (a.accel_mps2, b.accel_mps2),
                 *((a.slips[w], b.slips[w]) for w in WHEELS)]:
        assert x.dtype == y.dtype == np.float64
        assert x.tobytes() == y.tobytes()


def test_batches_records_and_dicts_make_the_same_columns() -> None:
    batches = _batches(300)
    from_batches = FastRowsHeld()
    for b in batches:
        from_batches.add(b)
    records = [r for b in batches for r in b]
    dicts = [d for b in batches for d in b.dicts()]
    span = from_batches.span()
    assert len(span) == len(records) > 900
    _same(span, FastSpan.of(records))
    _same(span, FastSpan.of(dicts))
    # the values, as the records hold them (None: NaN)
    assert span.time_s.tolist() == [r.time_s for r in records]
    for w in WHEELS:
        assert [None if math.isnan(x) else x for x in span.slips[w].tolist()] == [r.wheels[w].slip for r in records]
    assert np.isnan(span.slips["FL"]).any()


def test_a_wheel_a_batch_lacks_is_undefined() -> None:
    held = FastRowsHeld()
    held.add(FastSlipBatch([1.0, 2.0], [5.0, 6.0], [0.0, 0.1], ["gps", "gps"], ("FL",), {"FL": [0.01, None]},
                           {"FL": [5.0, 6.0]}))
    span = held.span()
    assert span.slips["FL"][0] == 0.01 and math.isnan(span.slips["FL"][1])
    assert all(np.isnan(span.slips[w]).all() for w in WHEELS if w != "FL")


def test_a_span_holds_the_rows_inside_its_bounds_and_rows_let_go_are_gone() -> None:
    held = FastRowsHeld()
    for b in _batches(200):
        held.add(b)
    t = held.span().time_s
    lo, hi = float(t[100]), float(t[400])
    span = held.span(lo, hi)  # both bounds inside
    assert span.time_s[0] == lo and span.time_s[-1] == hi and len(span) == 301
    last = held.last_s
    held.drop_before(float(t[250]))
    assert held.span().time_s[0] == t[250] and len(held) == len(t) - 250
    held.drop_before(math.inf)
    assert len(held) == 0 and len(held.span()) == 0
    assert held.last_s == last  # the newest row's time is kept


def test_the_detector_decides_the_same_from_batches_as_from_their_rows() -> None:
    """A detector fed the estimator's batches decides the same maneuvers, with the same high-rate columns, as one fed
    the same rows as dicts one by one."""
    batches = _batches(2000, seed=5)
    by_batch, by_row = ManeuverDetector(None), ManeuverDetector(None)
    jobs_a, jobs_b = [], []
    rng = random.Random(1)
    phases = ["cruise"] * 30 + ["accelerate"] * 40 + ["cruise"] * 30 + ["brake"] * 40
    for k, b in enumerate(batches):
        if k % 5 == 0:  # an estimate row at 4 Hz of fixes
            row = {"time_s": b.time_s[0], "speed_mps": b.speed_mps[0], "phase": phases[(k // 5) % len(phases)],
                   "window_s": 0.5} | {f"slip_{w}": rng.gauss(0.02, 0.01) for w in WHEELS} \
                | {f"force_{w}_n": rng.gauss(500, 50) for w in WHEELS}
            jobs_a += by_batch.add_estimate(row)
            jobs_b += by_row.add_estimate(dict(row))
        jobs_a += by_batch.add_fast(b)
        for d in b.dicts():
            jobs_b += by_row.add_fast([d])
    jobs_a += by_batch.finish()
    jobs_b += by_row.finish()
    assert len(jobs_a) == len(jobs_b) >= 4
    for a, b in zip(jobs_a, jobs_b):
        assert a.phase == b.phase and len(a.fast) > 10
        _same(a.fast, b.fast)


def test_a_part_of_a_batch_is_its_rows() -> None:
    b = max(_batches(50), key=len)
    assert len(b) >= 4
    assert b.part(0, len(b)) is b
    assert [r.as_row() for r in b.part(1, 3)] == [r.as_row() for r in list(b)[1:3]]
    assert len(b.part(2, 2)) == 0


def test_the_time_order_feed_decides_the_same_as_it_comes_as_at_the_end() -> None:
    """Rows given to a TimeOrderFeed as a run makes them, taken at log times along the way, decide the same maneuvers
    as all of them taken at the end, and as a detector fed them one by one in heapq.merge's order (an estimate row
    before a high-rate row of the same time)."""
    import heapq

    from slipdaq.maneuver.detector import TimeOrderFeed

    batches = _batches(2000, seed=7)
    rng = random.Random(2)
    phases = ["cruise"] * 30 + ["accelerate"] * 40 + ["cruise"] * 30 + ["brake"] * 40
    rows = []
    for k, b in enumerate(batches):
        if k % 5 == 0:
            t = b.time_s[2] if len(b) > 2 and k % 10 == 0 else b.time_s[0]  # some on a high-rate row's time
            rows.append({"time_s": t, "speed_mps": 10.0, "phase": phases[(k // 5) % len(phases)], "window_s": 0.5}
                        | {f"slip_{w}": rng.gauss(0.02, 0.01) for w in WHEELS}
                        | {f"force_{w}_n": rng.gauss(500, 50) for w in WHEELS})
    as_it_comes, at_end = TimeOrderFeed(ManeuverDetector(None)), TimeOrderFeed(ManeuverDetector(None))
    got_streamed, row_at = [], 0
    for k, b in enumerate(batches):
        while row_at < len(rows) and rows[row_at]["time_s"] <= b.time_s[-1]:
            as_it_comes.estimate(rows[row_at])
            at_end.estimate(rows[row_at])
            row_at += 1
        as_it_comes.fast(b)
        at_end.fast(b)
        if k % 37 == 0:
            got_streamed += as_it_comes.take(b.time_s[-1] - 1.0)
    got_streamed += as_it_comes.take(final=True) + as_it_comes.detector.finish()
    got_at_end = at_end.take(final=True) + at_end.detector.finish()
    one_by_one = ManeuverDetector(None)
    dicts = [d for b in batches for d in b.dicts()]
    got_one_by_one = []
    for _t, kind, i in heapq.merge(((r["time_s"], 0, i) for i, r in enumerate(rows)),
                                   ((d["time_s"], 1, i) for i, d in enumerate(dicts))):
        got_one_by_one += one_by_one.add_estimate(rows[i]) if kind == 0 else one_by_one.add_fast([dicts[i]])
    got_one_by_one += one_by_one.finish()
    assert len(got_streamed) == len(got_at_end) == len(got_one_by_one) >= 4
    for a, b, c in zip(got_streamed, got_at_end, got_one_by_one):
        assert a.phase == b.phase == c.phase and a.rows == b.rows == c.rows
        _same(a.fast, b.fast)
        _same(a.fast, c.fast)


def test_detect_maneuvers_over_a_logs_rows_in_chunks_is_the_detector_fed_one_by_one(monkeypatch) -> None:
    """report.summary.detect_maneuvers feeds the high-rate rows a chunk at a time as the estimate rows need them: the
    maneuvers are those of a detector fed every row in turn in heapq.merge's order, summarized as decided; for a
    log's rows (dicts) and for a run's columns (FastRows)."""
    import heapq

    from slipdaq.config import TestConfig
    from slipdaq.maneuver.record import maneuver_record
    from slipdaq.records.fast_rows import FastRows
    from slipdaq.report import summary

    monkeypatch.setattr(FastRows, "CHUNK", 97)  # many chunks, their ends anywhere between the estimate rows
    batches = _batches(1200, seed=11)
    rng = random.Random(4)
    phases = ["cruise"] * 25 + ["accelerate"] * 30 + ["cruise"] * 25 + ["brake"] * 30
    rows = [{"time_s": b.time_s[0], "speed_mps": 12.0, "phase": phases[(k // 4) % len(phases)], "window_s": 0.5,
             "gps_latency_s": 0.05} | {f"slip_{w}": rng.gauss(0.02, 0.01) for w in WHEELS}
            | {f"force_{w}_n": rng.gauss(500, 50) for w in WHEELS} for k, b in enumerate(batches) if k % 4 == 0]
    dicts = [d for b in batches for d in b.dicts()]
    one_by_one = ManeuverDetector(None, phases=summary.PHASES)
    expected = []
    for _t, kind, i in heapq.merge(((r["time_s"], 0, i) for i, r in enumerate(rows)),
                                   ((d["time_s"], 1, i) for i, d in enumerate(dicts))):
        jobs = one_by_one.add_estimate(rows[i]) if kind == 0 else one_by_one.add_fast([dicts[i]])
        expected += [job() for job in jobs]
    expected += [job() for job in one_by_one.finish()]
    columns = FastRows()
    for b in batches:
        columns.add(b)

    def records(found: list[Any]) -> list[Any]:
        return [(m.phase, m.t_start_s, m.t_end_s) if m.phase == "cruise" else maneuver_record(m, k, TestConfig(), WHEELS)
                for k, m in enumerate(found, 1)]

    assert len(expected) >= 6
    assert records(summary.detect_maneuvers(rows, None, fast=dicts)) == records(expected)
    assert records(summary.detect_maneuvers(rows, None, fast=columns)) == records(expected)
