#!/usr/bin/env python3
"""Replay (and import) output identity: a base revision against this tree, file for file.

Raw logs that exercise the replay path are written once (by the base's code): the benchmark's 4 x 500 Hz log, the
drives of perf_epoch.py's --check (latency auto and fixed, grade, UBX velocity, GPS lost and back, NMEA jitter and
RMC gaps, epochs out of order, CAN jitter), a drive with CAN faults (Seq gaps, a counter node reset, counts wrapping
at 2^32, error, extended, unknown, short and CAN FD frames, a wheel silent for a while, samples out of order), the
same drive in the old per-frame JSON format, an unfinished (torn) copy, and the RAV4 drive of tests/data imported
(wheel-speed signals: the cantools path). The live logs are written with CAN frames batched at random sizes.

Each log is then replayed by both sides (`python -m slipdaq replay`, the base from `git archive BASE src` on
PYTHONPATH) and the two output files are compared byte for byte, except the value of the `created_utc` metadata
key (the wall-clock time of the run: the only part that legitimately differs; it has the same length, so every
other byte, offset and CRC of the summary must match). The RAV4 import (`slipdaq import`) is compared the same way.
On a difference, the first differing message (topic, log time, bytes) is shown. --values: where the bytes differ (an
encoding changed on purpose), the messages' decoded values are compared instead: each at the same log time and in
the same order, floats bit for bit, /slip/fast row by row however its rows are cut into messages. Also checked: the replay's
estimates, fixes, wheel samples and diagnostics equal those the live pipeline logged when it wrote the input
(live = replay, whatever the batching).

    python -m benchmarks.replay_check [--base REV] [--work /tmp/replay-check] [--quick] [--values]

REV defaults to the merge base of HEAD with main.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import random
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.base_revision import add_base_argument, resolve, under, unpack

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "benchmarks"
RAV4 = ROOT / "tests" / "data" / "rav4-comma2k19"
EXCLUDED_METADATA = ("created_utc",)
"""Metadata keys whose value names the time of the run (not compared; same length, so the file offsets agree)."""


# ---- inputs (run under the base's code) ----------------------------------------------------------

def _write_live(path: Path, cfg: Any, records: list[Any], seed: int) -> None:
    """records through the pipeline into a log as a live run writes it, CAN frames in batches of random sizes."""
    from slipdaq.pipeline import Pipeline
    from slipdaq.records import CanFrame
    from slipdaq.sinks.mcap_log import McapLogSink

    rng = random.Random(seed)
    sink = McapLogSink(path, cfg, mode="live")
    p = Pipeline(cfg, [sink])
    run: list[Any] = []
    limit = rng.choice((1, 5, 60, 300))
    for r in records + [None]:
        if isinstance(r, CanFrame):
            run.append(r)
            if len(run) < limit:
                continue
        if run:
            p.process_can_batch(run)
            run = []
            limit = rng.choice((1, 5, 60, 300, 1000))
        if r is not None and not isinstance(r, CanFrame):
            p.process(r)
    p.finish()
    sink.close()


def _records_of(case: dict[str, Any]) -> list[Any]:
    from slipdaq.records import CanFrame, NmeaLine, UbxFrame

    out: list[Any] = []
    for rec in case["records"]:
        if rec[0] == "c":
            out.append(CanFrame(rec[1], rec[2], rec[3], rec[4]))
        elif rec[0] == "n":
            out.append(NmeaLine(rec[1], rec[2]))
        else:
            out.append(UbxFrame(rec[1], rec[2]))
    return out


def _faults(records: list[Any]) -> list[Any]:
    """Seq gaps, an FL counter node reset, error / extended / unknown / short / CAN FD frames, RR silent for 2 s,
    a few samples out of order."""
    import struct

    from slipdaq.records import CanFrame

    out: list[Any] = []
    t0 = next(r.timestamp_s for r in records if isinstance(r, CanFrame))
    base: tuple[int, int] | None = None
    for k, r in enumerate(records):
        if isinstance(r, CanFrame):
            t = r.timestamp_s - t0
            if r.arbitration_id == 0x311 and 4.0 <= t < 9.0 and k % 7 == 0:
                continue  # FR: Seq gaps
            if r.arbitration_id == 0x313 and 12.0 <= t < 14.0:
                continue  # RR silent
            if r.arbitration_id == 0x310 and t >= 16.0:  # FL node reset at 16 s: counts and Seq start again
                count, seq = struct.unpack_from("<I", r.data)[0], r.data[7]
                base = base or (count, seq)
                r = CanFrame(r.timestamp_s, 0x310, struct.pack("<I3xB", (count - base[0]) % 2**32,
                                                              (seq - base[1]) % 256))
            if k % 613 == 0 and r.arbitration_id == 0x312:
                r = CanFrame(r.timestamp_s - 0.03, r.arbitration_id, r.data)  # out of order
            if k % 907 == 0 and r.arbitration_id == 0x310:
                r = CanFrame(r.timestamp_s, r.arbitration_id, r.data[:5])  # short: a bad frame
            out.append(r)
            if k % 97 == 0:
                out.append(CanFrame(r.timestamp_s, 0x18DAF110, bytes(range(k % 65)), is_extended_id=True))
            if k % 131 == 0:
                out.append(CanFrame(r.timestamp_s, 0x20000004, bytes(8), is_extended_id=True, is_error_frame=True))
            if k % 151 == 0:
                out.append(CanFrame(r.timestamp_s, 0x7DF, b""))
        else:
            out.append(r)
    return out


def make_inputs(work: Path, quick: bool) -> None:
    from benchmarks import perf_common, perf_epoch, perf_replay
    from slipdaq.config import load_config, packaged_config_path
    perf_replay.write_raw_log(perf_common.base_config(), 0.5 if quick else 1.0, work / "in-perf-raw.mcap")
    cases = perf_epoch.CHECK_CASES[:3] + perf_epoch.CHECK_CASES[5:6] if quick else perf_epoch.CHECK_CASES
    for k, (name, overrides, settings, scenario, road, seconds, edit) in enumerate(cases):
        tmp = work / f"case{k}.pkl"
        perf_epoch.make_records(min(seconds, 20 if quick else 45), tmp, overrides, settings, scenario, road, edit)
        case = pickle.loads(tmp.read_bytes())
        tmp.unlink()
        cfg = load_config(packaged_config_path()).with_overrides(**case["overrides"])
        _write_live(work / f"in-drive{k}.mcap", cfg, _records_of(case), seed=k)
        print(f"  in-drive{k}.mcap: {name}", flush=True)
    tmp = work / "faults.pkl"
    perf_epoch.make_records(24, tmp, {}, {"wpt_rate_hz": 250.0, "gps_rate_hz": 10.0, "gps_latency_s": 0.05,
                                          "start_count": 2**32 - 3000}, "cycle", "paved", "gap")
    cfg = load_config(packaged_config_path())
    records = _faults(_records_of(pickle.loads(tmp.read_bytes())))
    tmp.unlink()
    _write_live(work / "in-faults.mcap", cfg, records, seed=99)
    from tools.legacy_log import write_old_format_log  # the old format's writer (runs under the base's slipdaq here)

    write_old_format_log(work / "in-old-format.mcap", cfg, records)
    data = (work / "in-faults.mcap").read_bytes()
    (work / "in-torn.mcap").write_bytes(data[: int(len(data) * 0.6)])


# ---- comparing ----------------------------------------------------------------------------------

def _mask(data: bytes, value: str) -> bytes:
    v = value.encode()
    assert data.count(v) >= 1, "created_utc value not found"  # in each copy of the slipdaq record
    return data.replace(v, b"X" * len(v))


def _messages(path: Path) -> list[tuple[str, int, int, int, bytes]]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time, m.sequence, m.data)
                for _s, c, m in make_reader(f).iter_messages(log_time_order=False)]


def _metadata(path: Path) -> dict[str, dict[str, str]]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}


def _schemas(path: Path) -> dict[str, tuple[str, bytes]]:
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return {s.name: (s.encoding, s.data) for s in summary.schemas.values()} if summary else {}


def _unordered(schema: Any) -> Any:
    """A JSON Schema with its `required` lists as sets (their order means nothing)."""
    if isinstance(schema, dict):
        return {k: frozenset(v) if k == "required" else _unordered(v) for k, v in schema.items()}
    return [_unordered(v) for v in schema] if isinstance(schema, list) else schema


def _schema_order_only(a: Path, b: Path) -> list[str] | None:
    """The schemas that differ only in the order of their keys and `required` lists (the same JSON Schema); None if
    any differs more or the files have other schemas."""
    sa, sb = _schemas(a), _schemas(b)
    if sa.keys() != sb.keys():
        return None
    out = []
    for name, (enc, data) in sa.items():
        if (enc, data) == sb[name]:
            continue
        if enc != sb[name][0] or enc != "jsonschema" or _unordered(json.loads(data)) != _unordered(json.loads(sb[name][1])):
            return None
        out.append(name)
    return out


def _exact(x: Any) -> Any:
    """A decoded JSON value with each float by its bits (NaN, infinities, -0.0 told apart)."""
    if isinstance(x, float):
        return ("float", x.hex())
    if isinstance(x, dict):
        return {k: _exact(v) for k, v in x.items()}
    return [_exact(v) for v in x] if isinstance(x, list) else x


def _values(path: Path, topics: tuple[str, ...] | None = None) -> list[tuple[str, int, Any]]:
    """(topic, log time, value) of every message in file order: JSON decoded (floats by their bits), a /slip/fast
    message of rows as its rows (each at the message's log time), CDR as its bytes."""
    from mcap.reader import make_reader

    out: list[tuple[str, int, Any]] = []
    with open(path, "rb") as f:
        for _s, c, m in make_reader(f).iter_messages(log_time_order=False):
            if topics is not None and c.topic not in topics:
                continue
            if c.message_encoding != "json":
                out.append((c.topic, m.log_time, m.data))
                continue
            d = json.loads(m.data, parse_constant=lambda name: float(name.replace("Infinity", "inf")))
            if c.topic == "/slip/fast" and isinstance(d.get("time_s"), list):
                keys = list(d)
                out += [(c.topic, m.log_time, _exact(dict(zip(keys, row)))) for row in zip(*d.values())]
            else:
                out.append((c.topic, m.log_time, _exact(d)))
    return out


def compare_values(a: Path, b: Path) -> str:
    """'' when every message decodes to the same values at the same log time, in the same order (the /slip/fast rows
    however they are cut into messages), else the first that differs."""
    va, vb = _values(a), _values(b)
    for i, (p, q) in enumerate(zip(va, vb)):
        if p != q:
            return f"value {i} differs: base {str(p)[:300]} / new {str(q)[:300]}"
    return "" if len(va) == len(vb) else f"value counts differ: {len(va)} != {len(vb)}"


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out |= _flat(v, f"{prefix}.{k}" if prefix else str(k))
    return out


def _metadata_change(ma: dict[str, Any], mb: dict[str, Any]) -> str:
    """What the new side's metadata changed: the config keys it added, removed or changed (config_toml parsed),
    and any other key."""
    import tomllib

    sa, sb = dict(ma.get("slipdaq", {})), dict(mb.get("slipdaq", {}))
    ca, cb = (_flat(tomllib.loads(s.pop("config_toml", "") or "")) for s in (sa, sb))
    parts = []
    if ca.keys() - cb.keys():
        parts.append("config keys removed: " + ", ".join(sorted(ca.keys() - cb.keys())))
    if cb.keys() - ca.keys():
        parts.append("config keys added: " + ", ".join(sorted(cb.keys() - ca.keys())))
    changed = sorted(k for k in ca.keys() & cb.keys() if ca[k] != cb[k])
    if changed:
        parts.append("config values changed: " + ", ".join(changed))
    other = sorted(k for k in sa.keys() | sb.keys() if sa.get(k) != sb.get(k))
    if other:
        parts.append("metadata keys differ: " + ", ".join(other))
    return "; ".join(parts) or "metadata equal"


def _difference(xa: list[Any], xb: list[Any], i: int) -> str:
    """Message i of two lists of (log time, value): the fields added, removed or changed where both are objects."""
    if i >= len(xa) or i >= len(xb):
        return f"{len(xa) - i} base / {len(xb) - i} new messages more"
    (ta, a), (tb, b) = xa[i], xb[i]
    if ta != tb or not (isinstance(a, dict) and isinstance(b, dict)):
        return f"base {str(xa[i])[:200]} / new {str(xb[i])[:200]}"
    added, removed = sorted(b.keys() - a.keys()), sorted(a.keys() - b.keys())
    changed = sorted(k for k in a.keys() & b.keys() if a[k] != b[k])
    return "; ".join(f"{name} {', '.join(keys)}" for name, keys in (
        ("fields added", added), ("fields removed", removed), ("fields changed", changed)) if keys)


def by_topic(a: Path, b: Path, metadata: str) -> str:
    """Each topic's decoded values, base against new: equal, differing (the first difference), only on one side."""
    va, vb = _values(a), _values(b)
    topics = sorted({v[0] for v in va} | {v[0] for v in vb})
    equal, differ, new, gone = [], [], [], []
    for topic in topics:
        xa, xb = [v[1:] for v in va if v[0] == topic], [v[1:] for v in vb if v[0] == topic]
        if not xa:
            new.append(f"{topic} ({len(xb)})")
        elif not xb:
            gone.append(f"{topic} ({len(xa)})")
        elif xa == xb:
            equal.append(f"{topic} ({len(xa)})")
        else:
            first = next((i for i, (p, q) in enumerate(zip(xa, xb)) if p != q), min(len(xa), len(xb)))
            differ.append(f"{topic} ({len(xa)} / {len(xb)}; first at {first}: {_difference(xa, xb, first)})")
    return "; ".join(f"{name}: {', '.join(items)}" for name, items in (
        ("metadata", [metadata]), ("values differ", differ), ("new topics", new), ("topics gone", gone),
        ("values equal", equal)) if items)


def compare(a: Path, b: Path, values: bool = False) -> str:
    """'' when identical (but for EXCLUDED_METADATA), "same: ..." when the messages and metadata are identical and
    a JSON Schema differs only in the order of its keys (values: or the messages' bytes differ and their decoded
    values are the same, compare_values), else what differs first."""
    ma, mb = _metadata(a), _metadata(b)
    da, db = a.read_bytes(), b.read_bytes()
    for key in EXCLUDED_METADATA:
        va, vb = ma.get("slipdaq", {}).get(key), mb.get("slipdaq", {}).get(key)
        if va is not None and vb is not None and len(va) == len(vb):
            da, db = _mask(da, va), _mask(db, vb)
    if da == db:
        return ""
    for m in (ma, mb):
        for key in EXCLUDED_METADATA:
            m.get("slipdaq", {}).pop(key, None)
    if ma != mb and values:
        return by_topic(a, b, _metadata_change(ma, mb))
    if ma != mb:
        return f"metadata differs: {ma} != {mb}"
    xa, xb = _messages(a), _messages(b)
    if values and xa != xb:
        diff = compare_values(a, b)
        topics = sorted({m[0] for m in xa + xb})
        changed = [t for t in topics if [m[4] for m in xa if m[0] == t] != [m[4] for m in xb if m[0] == t]]
        return diff or (f"same: every value equal ({len(_values(b))} messages and rows); the bytes of "
                        f"{', '.join(changed) or 'no topic'} differ")
    for i, (p, q) in enumerate(zip(xa, xb)):
        if p != q:
            return f"message {i} differs: base {p[:4]} {p[4][:200]!r} / new {q[:4]} {q[4][:200]!r}"
    if len(xa) != len(xb):
        return f"message counts differ: {len(xa)} != {len(xb)}"
    reordered = _schema_order_only(a, b)
    if reordered:
        return f"same: messages and metadata identical; JSON Schema keys in another order: {', '.join(reordered)}"
    return f"messages equal ({len(xa)}), but the files differ (chunking or summary): {len(da)} vs {len(db)} bytes"


def live_vs_replay(inp: Path, out: Path, values: bool = False) -> str:
    """The derived topics the live pipeline logged into inp against the replay's (values: decoded, _values)."""
    from collections import defaultdict

    from slipdaq.logformat.reader import is_finished

    if not is_finished(inp):
        return "n/a (unfinished input)"
    topics = ("/estimate", "/gps/fix", "/gps/location", "/wpt/count", "/diagnostics")
    got: dict[Path, dict[str, list[tuple[int, Any]]]] = {}
    for p in (inp, out):
        d: dict[str, list[tuple[int, Any]]] = defaultdict(list)
        for topic, log_time, data in (_values(p, topics) if values else
                                      ((m[0], m[1], m[4]) for m in _messages(p) if m[0] in topics)):
            d[topic].append((log_time, data))
        got[p] = d
    if not got[inp]:
        return "n/a (raw-only log)"
    topics = tuple(t for t in topics if t in got[inp])  # a derived topic newer than the input log: not compared
    bad = [t for t in topics if got[inp][t] != got[out][t]]
    return "equal " + ", ".join(f"{t} {len(got[out][t])}" for t in topics) if not bad else f"DIFFER: {bad}"


def _verdict(diff: str) -> str:
    return "identical" if not diff else diff if diff.startswith("same:") else "DIFFERENT: " + diff


def run(side: str, env: dict[str, str], args: list[str], cwd: Path) -> tuple[int, str]:
    p = subprocess.run([sys.executable, "-m", "slipdaq", *args], env=env, cwd=cwd, capture_output=True, text=True)
    return p.returncode, (p.stdout + p.stderr).replace(f"-{side}.mcap", "-SIDE.mcap")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--work", type=Path, help="directory for the logs (default: a temporary one, removed)")
    ap.add_argument("--quick", action="store_true", help="fewer and shorter drives")
    ap.add_argument("--values", action="store_true",
                    help="where the bytes differ (an encoding changed on purpose), compare the decoded values: every "
                         "message's at the same log time, /slip/fast row by row")
    ap.add_argument("--make-inputs", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.make_inputs:
        make_inputs(a.make_inputs, a.quick)
        return 0
    work = a.work or Path(tempfile.mkdtemp(prefix="replay-check-"))
    work.mkdir(parents=True, exist_ok=True)
    a.base = resolve(a.base)
    base_src = unpack(a.base, work / f"base-{a.base}")
    env_base = dict(os.environ, PYTHONPATH=str(base_src))
    env_new = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    if not list(work.glob("in-*.mcap")):
        print(f"writing the input logs with {a.base} in {work} ...", flush=True)
        cmd, env = under(base_src, __file__, "--make-inputs", str(work), *(["--quick"] if a.quick else []))
        subprocess.run(cmd, env=env, check=True)
        for side, env in (("base", env_base), ("new", env_new)):
            (work / "calibration.toml").unlink(missing_ok=True)  # each side starts cold (import saves what it learned)
            code, text = run(side, env, ["import", "--can", str(RAV4 / "rav4_bus0.candump.log"), "--nmea",
                                         str(RAV4 / "rav4_ublox.nmea"), "--config",
                                         str(ROOT / "config" / "examples" / "rav4-comma2k19.toml"),
                                         "-o", str(work / f"import-rav4-{side}.mcap"), "--no-calibration"], work)
            assert code == 0, text
        shutil.copy(work / "import-rav4-base.mcap", work / "in-rav4.mcap")
    failures = 0
    diff = compare(work / "import-rav4-base.mcap", work / "import-rav4-new.mcap", a.values)
    print(f"{'import rav4':<22} {_verdict(diff)}")
    failures += bool(diff) and not diff.startswith("same:")
    reordered = int(diff.startswith("same:"))
    for inp in sorted(work.glob("in-*.mcap")):
        outs, texts = {}, {}
        for side, env in (("base", env_base), ("new", env_new)):
            out = work / f"out-{inp.stem[3:]}-{side}.mcap"
            code, texts[side] = run(side, env, ["replay", str(inp), "-o", str(out)], work)
            assert code == 0, texts[side]
            outs[side] = out
        diff = compare(outs["base"], outs["new"], a.values)
        if texts["base"] != texts["new"]:
            diff += f" output text differs: {texts['base']!r} != {texts['new']!r}"
        lvr = live_vs_replay(inp, outs["new"], a.values)
        n = len(_messages(outs["new"]))
        print(f"replay {inp.stem[3:]:<15} {_verdict(diff)} ({n} messages);"
              f" live vs replay: {lvr}", flush=True)
        failures += bool(diff) and not diff.startswith("same:")
        reordered += diff.startswith("same:")
    print(f"{failures} DIFFERENT" if failures else "all identical" if not reordered else
          f"all identical but for {reordered} files with the same content (see 'same:' above)")
    if a.work is None:
        shutil.rmtree(work)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
