"""`slipdaq batch` on real logs (the pipeline over simulator records, as `import`) and a corrupt file: on a local
cluster of two worker processes, and against a `dask scheduler` and a `dask worker` started here on localhost. The
Parquet files equal the two-pass estimates, the report's tire files (fitted on the cluster) and each log's page data
(written by its task) those of `slipdaq report`; a re-run skips every log (its line says "up to date", no file is
written again: the mtimes are unchanged); a changed log is processed again and replaces its older file."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.export.csv_file import ALL_COLUMNS
from slipdaq.offline.run import process_to_log, two_pass_rows
from slipdaq.report.labels import labels_metadata
from slipdaq.sim.emit import SimSettings, generate
from support.paths import CONFIG

distributed = pytest.importorskip("distributed")

DRIVES = (("paved-1", "cycle", "paved", 10.0, 1), ("paved-2", "cycle", "paved", 9.0, 2),
          ("sand-1", "brake", "sand", 9.0, 3), ("sand-2", "cycle", "sand", 8.0, 4))
START_TIMEOUT_S = 30.0


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Four short logs labelled road=paved/sand, and `corrupt.mcap` (the first 4 kB of a log)."""
    return drive_logs(tmp_path_factory.mktemp("batch-logs"), DRIVES)


def drive_logs(d: Path, drives: tuple[tuple[str, str, str, float, int], ...]) -> dict[str, Path]:
    """Each drive (name, scenario, road, seconds, seed) simulated into d/<name>.mcap (as `import`), labelled
    road=<road>, driver=sim; and d/corrupt.mcap, the first 4 kB of the first."""
    cfg = load_config(CONFIG)
    out: dict[str, Path] = {}
    for name, scenario, road, duration_s, seed in drives:
        records = (ev.record for ev in generate(cfg, scenario, road, SimSettings(seed=seed), duration_s=duration_s)
                   if ev.record is not None)
        with open(os.devnull, "w") as quiet:
            process_to_log(cfg, records, d / f"{name}.mcap", "import", stream=quiet,
                           metadata=labels_metadata({"road": road, "driver": "sim"}))
        out[name] = d / f"{name}.mcap"
    (d / "corrupt.mcap").write_bytes(out[drives[0][0]].read_bytes()[:4096])
    out["corrupt"] = d / "corrupt.mcap"
    return out


def _batch(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], str]:
    rc = main(["batch", *args])
    got = capsys.readouterr()
    return rc, got.err.splitlines(), got.out


