"""The Foxglove live server (`--foxglove`, sinks/foxglove_live.py) against real Foxglove WebSocket clients.

The clients are `websockets` speaking the Foxglove WebSocket protocol v1 (serverInfo and advertise in, subscribe
out, binary message data in: opcode 0x01, subscription id u32, log time u64, payload). foxglove-sdk 0.30 names the
subprotocol `foxglove.sdk.v1` and refuses the older name `foxglove.websocket.v1` (HTTP 400); the messages are the
same. The daemon is `slipdaq demo --scenario brake-abs` on python-can's virtual bus in a child process, with two
clients at once: one reads everything, one subscribes to everything and then never reads (a receive buffer of a few
kB that it never empties).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

websockets = pytest.importorskip("websockets")
pytest.importorskip("foxglove")
jsonschema = pytest.importorskip("jsonschema")


from slipdaq.config import ConfigError, parse_config, parse_host_port  # noqa: E402
from slipdaq.logformat.registry import TOPIC_FORMATS  # noqa: E402
from slipdaq.logformat.topics import TOPIC_DIAGNOSTICS, TOPIC_ESTIMATE, TOPIC_GPS_LOCATION, log_time_ns  # noqa: E402
from support.foxglove_client import Client, read_log  # noqa: E402  (tests/foxglove_client.py)

ROOT = Path(__file__).resolve().parents[2]
DEMO_S = 12.0
"""The brake-abs demo: 2 s standstill, acceleration to 80 km/h, cruise, ABS stop; 12 s covers the stop."""
TOPIC_MANEUVER = "/maneuver"


# ---- the live run ---------------------------------------------------------------------------------------------
@dataclass
class LiveRun:
    returncode: int
    output: str
    wall_s: float
    log_path: Path
    reader: Client


async def _live_run(log_dir: Path) -> LiveRun:
    started = time.monotonic()
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "slipdaq", "demo", "--scenario", "brake-abs", "--duration", str(DEMO_S),
        "--foxglove", "127.0.0.1:0", "--log-dir", str(log_dir), "--no-calibration",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT, cwd=ROOT)
    assert proc.stdout is not None
    lines: list[str] = []
    url = None
    while url is None:
        line = (await asyncio.wait_for(proc.stdout.readline(), 60)).decode()
        assert line, "the demo ended before its Foxglove server started:\n" + "".join(lines)
        lines.append(line)
        m = re.search(r"Foxglove live view on (ws://127\.0\.0\.1:(\d+))", line)
        if m:
            assert int(m.group(2)) != 0  # port 0 asked: the port it got is printed
            url = m.group(1)

    async def drain() -> None:
        async for raw in proc.stdout:  # type: ignore[union-attr]
            lines.append(raw.decode())

    drainer = asyncio.create_task(drain())
    reader, stuck = Client(), Client()
    await reader.connect(url)
    await reader.subscribe(list(reader.channels.values()))
    await stuck.connect(url, receive_buffer_bytes=4096)
    await stuck.subscribe(list(stuck.channels.values()))
    stuck.ws.transport.pause_reading()  # from here on it reads nothing while the daemon runs
    reading = asyncio.create_task(reader.read_all())
    returncode = await asyncio.wait_for(proc.wait(), DEMO_S + 90)
    wall_s = time.monotonic() - started
    await drainer
    await asyncio.wait_for(reading, 10)
    stuck.ws.transport.abort()  # it never reads: no close handshake
    output = "".join(lines)
    m = re.search(r"log:\s+(\S+\.mcap)", output)
    assert m, output
    return LiveRun(returncode, output, wall_s, Path(m.group(1)), reader)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> LiveRun:
    return asyncio.run(_live_run(tmp_path_factory.mktemp("foxglove")))


# ---- tests ----------------------------------------------------------------------------------------------------
def test_every_logged_topic_is_advertised_with_the_log_s_encoding_and_schema(live: LiveRun) -> None:
    assert live.returncode == 0, live.output
    log_channels, _ = read_log(live.log_path)
    advertised = live.reader.advertised()
    assert set(log_channels) == set(TOPIC_FORMATS) <= set(advertised)
    for topic, (encoding, schema_name, schema_encoding, schema_data) in log_channels.items():
        ch = advertised[topic]
        assert (ch["encoding"], ch["schemaName"], ch["schemaEncoding"]) == (encoding, schema_name, schema_encoding)
        assert ch["schema"].encode() == schema_data, topic
    assert advertised[TOPIC_ESTIMATE]["schema"].encode() == TOPIC_FORMATS[TOPIC_ESTIMATE].schema_data


def test_the_reader_gets_the_log_s_messages_byte_for_byte(live: LiveRun) -> None:
    _, logged = read_log(live.log_path)
    got = live.reader.messages
    schemas = {t: json.loads(ch["schema"]) for t, ch in live.reader.advertised().items() if ch["encoding"] == "json"}
    estimates = got.get(TOPIC_ESTIMATE, [])
    assert len(estimates) >= 50
    for topic, msgs in got.items():
        assert set(msgs) <= set(logged[topic]), topic  # each one is a logged message: its log time and its bytes
        if topic in schemas:
            for _t, data in msgs[:200]:
                jsonschema.validate(json.loads(data), schemas[topic])
    # a reader that keeps up gets (nearly) all of it: the SDK drops a client's oldest only when it falls behind
    assert len(estimates) >= 0.95 * len(logged[TOPIC_ESTIMATE])
    assert {"/can/raw", "/wpt/count", "/nmea/raw", "/gps/fix", "/slip/fast", "/diagnostics"} <= set(got)


def test_the_gps_track_is_live_and_in_the_log_as_location_fixes(live: LiveRun) -> None:
    _, logged = read_log(live.log_path)
    fixes = live.reader.messages.get(TOPIC_GPS_LOCATION, [])
    assert len(fixes) >= 20 and len(logged[TOPIC_GPS_LOCATION]) >= len(fixes)
    schema = json.loads(live.reader.advertised()[TOPIC_GPS_LOCATION]["schema"])
    assert schema["title"] == "foxglove.LocationFix"
    for log_time, data in fixes:
        fix = json.loads(data)
        jsonschema.validate(fix, schema)
        stamp_ns = fix["timestamp"]["sec"] * 10**9 + fix["timestamp"]["nsec"]  # the fix's own receive time
        assert 0 <= log_time - stamp_ns < 200_000_000  # logged when processed, after frames stamped a bit later
        assert -90 <= fix["latitude"] <= 90 and -180 <= fix["longitude"] <= 180


def test_the_maneuver_is_live(live: LiveRun) -> None:
    if TOPIC_MANEUVER not in TOPIC_FORMATS:
        pytest.skip("no /maneuver topic in the log's registry yet")
    _, logged = read_log(live.log_path)
    got = live.reader.messages.get(TOPIC_MANEUVER, [])
    assert got and set(got) <= set(logged[TOPIC_MANEUVER])
    schema = json.loads(live.reader.advertised()[TOPIC_MANEUVER]["schema"])
    for _t, data in got:
        jsonschema.validate(json.loads(data), schema)


def test_the_test_set_is_live(live: LiveRun) -> None:
    """The demo's brake 80-0 set ([[test.procedure]]) after the ABS stop: on /test_set, live as in the log."""
    _, logged = read_log(live.log_path)
    got = live.reader.messages.get("/test_set", [])
    assert got and set(got) <= set(logged["/test_set"])
    schema = json.loads(live.reader.advertised()["/test_set"]["schema"])
    last = json.loads(got[-1][1])
    jsonschema.validate(last, schema)
    assert (last["procedure"], last["runs_valid"], last["runs_required"]) == ("brake 80-0", 1, 3)
    assert "test set brake 80-0: 1 of 3" in live.output


