"""The Foxglove live view (`slipdaq run --foxglove`) on SocketCAN (vcan0), hardware in the loop. VM only.

One daemon run: `slipdaq run --foxglove 127.0.0.1:0` on vcan0 (forked by zygote.py, at hil_support.DAEMON_NICE), the
simulator's `brake` drive (3 s at 90 km/h, braking at 5.5 m/s² to a stop at ~7.8 s, standing) played into it as
case 1 of test_daemon_socketcan.py plays its drive — generated first, then sent by wpt_sender.py --drive (WPT frames
on a raw CAN socket at 25 Hz per wheel, each frame's count sampled when it is sent, the drive's 10 Hz NMEA on a
pseudo-terminal) — and a Foxglove WebSocket client (tests/foxglove_client.py), connected to the port the daemon
printed and subscribed to every topic before the drive starts, reading until the daemon closes the server.

Asserted: every topic of the log is advertised with the log's message encoding and schema (/estimate's also equal
to the registry's); estimates arrive live, many, each one of the log's messages (its log time and bytes), JSON that
validates against the advertised schema; so do the GPS fixes on /gps/location (foxglove.LocationFix); and the
stop's brake maneuver, which the daemon decides ~2 s after the car stands (drive time ~9.7 s of 14 s) and prints,
arrives as a /maneuver record during the run (the daemon also decides what is still open at its end, which a client
may miss: the drive ends standing, so nothing is). No timing is asserted: the emulated VM keeps real time loosely.

Why not the `cycle` drive (0-60 km/h, cruise, stop): the daemon summarizes a maneuver on its event loop; the
acceleration's summary (its fits: ~0.12 s on the host) stood the loop still for ~7.5 s in the VM, so the NMEA lines of
the following stop were read late, in a few bunches, their fixes rejected, and no stop was estimated. Here the stop
is the first maneuver and is summarized while the car stands (3.6 s in the VM, 0.02 s on the host). The largest gap
between the daemon's GPS read stamps is reported.

Skipped where the kernel has no SocketCAN or no vcan0 (the host): run it with tests/hil/run_vm.sh -k foxglove.
"""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import re
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hil_support import (
    DAEMON_NICE,
    Daemon,
    DaemonResult,
    Zygote,
    bind_pytest,
    can_unavailable_reason,
    diagnostics,
    finished,
    report,
    sender_result,
    start_sender,
    write_config,
    write_drive,
    write_nmea,
)

_reason = can_unavailable_reason()
if _reason:
    pytest.skip(_reason, allow_module_level=True)
pytest.importorskip("websockets")
jsonschema = pytest.importorskip("jsonschema")
if importlib.util.find_spec("foxglove") is None:  # the daemon's server; not imported here (slow in the VM)
    pytest.skip("foxglove-sdk is not installed", allow_module_level=True)

from support.foxglove_client import Client, read_log  # noqa: E402  (tests/foxglove_client.py; tests/ is on sys.path via its conftest)

RATE_HZ = 25.0
"""WPT frames per second per wheel (case 1's rate: the VM keeps it in real time)."""
SCENARIO = "brake"
DURATION_S = 14.0
"""The brake drive stops at ~7.8 s; its maneuver is decided at ~9.7 s (a high-rate row past its span, which ends
1.5 s after its last window, must come), then the car stands."""
GPS_LINK = "/tmp/hil-gps-foxglove"
TOPIC_ESTIMATE, TOPIC_GPS_LOCATION, TOPIC_MANEUVER = "/estimate", "/gps/location", "/maneuver"
TOPIC_TEST_SET = "/test_set"
PROCEDURE = "brake 90-0"
"""The daemon's config declares this procedure: the stop is its run (or is excluded from it, with why)."""
CONNECT_TIMEOUT_S = 120.0
MANEUVER_WAIT_S = 180.0
"""After the daemon has processed every frame sent: how long the stop's maneuver may still take to reach the client
(its summary is computed on the daemon's own thread, slowly in the emulated VM, and published when ready; the client,
emulated Python, may be behind on its socket)."""


@dataclass
class Run:
    url: str
    result: DaemonResult
    sender: dict[str, Any]
    client: Client
    log_channels: dict[str, tuple[str, str, str, bytes]]
    """topic -> (message encoding, schema name, schema encoding, schema data), as the log has them."""
    logged: dict[str, list[tuple[int, bytes]]]
    """topic -> (log time ns, payload) of every message in the log."""
    times: dict[str, float]
    """Seconds since the daemon was started."""
    decided: list[str]
    """The kinds of the maneuvers the daemon printed (decided) before it was stopped."""


