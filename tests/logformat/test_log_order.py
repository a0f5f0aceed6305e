"""Log order and schemas: every message of a log is written in log-time order (`mcap doctor --strict-message-order`'s
rule: no message has a log time earlier than one written before it), and every JSON message is valid against its
channel's JSON Schema with additionalProperties false at every level (every field the writer emits is declared, and
every field the schema lists as required is there). Checked on a live demo log and its replay, read with mcap's
reader in file order; and the order of a log does not depend on how the pipeline grouped the CAN frames."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import dataclasses
import io
import json
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from slipdaq import WHEELS
from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.live.demo import run_demo_async
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch, NmeaLine, WheelSample
from slipdaq.sinks.mcap_log import McapLogSink, samples_to_batch
from support.paths import CONFIG
from support.reliability_support import sim_records


def closed(schema: Any) -> Any:
    """A copy of a JSON Schema with additionalProperties false in every object that lists its properties."""
    schema = copy.deepcopy(schema)

    def walk(node: Any) -> None:
        if isinstance(node, dict):
            if "properties" in node:
                node["additionalProperties"] = False
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(schema)
    return schema


def check_log(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """Asserts the order and every JSON message's schema; returns (log time, data) per topic."""
    by_topic: dict[str, list[tuple[int, bytes]]] = {}
    validators: dict[int, jsonschema.protocols.Validator] = {}
    last = -1
    with open(path, "rb") as f:
        for n, (schema, channel, m) in enumerate(make_reader(f).iter_messages(log_time_order=False)):
            assert m.log_time >= last, f"message {n} ({channel.topic}) is earlier than the one before it"
            last = m.log_time
            by_topic.setdefault(channel.topic, []).append((m.log_time, m.data))
            if channel.message_encoding != "json":
                continue
            assert schema is not None and schema.encoding == "jsonschema"
            if schema.id not in validators:
                s = json.loads(schema.data)
                assert s.get("required"), f"{channel.topic}: the schema lists no required fields"
                validators[schema.id] = jsonschema.Draft202012Validator(closed(s))
            errors = [e.message for e in validators[schema.id].iter_errors(json.loads(m.data))]
            assert not errors, f"{channel.topic} message {n}: {errors[:3]}"
    return by_topic


@pytest.fixture(scope="module")
def demo_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("order")
    result, _, _ = asyncio.run(run_demo_async(6.0, "cycle", "paved", out, status_stream=io.StringIO()))
    return result.log_path


def test_a_live_log_is_in_log_time_order_and_valid_against_its_schemas(demo_log: Path, tmp_path: Path) -> None:
    live = check_log(demo_log)
    assert {"/can/raw", "/wpt/count", "/nmea/raw", "/gps/fix", "/estimate", "/diagnostics"} <= set(live)
    assert len(live["/estimate"]) > 20
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(demo_log), "-o", str(tmp_path / "replayed.mcap")]) == 0
    replayed = check_log(tmp_path / "replayed.mcap")
    for topic in ("/estimate", "/gps/fix"):  # the replay's, log time and bytes, are the live run's
        assert replayed[topic] == live[topic], topic


def _write(path: Path, records: list, sizes: list[int] | None) -> None:
    """records through the pipeline into a log: frame by frame (sizes None), or CAN frames in runs of the sizes."""
    cfg = load_config(CONFIG)
    sink = McapLogSink(path, cfg, mode="live")
    p = Pipeline(cfg, [sink])
    run: list = []
    k = 0
    for r in records + [None]:
        if sizes is not None and isinstance(r, CanFrame):
            run.append(r)
            if len(run) < sizes[k % len(sizes)]:
                continue
        if run:
            p.process_can_batch(run)
            run = []
            k += 1
        if r is not None and (sizes is None or not isinstance(r, CanFrame)):
            p.process(r)
    p.finish()
    sink.close()