def test_a_client_that_never_reads_stalls_neither_reading_nor_logging(live: LiveRun) -> None:
    assert live.returncode == 0, live.output
    # the daemon ended on time (its stop does not wait for the stuck client's close handshake)
    assert live.wall_s < DEMO_S + 30, live.wall_s
    _, logged = read_log(live.log_path)
    estimates = logged[TOPIC_ESTIMATE]
    m = re.search(r"estimates:\s+(\d+)", live.output)
    assert m and int(m.group(1)) == len(estimates)  # every estimate the pipeline made is in the log
    times = [json.loads(d)["time_s"] for _t, d in estimates]
    moving = [b - a for a, b in zip(times, times[1:])]
    assert len(estimates) >= 60 and max(moving) < 0.5  # estimates every 0.1 s: no stall of the pipeline
    assert re.search(r"CAN:\s+\d+ frames \(\d+ frames/s\), 0 lost", live.output), live.output
    diags = [json.loads(d) for _t, d in logged[TOPIC_DIAGNOSTICS]]
    assert max(b["time_s"] - a["time_s"] for a, b in zip(diags, diags[1:])) < 1.5
    assert max(d["live_clients"] for d in diags) == 2
    assert all(d["live_dropped_messages"] == 0 for d in diags)
    assert diags[-1]["live_published_messages"] >= len(estimates)


