"""The report's high-rate slip rows held as columns (offline.run.Rows: records.fast_rows.FastRows): they read back as
the rows a two-pass replay logs, and the report's consumers (the maneuver summaries, the page's data) give from them
what they give from the rows as dicts, byte for byte; the page's script made figure by figure is that of them all."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from tests.logformat.test_epoch_json import exact

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.logformat.json_codec import std_dumps
from slipdaq.logformat.reader import iter_fast_slip, read_metadata
from slipdaq.offline.run import two_pass_rows
from slipdaq.pipeline import Pipeline
from slipdaq.records.fast_rows import FastRows
from slipdaq.report.labels import labels_metadata
from slipdaq.report.page_data import _Script, log_page, script
from slipdaq.report.summary import summarize_log
from slipdaq.report.traces import HighRate
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks.mcap_log import McapLogSink
from support.paths import CONFIG


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A paved cycle with braking (16 s), logged as a live run logs it."""
    out = tmp_path_factory.mktemp("fast-rows") / "drive.mcap"
    cfg = load_config(CONFIG)
    sink = McapLogSink(out, cfg, "import", metadata=labels_metadata({"road": "paved"}))
    Pipeline(cfg, [sink]).run(e.record for e in generate(cfg, "cycle", "paved", SimSettings(seed=3), duration_s=16.0)
                              if e.record is not None)
    sink.close()
    return out


def test_columns_read_back_as_the_two_pass_replays_rows(log: Path, tmp_path: Path) -> None:
    got = two_pass_rows(log, stream=io.StringIO())
    assert got is not None and isinstance(got.fast, FastRows)
    out = tmp_path / "two-pass.mcap"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["replay", str(log), "--two-pass", "-o", str(out)]) == 0
    logged = [exact(std_dumps(r)) for r in iter_fast_slip(out)]
    assert len(logged) > 1000
    assert [exact(std_dumps(r)) for r in got.fast] == logged


def test_consumers_give_from_columns_what_they_give_from_dicts(log: Path) -> None:
    got = two_pass_rows(log, stream=io.StringIO())
    assert got is not None
    dicts = list(got.fast)
    assert any(r["slip_FL"] is None for r in dicts) and any(r["slip_FL"] is not None for r in dicts)
    a, b = HighRate.of(got.fast), HighRate.of(dicts)
    for x, y in [(a.time_s, b.time_s), (a.speed_mps, b.speed_mps), *((a.slips[w], b.slips[w]) for w in a.slips),
                 *((a.wheel_speeds_mps[w], b.wheel_speeds_mps[w]) for w in a.wheel_speeds_mps)]:
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes()  # bit for bit, NaN where undefined

    def summary(fast: object) -> tuple[object, bytes]:
        s = summarize_log(got.rows, read_metadata(log), got.diagnostics, path=str(log), name="drive", labels={},
                          fast=fast, sensors=got.sensors)  # type: ignore[arg-type]
        return exact(std_dumps([m.as_row() for m in s.records])), log_page(s, fast).script  # type: ignore[arg-type]

    from_columns, from_dicts = summary(got.fast), summary(dicts)
    assert len(from_columns[0]) >= 2 and b"high-rate" in from_columns[1]
    assert from_columns == from_dicts
    assert np.isfinite(a.time_s).all()


@given(st.lists(st.tuples(st.sampled_from(["a/b", "a/overview", "ä/μ", "c"]),
                          st.recursive(st.one_of(st.none(), st.floats(allow_nan=True), st.text(max_size=4),
                                                 st.integers(-(2**40), 2**40)),
                                       lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                               st.dictionaries(st.text(max_size=3), inner, max_size=3)),
                                       max_leaves=8)), max_size=6))
def test_page_script_made_figure_by_figure_is_the_script_of_them_all(figures: list[tuple[str, Any]]) -> None:
    """Each figure encoded as it is made (page_data._Script): the bytes of script() of the dict of them (a name given
    again: its new figure in the first one's place)."""
    out = _Script()
    for name, figure in figures:
        out.add(name, figure)
    assert out.bytes() == script(dict(figures))