def test_the_order_does_not_depend_on_how_frames_were_grouped(tmp_path: Path) -> None:
    """The same records frame by frame (as a live run reading few frames at a time) and in runs of 1 to 1000 frames
    (as a busy live run, replay or import): the same messages, log times and order, in log-time order. The GPS lines
    come 120 ms ahead of the CAN frames stamped before them (a CAN backlog, or an import whose NMEA clock is ahead),
    so the wheel frames release the estimates, inside the runs; other traffic between the wheel frames, on two
    channels; some wheel frames stamped 30 ms early (a /wpt/count batch may then end before the /can/raw batch that
    holds its frames)."""
    records = []
    for k, r in enumerate(sim_records(6.0, wpt_rate_hz=200.0)):
        if isinstance(r, CanFrame) and k % 37 == 0:  # a wheel frame stamped 30 ms early (a log's frames out of order)
            r = CanFrame(r.timestamp_s - 0.03, r.arbitration_id, r.data)
        records.append(r)
        for _ in range(k % 4):  # other traffic: /can/raw and /wpt/count batches end at different frames
            records.append(CanFrame(r.timestamp_s, 0x123 + k % 3, bytes(k % 9), channel="can1" if k % 5 else None))
    records.sort(key=lambda r: r.timestamp_s - (0.12 if isinstance(r, NmeaLine) else 0.0))
    logs = []
    for name, sizes in (("one", None), ("runs", [1, 700, 5, 60, 1000, 300, 48, 2])):
        _write(tmp_path / f"{name}.mcap", records, sizes)
        check_log(tmp_path / f"{name}.mcap")
        with open(tmp_path / f"{name}.mcap", "rb") as f:
            logs.append([(c.topic, m.log_time, m.data) for _s, c, m in make_reader(f).iter_messages(
                log_time_order=False) if c.topic != "/diagnostics/events"])
    assert sum(t == "/estimate" for t, _, _ in logs[0]) > 40 and logs[0] == logs[1]


def _sink_log(path: Path, frames: list[CanFrame], wheel_at: list[int], lines: set[int],
              cuts: set[int] | None) -> list[tuple[str, int, bytes]]:
    """frames into a log's sink with a GPS line after each frame of `lines`: frame by frame (cuts None: on_raw, then
    on_wheel for the frame's samples), or in runs (on_can_batch, on_wheel_batch) that end before each frame of cuts,
    at each line and at the end. wheel_at: the frame of each wheel sample, in order (a frame has one sample per wheel
    its wheel_at holds, at its time). The log's messages in file order."""
    samples = [WheelSample(frames[i].timestamp_s, WHEELS[wheel_at[:k].count(i)], 0.01 * k, k, float(k), None, 0)
               for k, i in enumerate(wheel_at)]
    sink = McapLogSink(path, load_config(CONFIG), mode="replay")
    start = 0
    for i, frame in enumerate(frames):
        if cuts is None:
            sink.on_raw(frame)
            for sample, at in zip(samples, wheel_at):
                if at == i:
                    sink.on_wheel(sample)
        elif i + 1 in cuts or i in lines or i == len(frames) - 1:
            mine = [k for k, at in enumerate(wheel_at) if start <= at <= i]
            sink.on_can_batch(CanFrameBatch.from_frames(frames[start : i + 1]))
            if mine:
                batch = samples_to_batch([samples[k] for k in mine])
                sink.on_wheel_batch(dataclasses.replace(batch, frame=np.array([wheel_at[k] - start for k in mine])))
            start = i + 1
        if i in lines:
            sink.on_raw(NmeaLine(frame.timestamp_s + 5e-5, "$GPGGA,*56"))
    sink.close()
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data) for _s, c, m in make_reader(f).iter_messages(log_time_order=False)]