# ---- without a daemon -----------------------------------------------------------------------------------------
def test_the_address_is_host_port_with_a_loopback_default() -> None:
    assert parse_host_port("8765") == ("127.0.0.1", 8765)
    assert parse_host_port("0") == ("127.0.0.1", 0)
    assert parse_host_port("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_host_port("[::1]:9000") == ("::1", 9000)
    for bad in ("", "x", "host:", "h:70000", "::1:80", "a b:1", "-1"):
        with pytest.raises(ValueError):
            parse_host_port(bad)
    assert parse_config('[live]\nfoxglove = "8765"\n').live.foxglove == "8765"
    assert parse_config("").live.foxglove is None
    for bad in ("[live]\nfoxglove = 8765\n", '[live]\nfoxglove = "x:y"\n', '[live]\nport = "1"\n'):
        with pytest.raises(ConfigError, match="live"):
            parse_config(bad)
    p = subprocess.run([sys.executable, "-m", "slipdaq", "demo", "--foxglove", "here:there"], capture_output=True,
                       text=True, cwd=ROOT)
    assert p.returncode == 2 and "--foxglove" in p.stderr


def test_the_tap_gets_what_the_log_gets(tmp_path: Path) -> None:
    """McapLogSink's tap: every message, its topic, log time and bytes as written; a valid fix with a position
    also as /gps/location, in the log too."""
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.records import GpsFix, SourceEvent
    from slipdaq.sinks.mcap_log import McapLogSink

    tapped: list[tuple[str, int, bytes]] = []
    sink = McapLogSink(tmp_path / "t.mcap", load_config(packaged_config_path()), "test",
                       tap=lambda topic, t, data: tapped.append((topic, log_time_ns(t), data)))
    sink.on_fix(GpsFix(1_700_000_000.25, 12.0, latitude_deg=48.1, longitude_deg=11.5, altitude_m=520.0))
    sink.on_fix(GpsFix(1_700_000_000.35, 12.0, valid=False, latitude_deg=48.1, longitude_deg=11.5))
    sink.on_fix(GpsFix(1_700_000_000.45, 12.0))
    sink.on_source_event(SourceEvent(1_700_000_000.5, "gps", "connected", "", None, {}))
    sink.close()
    _, logged = read_log(tmp_path / "t.mcap")
    assert sorted((t, lt, d) for t, msgs in logged.items() for lt, d in msgs) == sorted(tapped)
    assert [t for t, _lt, _d in tapped].count(TOPIC_GPS_LOCATION) == 1
    fix = json.loads(logged[TOPIC_GPS_LOCATION][0][1])
    assert fix["timestamp"] == dict(zip(("sec", "nsec"), divmod(log_time_ns(1_700_000_000.25), 10**9)))
    assert fix["timestamp"]["sec"] == 1_700_000_000 and fix["altitude"] == 520.0
    jsonschema.validate(fix, json.loads(TOPIC_FORMATS[TOPIC_GPS_LOCATION].schema_data))


def test_publishing_never_waits_for_a_client_that_stopped_reading() -> None:
    """40 MB for a client that subscribed and then stopped reading, far more than the sockets' buffers hold: each
    publish returns at once, memory stays bounded (the server drops that client's oldest messages), and close()
    does not wait for its close handshake."""
    from slipdaq.sinks.foxglove_live import FoxgloveLive

    def rss_bytes() -> int:
        return int(Path("/proc/self/statm").read_text().split()[1]) * 4096

    async def main() -> tuple[list[float], int, float, int, int]:
        live = FoxgloveLive("127.0.0.1:0", backlog_messages=256, flush_every_s=0)  # each message at once
        stuck = Client()
        await stuck.connect(live.url, receive_buffer_bytes=4096)
        await stuck.subscribe([ch for ch in stuck.channels.values() if ch["topic"] == "/diagnostics/events"])
        while not live.clients:
            await asyncio.sleep(0.01)
        stuck.ws.transport.pause_reading()
        payload, n = b"x" * 2000, 20_000
        rss0 = rss_bytes()
        calls = []
        for i in range(n):
            t0 = time.perf_counter()
            live.publish("/diagnostics/events", 1_700_000_000.0 + i * 1e-3, payload)
            calls.append(time.perf_counter() - t0)
        grown = rss_bytes() - rss0
        t0 = time.perf_counter()
        stopped = live.close(wait_s=1.0)
        close_s = time.perf_counter() - t0
        stuck.ws.transport.resume_reading()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stuck.read_all(), 5)
        assert live.published_messages == n and live.dropped_messages == 0 and not stopped
        return calls, grown, close_s, n, len(stuck.messages.get("/diagnostics/events", []))

    calls, grown, close_s, n, received = asyncio.run(main())
    assert statistics.median(calls) < 20e-6 and sorted(calls)[int(0.999 * n)] < 2e-3, (statistics.median(calls),
                                                                                         max(calls))
    assert grown < 20_000_000  # 40 MB published: the server keeps at most its backlog for the client
    assert close_s < 1.5
    assert received < n / 2  # the client lost most of it, the publisher nothing