def _same(a: object, b: object) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def _check_outputs(out: Path, logs: dict[str, Path], names: list[str], png: bool = False) -> None:
    """One Parquet file per log, equal to its two-pass estimates; the fleet table and the report (one page, each
    log's plot data beside it; with png the PNGs)."""
    files = sorted((out / "estimates").glob("*.parquet"))
    assert sorted(f.name.rsplit("-", 1)[0] for f in files) == sorted(names)
    for f in files:
        name = f.name.rsplit("-", 1)[0]
        table = pq.read_table(f)
        with open(os.devnull, "w") as quiet:
            got_rows = two_pass_rows(logs[name], stream=quiet)
        assert got_rows is not None
        expected = got_rows.rows
        assert table.num_rows == len(expected) > 20
        for c in ALL_COLUMNS:
            got = table.column(c).to_pylist()
            assert all(_same(g, r.get(c)) for g, r in zip(got, expected)), (name, c)
        assert set(table.column("log").to_pylist()) == {name}
        assert set(table.column("label_road").to_pylist()) == {name.split("-")[0]}
    with (out / "report" / "summary.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["log"] for r in rows} == set(names)
    assert all(len({r["wheel"] for r in rows if r["log"] == n}) == 4 for n in names)
    index = (out / "report" / "index.html").read_text()
    assert all(n in index for n in names)
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert summary["comparison"] and all((out / "report" / n / "plots.js").is_file() for n in names)
    assert (out / "report" / "plotly.min.js").is_file() and (out / "report" / "compare.js").is_file()
    assert index.count('data-slipdaq-table="maneuvers"') == 1
    assert index.count("<tr data-href=") == sum(len(log["maneuvers"]) for log in summary["logs"])
    pngs = {p.relative_to(out / "report").as_posix() for p in (out / "report").rglob("*.png")}
    if png:
        per_maneuver = {f for log in summary["logs"] for m in log["maneuvers"] for f in m["pngs"].values()}
        assert len(per_maneuver) == 6 * sum(len(log["maneuvers"]) for log in summary["logs"])
        assert len(summary["comparison"]) >= 2 and pngs == per_maneuver | {c["png"] for c in summary["comparison"]}
    else:
        assert pngs == set()


def _client_time(err: list[str]) -> list[float]:
    """The batch's line of where its time went: tasks summed, all, outside the tasks, then its parts (cluster start,
    planning, results, report, cluster stop), in seconds."""
    line = next(line for line in err if line.startswith("batch: ") and "in the tasks (summed)" in line)
    got = [float(x) for x in re.findall(r"([\d.]+) s\b", line)]
    assert len(got) == 8, line
    return got


def test_batch_on_a_local_cluster_skip_rule_and_a_failing_log(logs: dict[str, Path], tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    good = [n for n in logs if n != "corrupt"]
    out = tmp_path / "fleet"
    args = [*(str(logs[n]) for n in (*good[:2], "corrupt", *good[2:])), "-o", str(out), "--workers", "2", "--png"]
    rc, err, stdout = _batch(args, capsys)
    assert rc == 1  # the corrupt log failed, the others went on
    assert sum("FAILED" in line and "corrupt.mcap" in line for line in err) == 1
    assert any(line.startswith("slipdaq: batch: failed: ") and "corrupt.mcap" in line for line in err)
    assert len([line for line in err if line.startswith("batch: [")]) == 5
    assert "4 processed, 0 up to date, 1 failed" in stdout
    _check_outputs(out, logs, good, png=True)
    tasks, total, outside, start, _, _, report, _ = _client_time(err)
    assert 0 < tasks and 0 < outside < total and 0 < start < outside  # the time the batch process spent itself
    assert main(["report", *(str(logs[n]) for n in good), "-o", str(tmp_path / "report")]) == 0
    capsys.readouterr()
    tires = {p.relative_to(out / "report").as_posix(): p.read_bytes() for p in (out / "report" / "tires").rglob("*.tir")}
    assert any(p.endswith(".tir") for p in tires)  # fitted on the cluster, byte for byte those of `slipdaq report`
    assert tires == {p.relative_to(tmp_path / "report").as_posix(): p.read_bytes()
                     for p in (tmp_path / "report" / "tires").rglob("*.tir")}
    for n in good:  # each log's page data, written by its task where the report was built: `slipdaq report`'s
        assert (out / "report" / n / "plots.js").read_bytes() == (tmp_path / "report" / n / "plots.js").read_bytes()

    written = {p: p.stat().st_mtime_ns for p in (*(out / "estimates").iterdir(), *(out / "cache").iterdir())}
    rc, err, stdout = _batch(args, capsys)
    assert rc == 1 and "0 processed, 4 up to date, 1 failed" in stdout
    tasks, total, outside, start, _, _, _, stop = _client_time(err)
    assert tasks == start == stop == 0 and outside == pytest.approx(total, abs=0.06)  # no cluster: all the process's
    assert sum("up to date" in line for line in err) == 4
    assert {p: p.stat().st_mtime_ns for p in written} == written  # not written again
    assert set((out / "estimates").iterdir()) | set((out / "cache").iterdir()) == set(written)
    _check_outputs(out, logs, good, png=True)

    os.utime(logs["sand-2"], ns=(time.time_ns(), time.time_ns()))  # changed: processed again, older file removed
    rc, err, stdout = _batch([*(str(logs[n]) for n in good), "-o", str(out), "--workers", "1", "--png"], capsys)
    assert rc == 0 and "1 processed, 3 up to date, 0 failed" in stdout
    assert len(list((out / "estimates").glob("sand-2-*.parquet"))) == 1
    assert len(list((out / "cache").glob("sand-2-*.pickle"))) == 1
    assert all(written[p] == p.stat().st_mtime_ns for p in written if not p.name.startswith("sand-2-"))
    _check_outputs(out, logs, good, png=True)


@contextlib.contextmanager
def _process(args: list[str], log: Path) -> Iterator[subprocess.Popen[bytes]]:
    """A child process (its output in `log`), terminated at the end (killed if it does not stop in 10 s)."""
    with log.open("wb") as fh:
        proc = subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT)
        try:
            yield proc
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


def _unshared_dir_works(d: Path) -> bool:
    """A process can be started with an empty tmpfs over d (a mount namespace of its own: root, unshare)."""
    d.mkdir(parents=True, exist_ok=True)
    try:
        return subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                               f"mount -t tmpfs none '{d}'"], capture_output=True, timeout=20).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


