"""/slip/fast as one message of rows (columns) per record that released them: the reader gives the rows back, a log
written before (one message per row) still reads, and replays to the same rows and estimates, bit for bit."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import jsonschema
from mcap.reader import make_reader
from test_epoch_json import exact

from slipdaq import WHEELS
from slipdaq.cli import main
from slipdaq.config import load_config, packaged_config_path
from slipdaq.logformat.reader import iter_estimates, iter_fast_slip, iter_topic
from slipdaq.logformat.schemas import SCHEMAS
from slipdaq.logformat.topics import TOPIC_ESTIMATE, TOPIC_FAST_SLIP
from slipdaq.records import FastSlip, FastWheel
from slipdaq.sinks.mcap_log import McapLogSink
from support.paths import DATA

OLD = DATA / "slipdaq-6641212" / "drive-fast-rows.mcap"


def _messages(path: Path, topic: str) -> list[tuple[int, bytes]]:
    with open(path, "rb") as f:
        return [(m.log_time, m.data) for _s, _c, m in make_reader(f).iter_messages(topics=[topic])]


def _exact_rows(rows: list[dict[str, object]]) -> list[object]:
    return [exact(json.dumps(r).encode()) for r in rows]


def test_old_log_rows_read_and_replay_to_the_same_rows_and_estimates(tmp_path: Path) -> None:
    old_rows = list(iter_fast_slip(OLD))
    assert len(_messages(OLD, TOPIC_FAST_SLIP)) == len(old_rows) > 700  # one message per row
    assert sum(r["slip_FL"] is not None for r in old_rows) > 300
    out = tmp_path / "replayed.mcap"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["replay", str(OLD), "-o", str(out)]) == 0
    new_rows = list(iter_fast_slip(out))
    assert _exact_rows(new_rows) == _exact_rows(old_rows)
    # the rows' log times too: each row at its message's
    assert [t for _topic, t, _d in iter_topic(out, (TOPIC_FAST_SLIP,))] == [t for t, _ in _messages(OLD, TOPIC_FAST_SLIP)]
    messages = _messages(out, TOPIC_FAST_SLIP)
    assert len(messages) < len(new_rows) / 3  # the rows of each fix in one message
    for _t, data in messages:
        jsonschema.validate(json.loads(data), SCHEMAS[TOPIC_FAST_SLIP])
    assert _exact_rows(list(iter_estimates(out))) == _exact_rows(list(iter_estimates(OLD)))
    assert [t for t, _ in _messages(out, TOPIC_ESTIMATE)] == [t for t, _ in _messages(OLD, TOPIC_ESTIMATE)]


def _row(t: float, wheels: tuple[str, ...]) -> FastSlip:
    return FastSlip(t, 10.0 + t, float("nan") if t == 2 else 0.5, "gps",
                    {w: FastWheel(None if w == "RR" else 0.01 * t, float("inf") if t == 1 else 10.0) for w in wheels})


def test_rows_with_other_wheels_go_in_another_message(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    sink = McapLogSink(path, load_config(packaged_config_path()), mode="test")
    rows = [_row(0, WHEELS), _row(1, WHEELS), _row(2, WHEELS[:2]), _row(3, WHEELS), _row(4, WHEELS[::-1])]
    sink.on_fast_slip_rows(rows, 5.0)
    sink.on_fast_slip(_row(5, WHEELS), 6.0)
    sink.close()
    assert len(_messages(path, TOPIC_FAST_SLIP)) == 5
    assert _exact_rows(list(iter_fast_slip(path))) == _exact_rows([r.as_row() for r in rows + [_row(5, WHEELS)]])