def test_a_port_in_use_is_one_clear_error() -> None:
    from slipdaq.sinks.foxglove_live import FoxgloveLive

    first = FoxgloveLive("127.0.0.1:0")
    try:
        assert first.url == f"ws://127.0.0.1:{first.port}" and first.port != 0
        with pytest.raises(OSError, match="cannot start the Foxglove live server"):
            FoxgloveLive(f"127.0.0.1:{first.port}")
    finally:
        assert first.close()


def test_messages_go_out_in_bursts_through_a_bounded_queue() -> None:
    """On an event loop the messages wait for the next burst (flush_every_s); more than max_pending waiting are
    dropped and counted, the rest reach the client in order; nothing is queued while no client is subscribed."""
    from slipdaq.sinks.foxglove_live import FoxgloveLive

    async def main() -> tuple[dict[str, object], list[tuple[int, bytes]], dict[str, object]]:
        live = FoxgloveLive("127.0.0.1:0", flush_every_s=0.05, max_pending=100)
        live.publish("/diagnostics/events", 1.0, b"{}")  # no client yet: not queued (else it would come first)
        idle = live.status()
        client = Client()
        await client.connect(live.url)
        await client.subscribe([ch for ch in client.channels.values() if ch["topic"] == "/diagnostics/events"])
        while not live.clients:
            await asyncio.sleep(0.01)
        reading = asyncio.create_task(client.read_all())
        for i in range(150):  # without yielding to the loop: the burst waits for the timer
            live.publish("/diagnostics/events", 1_700_000_000.0 + i, b'{"i":%d}' % i)
        await asyncio.sleep(0.5)
        status = live.status()
        live.close()
        await asyncio.wait_for(reading, 5)
        return status, client.messages.get("/diagnostics/events", []), idle

    status, got, idle = asyncio.run(main())
    assert (idle["live_clients"], idle["live_published_messages"], idle["live_dropped_messages"]) == (0, 0, 0)
    assert status["live_clients"] == 1
    assert (status["live_published_messages"], status["live_dropped_messages"]) == (100, 50)
    assert [json.loads(d)["i"] for _t, d in got] == list(range(100))
    assert [t for t, _d in got] == [log_time_ns(1_700_000_000.0 + i) for i in range(100)]