@pytest.mark.parametrize("worker_sees_dir", [True, False], ids=["worker-sees-dir", "worker-elsewhere"])
def test_batch_against_a_scheduler_and_a_worker_on_localhost(logs: dict[str, Path], tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str],
                                                             worker_sees_dir: bool) -> None:
    """A worker that sees DIR writes its log's files there itself; one that does not (an empty tmpfs over DIR in its
    own mount namespace, as on another machine) returns them and the batch writes them: the same outputs."""
    dask = [sys.executable, "-m", "dask"]
    out = tmp_path / "fleet"
    elsewhere: list[str] = []
    if not worker_sees_dir:
        if not _unshared_dir_works(out):
            pytest.skip("no mount namespace here (unshare, root)")
        elsewhere = ["unshare", "--mount", "--propagation", "private", "sh", "-c",
                     f"mount -t tmpfs none '{out}' && exec \"$@\"", "worker"]
    info = tmp_path / "scheduler.json"
    with _process([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                   "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(info)], tmp_path / "scheduler.log"):
        deadline = time.monotonic() + START_TIMEOUT_S
        while not info.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert info.is_file(), (tmp_path / "scheduler.log").read_text()
        address = json.loads(info.read_text())["address"]
        with _process([*elsewhere, *dask, "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                       "--death-timeout", "30"], tmp_path / "worker.log"):
            with distributed.Client(address, timeout=START_TIMEOUT_S) as client:
                client.wait_for_workers(1, timeout=START_TIMEOUT_S)  # else batch would wait for one
            good = ["paved-1", "sand-1"]
            rc, err, stdout = _batch([*(str(logs[n]) for n in good), "-o", str(out), "--scheduler", address], capsys)
    assert rc == 0, err
    assert "2 processed, 0 up to date, 0 failed" in stdout
    _check_outputs(out, logs, good)


def test_batch_without_dask_says_what_to_install(logs: dict[str, Path], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)  # `import distributed` fails as if it were not installed
    rc, err, _ = _batch([str(logs["paved-1"]), "-o", str(tmp_path / "fleet")], capsys)
    assert rc == 1
    assert err[-1].startswith("slipdaq: batch: needs the fleet extra") and '".[fleet]"' in err[-1]


class _InterruptedStream(io.StringIO):
    """A progress stream where Ctrl-C arrives while the second log's line is printed."""

    def write(self, text: str) -> int:
        if text.startswith("batch: [2/"):
            raise KeyboardInterrupt
        return super().write(text)


def test_an_interrupted_batch_leaves_the_report_as_it_was(logs: dict[str, Path], tmp_path: Path) -> None:
    """The report is built as the logs come: a batch interrupted after its first log leaves DIR/report as the last
    finished batch wrote it (no file replaced: their mtimes unchanged; no half-built directory left)."""
    from slipdaq.fleet.batch import run_batch

    out = tmp_path / "fleet"
    good = [logs["paved-1"], logs["sand-1"]]
    run_batch(good, out, workers=1, stream=io.StringIO())
    before = {p: p.stat().st_mtime_ns for p in (out / "report").rglob("*") if p.is_file()}
    assert (out / "report" / "index.html") in before
    os.utime(logs["paved-1"])  # both processed again
    os.utime(logs["sand-1"])
    with pytest.raises(KeyboardInterrupt):
        run_batch(good, out, workers=1, stream=_InterruptedStream())
    after = {p: p.stat().st_mtime_ns for p in (out / "report").rglob("*") if p.is_file()}
    assert after == before
    assert not list(out.rglob(".slipdaq-*"))