class FoxgloveDaemon(Daemon):
    """hil_support.Daemon with `--foxglove 127.0.0.1:0`: a live server on a free port, which it prints."""

    def __init__(self, zygote: Zygote, config: Path, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.proc = zygote.spawn("daemon", "slipdaq", ["run", "--config", str(config), "--log-dir", str(log_dir),
                                                       "--foxglove", "127.0.0.1:0"],
                                 cwd=config.parent, nice=DAEMON_NICE)


def _drive(d: Path) -> None:
    """The simulator's drive as wpt_sender.py's --drive and --nmea files (case 1's generation)."""
    from slipdaq.config import load_config
    from slipdaq.records import NmeaLine
    from slipdaq.sim.emit import SimSettings, generate

    cfg = load_config(write_config(d, GPS_LINK))
    settings = SimSettings(wpt_rate_hz=0.0, gps_rate_hz=10.0, seed=1)  # the frames are made by the sender
    truth, nmea = [], []
    for ev in generate(cfg, SCENARIO, "paved", settings, duration_s=DURATION_S):
        if ev.truth is not None:
            truth.append(ev.truth)
        elif isinstance(ev.record, NmeaLine):
            nmea.append((ev.time_s, ev.record.line))
    write_drive(d / "drive.json", truth, cfg.wpt.pulses_per_rev, settings.start_count)
    write_nmea(d / "drive.nmea", nmea)


_MANEUVER_LINE = re.compile(r"^maneuver #(\d+) (\w+) ")


def printed_maneuvers(daemon: Daemon) -> list[str]:
    """The kinds of the maneuvers the daemon has printed so far (a line each, 0.25 s after it decided it)."""
    with daemon.proc._cv:
        return [m.group(2) for _t, line in daemon.proc.lines if (m := _MANEUVER_LINE.match(line))]


async def _live_run(zygote: Zygote, d: Path) -> tuple[str, DaemonResult, dict[str, Any], Client, dict[str, float],
                                                     list[str]]:
    t0 = time.monotonic()
    times: dict[str, float] = {}
    cfg = write_config(d, GPS_LINK)
    cfg.write_text(cfg.read_text() + f'\n[[test.procedure]]\nname = "{PROCEDURE}"\nkind = "brake"\n'
                                      "target_speed_kmh = 90.0\nruns = 1\n")
    daemon = FoxgloveDaemon(zygote, cfg, d / "logs")
    go = d / "client-subscribed"  # the sender starts once the client is subscribed (and the daemon reads the pty)
    sender = start_sender(RATE_HZ, DURATION_S, go=str(go), delay_s=1.5, drive=d / "drive.json",
                          nmea=d / "drive.nmea", gps_link=GPS_LINK, gps_reader_pid=daemon.pid)
    client = Client()
    reading: asyncio.Task[None] | None = None
    try:
        _, m = await asyncio.to_thread(daemon.proc.wait_line, r"Foxglove live view on (ws://127\.0\.0\.1:(\d+))", 900)
        url = m.group(1)
        assert int(m.group(2)) != 0, url  # port 0 asked: the port it got is printed
        times["server_up_s"] = time.monotonic() - t0
        await client.connect(url, timeout_s=CONNECT_TIMEOUT_S)
        await client.subscribe(list(client.channels.values()))
        reading = asyncio.create_task(client.read_all())  # subscribes to channels advertised later, too
        await asyncio.to_thread(daemon.wait_log_open, 600)
        go.touch()
        times["subscribed_s"] = time.monotonic() - t0
        r = await asyncio.to_thread(sender_result, sender, 10 * DURATION_S + 900)
        await asyncio.to_thread(daemon.wait_frames, r["sent"], 900)
        await asyncio.sleep(1.0)  # a maneuver decided with the last frames is printed 0.25 s later
        # the drive's stop is over: its summary is computed on the daemon's own thread (slow in the emulated VM) and
        # goes out when ready; the client should get it, and every maneuver the daemon printed, before it stops
        deadline = time.monotonic() + MANEUVER_WAIT_S
        while (not client.messages.get(TOPIC_MANEUVER)
               or len(client.messages[TOPIC_MANEUVER]) < len(printed_maneuvers(daemon))) \
                and time.monotonic() < deadline and not reading.done():
            await asyncio.sleep(0.25)
        decided = printed_maneuvers(daemon)
        times["stop_s"] = time.monotonic() - t0
        result = await asyncio.to_thread(daemon.stop)
        await asyncio.wait_for(reading, 120)  # read_all ends when the daemon closes the server
        times["end_s"] = time.monotonic() - t0
    finally:
        if reading is not None and not reading.done():
            reading.cancel()
        if client.ws is not None:
            client.ws.transport.abort()
        sender.kill()
        daemon.proc.kill()
    return url, result, r, client, times, decided


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory, pytestconfig: pytest.Config) -> Iterator[Run]:
    bind_pytest(pytestconfig)
    t0 = time.time()
    zygote = Zygote()  # imports in parallel with this process's own imports and the drive's generation
    try:
        import slipdaq.sim.emit  # noqa: F401

        d = tmp_path_factory.mktemp("foxglove")
        _drive(d)
        report(f"foxglove: drive generated {time.time() - t0:.0f} s after the start; zygote imports took "
               f"{zygote.wait_ready():.0f} s")
        url, result, sender, client, times, decided = asyncio.run(_live_run(zygote, d))
        if os.environ.get("SLIPDAQ_HIL_ARTIFACTS"):  # run_vm.sh passes it on: the log for a look afterwards
            target = Path(os.environ["SLIPDAQ_HIL_ARTIFACTS"])
            target.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(result.log, target / "foxglove-live.mcap")
        channels, logged = read_log(result.log)
        yield Run(url, result, sender, client, channels, logged, times, decided)
    finally:
        zygote.close()