@pytest.mark.parametrize(("n_frames", "wheel_at", "topics"), [
    # samples up to 40 ms; the /can/raw batch closes at 50 ms; the GPS line closes the /wpt/count batch
    (80, list(range(0, 41, 10)), ["/can/raw", "/wpt/count", "/can/raw", "/nmea/raw"]),
    # four wheels a frame; the first sample at 50 ms and at 100 ms closes a /wpt/count batch, the GPS line the other
    # three (samples 401-403 after 201-400: the order they closed in, not their first numbers' bytes, comes first)
    (101, [i for i in range(101) for _ in WHEELS], ["/can/raw", "/wpt/count", "/can/raw", "/wpt/count", "/wpt/count",
                                                    "/nmea/raw"]),
])
def test_a_batch_closed_by_a_gps_line_goes_where_frame_by_frame_puts_it(tmp_path: Path, n_frames: int,
                                                                        wheel_at: list[int], topics: list[str]) -> None:
    """Wheel frames among other traffic (a production car's ABS speeds) and batches that close by their span in a
    run of frames: frame by frame, a closed batch is written at the next frame, before a batch the GPS line closes
    even if that one holds earlier samples; from one batch of the same frames (an import, a replay, or a live read
    of many frames at once) the log is the same, message for message."""
    # times i ms exactly as the span rule sees them (0.001 * 50 == 0.05)
    frames = [CanFrame(0.001 * i, 0x200 if i in wheel_at else 0x123, bytes(8)) for i in range(n_frames)]
    line = {n_frames - 1}
    one = _sink_log(tmp_path / "one.mcap", frames, wheel_at, line, cuts=None)
    assert [t for t, _, _ in one] == topics
    assert _sink_log(tmp_path / "batch.mcap", frames, wheel_at, line, cuts=set()) == one


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_frames_one_by_one_and_in_any_runs_make_the_same_log(tmp_path_factory: pytest.TempPathFactory,
                                                             data: st.DataObject) -> None:
    """Random traffic: frames 0.1-5 ms apart, some with a sample of one wheel or of four, GPS lines between them, the
    frames between two lines cut into runs at random (a reader's wake-ups, a log's batches). Frame by frame and in
    runs, the sink writes the same messages in the same order."""
    n = data.draw(st.integers(50, 400))
    gaps = data.draw(st.lists(st.integers(1, 50), min_size=n, max_size=n))
    wheels = data.draw(st.lists(st.sampled_from([0, 0, 0, 1, 4]), min_size=n, max_size=n))
    lines = set(data.draw(st.lists(st.integers(0, n - 1), max_size=12)))
    cuts = set(data.draw(st.lists(st.integers(1, n - 1), max_size=30)))
    times = np.cumsum(np.array(gaps) * 1e-4).tolist()
    frames = [CanFrame(t, 0x200 if w else 0x123, bytes(8)) for t, w in zip(times, wheels)]
    wheel_at = [i for i, w in enumerate(wheels) for _ in range(w)]
    logs = [_sink_log(tmp_path_factory.mktemp("order") / "log.mcap", frames, wheel_at, lines, c) for c in (None, cuts)]
    assert logs[0] == logs[1]


def test_a_batch_that_filled_is_on_disk_within_a_flush_period_when_nothing_follows(tmp_path: Path) -> None:
    """A live log: 512 frames fill a /can/raw batch, then the bus and the GPS go quiet. The batch is written (in its
    turn, after the samples of its frames) with the next chunk, not held until another record comes."""
    from slipdaq.logformat.reader import iter_raw_records
    from slipdaq.logformat.salvage import ScanResult

    path = tmp_path / "quiet.mcap"

    async def run() -> list:
        sink = McapLogSink(path, load_config(CONFIG), mode="live", flush_every_s=0.2, fsync=False)
        for k in range(512):
            sink.on_raw(CanFrame(1000.0 + k * 5e-5, 0x123, bytes(8)))  # one batch, closed by its 512th frame
        await asyncio.sleep(0.6)  # two flush periods with nothing to do but the timer
        scanned = ScanResult(path)
        got = [r for r in iter_raw_records(path, scanned) if isinstance(r, CanFrame)]
        assert not scanned.has_summary  # read from the file as it is on disk, unfinished
        sink.close()
        return got

    assert len(asyncio.run(run())) == 512


def test_the_diagnostics_schema_names_every_field() -> None:
    """The /diagnostics schema is written out by hand (nested per-wheel counters, the estimator's status): a field
    added to Diagnostics or to SlipEstimator.status() and not to the schema fails here, not only a field missing from
    a message (which the jsonschema validation above catches)."""
    import dataclasses

    from slipdaq.estimator import SlipEstimator
    from slipdaq.logformat.schemas import LIVE_DIAGNOSTICS, SCHEMAS
    from slipdaq.logformat.topics import TOPIC_DIAGNOSTICS
    from slipdaq.records import Diagnostics
    from support.estimator_params import params

    props = SCHEMAS[TOPIC_DIAGNOSTICS]["properties"]
    assert set(props) - set(LIVE_DIAGNOSTICS) == {f.name for f in dataclasses.fields(Diagnostics)}
    assert set(props["estimator"]["properties"]) == set(SlipEstimator(params()).status())