def test_the_layout_is_a_foxglove_layout_of_the_log_s_topics_and_fields() -> None:
    """config/foxglove/slipdaq-layout.json: Foxglove's layout file (configById, the panels' tree in `layout`); every
    panel in the tree is configured and every configured panel is in the tree; every message path names a topic of
    the log and a field of its schema."""
    doc = json.loads((ROOT / "config" / "foxglove" / "slipdaq-layout.json").read_text())
    assert {"configById", "layout", "globalVariables", "userNodes", "playbackConfig"} <= set(doc)

    def panels(node: Any) -> list[str]:
        if isinstance(node, str):
            return [node]
        assert node["direction"] in ("row", "column") and 0 < node.get("splitPercentage", 50) < 100
        return panels(node["first"]) + panels(node["second"])

    in_tree = panels(doc["layout"])
    assert sorted(in_tree) == sorted(doc["configById"]) and len(set(in_tree)) == len(in_tree)
    assert {p.split("!")[0] for p in in_tree} == {"Plot", "map", "Table"}
    paths = []
    for conf in doc["configById"].values():
        paths += [s["value"] for s in conf.get("paths", [])]
        paths += [conf[k]["value"] if isinstance(conf[k], dict) else conf[k] for k in ("xAxisPath", "topicPath",
                                                                                     "followTopic") if k in conf]
    fields = {t: set(json.loads(f.schema_data).get("properties", {})) for t, f in TOPIC_FORMATS.items()
              if f.schema_encoding == "jsonschema"}
    for path in paths:
        topic, _, field_ = path.partition(".")
        if topic == TOPIC_MANEUVER and topic not in fields:
            continue  # the maneuvers' topic, in logs that have it
        assert topic in fields, path
        assert not field_ or field_ in fields[topic], path
    assert {TOPIC_ESTIMATE, "/slip/fast/row", TOPIC_GPS_LOCATION, TOPIC_MANEUVER} <= {p.partition(".")[0] for p in paths}
    scatter = [c for c in doc["configById"].values() if c.get("xAxisVal") == "custom"]
    assert [c["xAxisPath"]["value"] for c in scatter] == [f"/estimate.slip_{w}" for w in ("FL", "FR", "RL", "RR")]


def test_a_topic_registered_later_is_advertised_with_its_first_message() -> None:
    """A topic registered after the server started (a new stream's registration) needs no change here: its channel
    is made and advertised when its first message comes; a client subscribed then gets the next ones."""
    from slipdaq.logformat.registry import TopicFormat, register
    from slipdaq.sinks.foxglove_live import FoxgloveLive

    topic = "/test/registered-later"

    async def main() -> tuple[dict[str, Any], list[tuple[int, bytes]]]:
        live = FoxgloveLive("127.0.0.1:0", flush_every_s=0)
        client = Client()
        await client.connect(live.url)
        await client.subscribe(list(client.channels.values()))
        while not live.clients:
            await asyncio.sleep(0.01)
        reading = asyncio.create_task(client.read_all())  # subscribes to channels advertised later
        register(TopicFormat(topic, "json", "test.Later", "jsonschema", b'{"type":"object"}'))
        try:
            live.publish(topic, 1.0, b'{"n":1}')  # advertised now; no one subscribed to it yet
            for _ in range(200):
                await asyncio.sleep(0.02)
                if topic in client.subscriptions.values():
                    break
            await asyncio.sleep(0.2)  # the subscription reaches the server
            live.publish(topic, 2.0, b'{"n":2}')
            for _ in range(100):
                await asyncio.sleep(0.02)
                if client.messages.get(topic):
                    break
        finally:
            TOPIC_FORMATS.pop(topic)
            live.close()
        await asyncio.wait_for(reading, 5)
        return client.advertised()[topic], client.messages.get(topic, [])

    advertised, got = asyncio.run(main())
    assert (advertised["encoding"], advertised["schemaName"], advertised["schemaEncoding"]) == ("json", "test.Later",
                                                                                               "jsonschema")
    assert got == [(log_time_ns(2.0), b'{"n":2}')]