@pytest.fixture(autouse=True)
def _bind(pytestconfig: pytest.Config) -> None:
    bind_pytest(pytestconfig)


def _validator(schema: dict[str, Any]) -> Any:
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema)


def test_the_run_is_complete(run: Run) -> None:
    """The drive went through: every frame and line the sender wrote is in the finished log, no frame lost; the
    client was the daemon's one live client."""
    r, res, t = run.sender, run.result, run.times
    diags = diagnostics(res.log)
    stamps = sorted({json.loads(data)["timestamp_s"] for _t, data in run.logged["/gps/fix"]})
    stall = max(b - a for a, b in zip(stamps, stamps[1:]))
    got = {k: len(v) for k, v in sorted(run.client.messages.items())}
    logged = {k: len(v) for k, v in sorted(run.logged.items())}
    report(f"foxglove: server up {t['server_up_s']:.0f} s after the daemon was started, client subscribed at "
           f"{t['subscribed_s']:.0f} s, drive sent in {r['end_s'] - r['start_s']:.1f} s ({r['sent']} frames, "
           f"{r['nmea_written']} NMEA lines), daemon stopped at {t['stop_s']:.0f} s, client done at {t['end_s']:.0f} "
           f"s; {res.estimates} estimates, {diags[-1]['estimator']['rejected_fixes']} GPS fixes rejected (largest gap "
           f"between GPS read stamps {stall:.2f} s); live "
           f"published {diags[-1]['live_published_messages']}, dropped {diags[-1]['live_dropped_messages']}; "
           f"messages live / logged per topic: " + ", ".join(f"{k} {got.get(k, 0)}/{n}" for k, n in logged.items()))
    assert r["sent"] == 4 * int(RATE_HZ * DURATION_S) and r["failed"] == 0
    assert res.can_frames == r["sent"] and res.lost_frames == 0
    assert r["nmea_dropped"] == r["nmea_unread"] == 0 and res.nmea_lines == r["nmea_written"]
    assert finished(res.log)
    assert max(x["live_clients"] for x in diags) == 1, [x["live_clients"] for x in diags]


def test_every_logged_topic_is_advertised_with_the_log_s_schema(run: Run) -> None:
    from slipdaq.logformat.registry import TOPIC_FORMATS

    advertised = run.client.advertised()
    assert {TOPIC_ESTIMATE, TOPIC_GPS_LOCATION, TOPIC_MANEUVER} <= set(run.log_channels) <= set(advertised)
    for topic, (encoding, schema_name, schema_encoding, schema_data) in run.log_channels.items():
        ch = advertised[topic]
        assert (ch["encoding"], ch["schemaName"], ch["schemaEncoding"]) == (encoding, schema_name, schema_encoding)
        assert ch["schema"].encode() == schema_data, topic
    assert advertised[TOPIC_ESTIMATE]["schema"].encode() == TOPIC_FORMATS[TOPIC_ESTIMATE].schema_data


