"""Every message path of every panel of every shipped Foxglove layout (config/foxglove/*.json), resolved against the
messages of a real run (a short simulated drive imported, its MCAP read back with the mcap library): a plotted path
gives one number per message, at the time its panel plots it by."""

from __future__ import annotations

import json
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from support.paths import CONFIG, ROOT

LAYOUTS = sorted((ROOT / "config" / "foxglove").glob("*.json"))
_SEGMENT = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?P<index>(\[[^\]]*\])*)$")


@pytest.fixture(scope="module")
def run_messages(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[tuple[int, Any]]]:
    """topic -> (log time, decoded JSON) of a 10 s ABS stop imported like a real drive (its maneuver decided)."""
    d = tmp_path_factory.mktemp("layout")
    can_path, nmea_path, out = d / "drive.log", d / "drive.nmea", d / "drive.mcap"
    write_drive_logs(generate(load_config(CONFIG), "brake-abs", "paved", SimSettings(gps_latency_s=0.05), 10.0),
                     can_path, nmea_path)
    assert main(["import", "--can", str(can_path), "--nmea", str(nmea_path), "--config", str(CONFIG),
                 "-o", str(out)]) == 0
    got: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with open(out, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "json":
                got[channel.topic].append((message.log_time, json.loads(message.data)))
    return got


def split_path(path: str, topics: set[str]) -> tuple[str, list[str]]:
    """A Foxglove message path -> (topic, field segments): the topic is the longest known topic it starts with."""
    topic = max((t for t in topics if path == t or path.startswith(t + ".")), key=len, default=None)
    assert topic is not None, f"{path}: no topic of the run"
    rest = path[len(topic) + 1:]
    return topic, rest.split(".") if rest else []


def resolve(message: Any, fields: list[str]) -> list[Any]:
    """The values a path's fields select in one message (Foxglove's syntax: name, name[i], name[:] )."""
    values = [message]
    for seg in fields:
        m = _SEGMENT.match(seg)
        assert m, f"unsupported path segment {seg!r}"
        values = [v[m["name"]] for v in values if isinstance(v, dict) and m["name"] in v]
        for index in re.findall(r"\[([^\]]*)\]", m["index"]):
            if index == ":":
                values = [x for v in values for x in v]
            else:
                values = [v[int(index)] for v in values if isinstance(v, list) and -len(v) <= int(index) < len(v)]
    return values


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _series(conf: dict[str, Any]) -> list[tuple[str, str]]:
    """(message path, timestamp method) of a panel's plotted paths (its x-axis path plotted against them)."""
    out = [(s["value"], s.get("timestampMethod", "receiveTime")) for s in conf.get("paths", []) if s.get("enabled", 1)]
    if isinstance(conf.get("xAxisPath"), dict):
        out.append((conf["xAxisPath"]["value"], "receiveTime"))
    return out


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda p: p.name)
def test_every_plotted_path_gives_one_number_per_message(layout: Path, run_messages) -> None:
    doc = json.loads(layout.read_text())
    topics = set(run_messages)
    checked = 0
    for panel, conf in doc["configById"].items():
        for path, method in _series(conf):
            topic, fields = split_path(path, topics)
            messages = run_messages[topic]
            assert messages, f"{panel}: {path}: no message on {topic}"
            values = [resolve(m, fields) for _t, m in messages]
            assert all(len(v) == 1 for v in values), f"{panel}: {path}: not one value per message"
            assert all(_number(v[0]) or v[0] is None for v in values), f"{panel}: {path}: not a number"
            assert any(_number(v[0]) for v in values), f"{panel}: {path}: never a number in the run"
            if method == "headerStamp":  # placed by the message's own header.stamp, a distinct instant each
                stamps = [resolve(m, ["header", "stamp"]) for _t, m in messages]
                assert all(len(s) == 1 and _number(s[0]["sec"]) and _number(s[0]["nsec"]) for s in stamps), path
                ns = [s[0]["sec"] * 1_000_000_000 + s[0]["nsec"] for s in stamps]
                assert len(set(ns)) == len(ns), f"{panel}: {path}: rows at one time"
            else:
                assert method == "receiveTime", f"{panel}: {path}: timestamp {method}"
            checked += 1
        for key in ("topicPath", "followTopic"):
            if key in conf:
                assert run_messages.get(conf[key]), f"{panel}: {key} {conf[key]}: no message in the run"
    assert checked >= 10


def test_high_rate_rows_plot_at_their_own_time(run_messages) -> None:
    """/slip/fast/row: one row per message, stamped with its instant; the same rows /slip/fast holds as columns."""
    rows = [m for _t, m in run_messages["/slip/fast/row"]]
    columns = [m for _t, m in run_messages["/slip/fast"]]
    flat = [{k: c[k][i] for k in c} for c in columns for i in range(len(c["time_s"]))]
    assert len(rows) == len(flat) > 500
    assert max(len(c["time_s"]) for c in columns) > 1  # /slip/fast: several rows at one log time ...
    for row, ref in zip(rows, flat):  # ... /slip/fast/row: each its own, to the nanosecond
        assert {k: v for k, v in row.items() if k != "header"} == ref
        assert row["header"]["stamp"]["sec"] * 1_000_000_000 + row["header"]["stamp"]["nsec"] == \
            round(ref["time_s"] * 1e9)
