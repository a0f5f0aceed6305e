"""The batch report's tables made as the tasks end: each task encodes its log's share of summary.json and
summary.csv (report.write.log_pieces), the batch joins them. The tables are the bytes `slipdaq report` writes over the
same logs (which makes every piece itself, after reading the logs), and summary.json the bytes json.dumps(indent=1)
writes of its own contents; a re-run with another --group-by makes the pieces the cache holds again (they were made
for the old groups)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import re
from pathlib import Path

import pytest
from test_fleet_batch import drive_logs

from slipdaq.cli import main
from slipdaq.fleet.task import Job, log_identity, process_log
from slipdaq.report.summary import group_of
from slipdaq.report.write import log_pieces, pieces_of

pytest.importorskip("distributed")

DRIVES = (("paved-1", "cycle", "paved", 9.0, 1), ("sand-1", "brake", "sand", 9.0, 3))
GENERATED = re.compile(rb'"generated_utc": "[^"]*"|\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00')
"""The tables' generation times (summary.json's field, index.html's note): the only bytes two runs may differ in."""


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return drive_logs(tmp_path_factory.mktemp("pieces-logs"), DRIVES)


def _tables(report: Path) -> dict[str, bytes]:
    return {n: GENERATED.sub(b"TIME", (report / n).read_bytes()) for n in ("summary.json", "summary.csv", "index.html")}


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(args) == 0
    capsys.readouterr()


def test_the_batch_report_joined_from_the_tasks_pieces_is_the_reports_bytes(
        logs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = [str(logs[n]) for n, *_ in DRIVES]
    _run(["batch", *paths, "-o", str(tmp_path / "fleet"), "--workers", "1"], capsys)
    _run(["report", *paths, "-o", str(tmp_path / "report")], capsys)
    batch, report = _tables(tmp_path / "fleet" / "report"), _tables(tmp_path / "report")
    assert batch == report
    text = (tmp_path / "fleet" / "report" / "summary.json").read_text(encoding="utf-8")
    doc = json.loads(text)
    assert text == json.dumps(doc, indent=1, ensure_ascii=False) + "\n"  # spliced as the encoder writes it
    assert [d["log"] for d in doc["logs"]] == [n for n, *_ in DRIVES] and doc["rows"]
    assert {r["group"] for r in doc["rows"]} == {d["group"] for d in doc["logs"]} == {"driver=sim, road=paved",
                                                                                      "driver=sim, road=sand"}
    table = (tmp_path / "fleet" / "report" / "summary.csv").read_bytes().decode("utf-8")
    again = io.StringIO(newline="")
    csv.writer(again).writerows(csv.reader(io.StringIO(table, newline="")))
    assert table == again.getvalue() and len(table.splitlines()) == 1 + len(doc["rows"])

    # the cache's pieces were made for the default groups: --group-by makes them again, as `report --group-by`
    _run(["batch", *paths, "-o", str(tmp_path / "fleet"), "--workers", "1", "--group-by", "road"], capsys)
    _run(["report", *paths, "-o", str(tmp_path / "report-road"), "--group-by", "road"], capsys)
    assert _tables(tmp_path / "fleet" / "report") == _tables(tmp_path / "report-road") != report
    doc = json.loads((tmp_path / "fleet" / "report" / "summary.json").read_text(encoding="utf-8"))
    assert {d["group"] for d in doc["logs"]} == {"road=paved", "road=sand"}
    assert {r["group"] for r in doc["rows"]} == {"road=paved", "road=sand"}


def test_a_tasks_pieces_are_those_the_report_makes_of_its_result(logs: dict[str, Path]) -> None:
    path = str(logs["sand-1"])
    key, size = log_identity(path, "sand-1")
    r = process_log(Job(path, "sand-1", key, path, png=False, size_bytes=size, group_by=("road",)))
    assert r.error is None and r.summary is not None and r.page is not None and r.pieces is not None
    log = dataclasses.replace(r.summary, group=group_of(r.summary.labels, ("road",)))
    assert log.group == "road=sand"
    ours = log_pieces(log, r.page.plots, {}, r.page.overview)
    assert r.pieces == ours  # made on the worker: what the report would make of the same result
    assert json.loads(r.pieces.json_log)["group"] == "road=sand"
    rows = [json.loads(x) for x in r.pieces.json_rows]
    assert rows and all(x["log"] == "sand-1" and x["group"] == "road=sand" for x in rows)
    assert len(r.pieces.csv.splitlines()) == len(rows)
    kept = pieces_of([log], {"sand-1": r.page.plots}, {"sand-1": {}}, {"sand-1": r.page.overview}, {"sand-1": r.pieces})
    assert kept[0] is r.pieces  # made for what the report has: used as it is
    other = dataclasses.replace(log, group="driver=sim, road=sand")
    remade = pieces_of([other], {"sand-1": r.page.plots}, {"sand-1": {}}, {"sand-1": r.page.overview},
                       {"sand-1": r.pieces})
    assert remade[0] is not r.pieces and json.loads(remade[0].json_log)["group"] == "driver=sim, road=sand"


def test_a_task_writes_dir_only_where_its_worker_sees_the_report_being_built(logs: dict[str, Path],
                                                                            tmp_path: Path) -> None:
    """A worker of --scheduler on another machine does not find the report's build directory (made by the batch under
    a random name): its task returns its files' bytes for the batch to write; where it finds it, it writes them."""
    path, out = str(logs["paved-1"]), tmp_path / "fleet"
    key, size = log_identity(path, "paved-1")
    building = out / "report" / ".slipdaq-build.part"
    job = Job(path, "paved-1", key, path, size_bytes=size, out=str(out), page_dir=str(building))
    elsewhere = process_log(job)
    assert elsewhere.error is None and not elsewhere.written and not elsewhere.placed
    assert elsewhere.parquet and elsewhere.page is not None and elsewhere.page.script
    assert not out.exists()  # nothing written: the batch writes it from the result
    building.mkdir(parents=True)
    here = process_log(job)
    assert here.error is None and here.written and here.placed and here.parquet == b""
    assert (building / "paved-1" / "plots.js").read_bytes() == elsewhere.page.script
    assert (out / "estimates" / f"{job.stem}.parquet").is_file() and (out / "cache" / f"{job.stem}.pickle").is_file()
    assert here.pieces == elsewhere.pieces