def _live_and_valid(run: Run, topic: str) -> list[dict[str, Any]]:
    """The topic's messages the client got: each one of the log's (log time and bytes), JSON valid against the
    schema advertised for it; decoded."""
    got = run.client.messages.get(topic, [])
    logged = set(run.logged.get(topic, []))
    assert set(got) <= logged, f"{topic}: {len(set(got) - logged)} messages the log does not have"
    validator = _validator(json.loads(run.client.advertised()[topic]["schema"]))
    out = []
    for _t, data in got:
        msg = json.loads(data)
        validator.validate(msg)
        out.append(msg)
    return out


def test_estimates_arrive_live_and_valid(run: Run) -> None:
    estimates = _live_and_valid(run, TOPIC_ESTIMATE)
    logged = len(run.logged[TOPIC_ESTIMATE])
    assert len(estimates) >= 60, (len(estimates), logged)  # 137 offline: one per 10 Hz fix after the first 0.3 s
    moving = [e for e in estimates if (e.get("speed_mps") or 0.0) > 5.0]
    assert len(moving) >= 30 and sum(e.get("slip_FL") is not None for e in moving) >= 20, len(moving)  # 69 offline
    report(f"foxglove: {len(estimates)} of {logged} estimates live, all valid JSON of the advertised schema, "
           f"{len(moving)} above 5 m/s")


def test_gps_location_arrives_live(run: Run) -> None:
    fixes = _live_and_valid(run, TOPIC_GPS_LOCATION)
    assert json.loads(run.client.advertised()[TOPIC_GPS_LOCATION]["schema"])["title"] == "foxglove.LocationFix"
    assert len(fixes) >= 20, len(fixes)
    assert all(-90 <= f["latitude"] <= 90 and -180 <= f["longitude"] <= 180 for f in fixes)
    report(f"foxglove: {len(fixes)} of {len(run.logged[TOPIC_GPS_LOCATION])} /gps/location fixes live")


def test_the_stop_s_maneuver_arrives_live(run: Run) -> None:
    """The stop's brake maneuver reached the client live, before the daemon was stopped, and so did every maneuver the
    daemon printed during the run, in order, each one of the log's /maneuver records."""
    maneuvers = _live_and_valid(run, TOPIC_MANEUVER)
    kinds = [m["kind"] for m in maneuvers]
    decided = run.decided
    logged = [json.loads(data)["kind"] for _t, data in run.logged.get(TOPIC_MANEUVER, [])]
    phases = [json.loads(data).get("phase") for _t, data in run.logged[TOPIC_ESTIMATE]]
    runs = [f"{p} x{n}" for p, n in _runs(phases)]
    report(f"foxglove: maneuvers decided during the run {decided}, live {kinds}, logged {logged}; "
           f"estimates' phases: {', '.join(runs)}")
    assert "brake" in kinds, f"live {kinds}; the daemon printed {decided} during the run, {logged} in all"
    assert kinds[:len(decided)] == decided, f"live {kinds}, decided during the run {decided}"
    brake = next(m for m in maneuvers if m["kind"] == "brake")
    assert brake["speed_to_kmh"] < 5.0 < brake["speed_from_kmh"], brake  # a stop


def test_the_stop_fills_its_test_set_live(run: Run) -> None:
    """The stop's test set reached the client live: the procedure's /test_set record after its run, counted or
    excluded with its reason, each record one of the log's."""
    sets = _live_and_valid(run, TOPIC_TEST_SET)
    report(f"foxglove: /test_set live {[(s['procedure'], s['runs_valid'], s['excluded']) for s in sets]}")
    assert sets, f"no /test_set live; logged {len(run.logged.get(TOPIC_TEST_SET, []))}"
    last = sets[-1]
    assert last["procedure"] == PROCEDURE and last["kind"] == "brake"
    assert last["runs_valid"] + len(last["excluded"]) >= 1, last


def _runs(values: list[Any]) -> list[tuple[Any, int]]:
    out: list[tuple[Any, int]] = []
    for v in values:
        if out and out[-1][0] == v:
            out[-1] = (v, out[-1][1] + 1)
        else:
            out.append((v, 1))
    return out
