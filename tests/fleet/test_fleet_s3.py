"""`slipdaq batch` with logs and outputs on object storage: a real S3 API server (moto's, in a thread of this process,
on a free localhost port), reached through s3fs by this process and by the Dask workers, its endpoint and keys from
the environment only (AWS_ENDPOINT_URL in process; FSSPEC_S3_ENDPOINT_URL for the CLI in a child process).

Simulated logs are uploaded to s3://logs-bucket/day1/; `batch 's3://logs-bucket/day1/*.mcap' -o s3://logs-bucket/out`
writes one Parquet object per log (read back with pyarrow through s3fs: the two-pass estimates), the cache objects and
the report (summary.json, index.html, each log's plots.js); a re-run finds every log up to date and writes nothing; a
log replaced by other contents is processed again and its older objects removed; a log at a URL with a local DIR
works; bad URLs are one line and exit status 1. And on local paths: the local cluster's tasks write their own files."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_fleet_batch import drive_logs

from slipdaq.cli import main
from slipdaq.export.csv_file import ALL_COLUMNS
from slipdaq.offline.run import two_pass_rows

pytest.importorskip("distributed")
pq = pytest.importorskip("pyarrow.parquet")
s3fs = pytest.importorskip("s3fs")
moto_server = pytest.importorskip("moto.server")
boto3 = pytest.importorskip("boto3")

BUCKET = "logs-bucket"
DRIVES = (("paved-1", "cycle", "paved", 8.0, 1), ("sand-1", "brake", "sand", 8.0, 3))
KEYS = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two short logs labelled road=paved/sand, and `corrupt.mcap` (the first 4 kB of a log)."""
    return drive_logs(tmp_path_factory.mktemp("s3-logs"), DRIVES)


@pytest.fixture
def s3(monkeypatch: pytest.MonkeyPatch, logs: dict[str, Path]) -> Iterator[str]:
    """The S3 server's endpoint, in the environment (inherited by the Dask workers), the logs in s3://BUCKET/day1/."""
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        endpoint = f"http://{host}:{port}"
        for k in ("AWS_PROFILE", "AWS_SESSION_TOKEN", "AWS_CONFIG_FILE", "AWS_SHARED_CREDENTIALS_FILE"):
            monkeypatch.delenv(k, raising=False)
        for k, v in KEYS.items():
            monkeypatch.setenv(k, v)
        monkeypatch.setenv("AWS_ENDPOINT_URL", endpoint)
        client = boto3.client("s3", endpoint_url=endpoint)
        client.create_bucket(Bucket=BUCKET)
        for name, p in logs.items():
            client.upload_file(str(p), BUCKET, f"day1/{name}.mcap")
        s3fs.S3FileSystem.clear_instance_cache()
        yield endpoint
    finally:
        server.stop()


def _fs(endpoint: str) -> s3fs.S3FileSystem:
    return s3fs.S3FileSystem(key="testing", secret="testing", endpoint_url=endpoint, skip_instance_cache=True)


def _batch(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str], str]:
    rc = main(["batch", *args])
    got = capsys.readouterr()
    return rc, got.err.splitlines(), got.out


def _same(a: object, b: object) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def _objects(fs: s3fs.S3FileSystem, prefix: str) -> dict[str, str]:
    """Every object under the prefix with its ETag (a rewrite of the same bytes changes LastModified: both kept)."""
    fs.invalidate_cache()
    return {p: f"{i['ETag']} {i['LastModified']}" for p, i in fs.find(prefix, detail=True).items()}


def _check_parquet(fs: s3fs.S3FileSystem, logs: dict[str, Path], names: list[str], contents: dict[str, str]) -> None:
    fs.invalidate_cache()  # listings of an earlier check
    files = sorted(fs.glob(f"{BUCKET}/out/estimates/*.parquet"))
    assert sorted(f.rsplit("/", 1)[1].rsplit("-", 1)[0] for f in files) == sorted(names)
    for f in files:
        name = f.rsplit("/", 1)[1].rsplit("-", 1)[0]
        table = pq.read_table(f, filesystem=fs)
        with open(os.devnull, "w") as quiet:
            got_rows = two_pass_rows(logs[contents.get(name, name)], stream=quiet)
        assert got_rows is not None
        assert table.num_rows == len(got_rows.rows) > 20
        for c in ALL_COLUMNS:
            assert all(_same(g, r.get(c)) for g, r in zip(table.column(c).to_pylist(), got_rows.rows)), (name, c)
        assert set(table.column("log").to_pylist()) == {name}


def test_batch_from_and_to_s3(s3: str, logs: dict[str, Path], tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    fs = _fs(s3)
    good = ["paved-1", "sand-1"]
    args = [f"s3://{BUCKET}/day1/*.mcap", "-o", f"s3://{BUCKET}/out", "--workers", "1"]
    rc, err, stdout = _batch(args, capsys)
    assert rc == 1, err  # corrupt.mcap failed, the others went on
    assert "2 processed, 0 up to date, 1 failed" in stdout and f"s3://{BUCKET}/out/estimates" in stdout
    assert f"report s3://{BUCKET}/out/report/index.html" in stdout
    assert sum("FAILED" in line and f"s3://{BUCKET}/day1/corrupt.mcap" in line for line in err) == 1
    assert sum(f"-> s3://{BUCKET}/out/estimates/" in line for line in err) == 2
    _check_parquet(fs, logs, good, {})
    summary = json.loads(fs.cat_file(f"{BUCKET}/out/report/summary.json"))
    assert sorted(log["log"] for log in summary["logs"]) == good
    assert sorted(log["path"] for log in summary["logs"]) == [f"s3://{BUCKET}/day1/{n}.mcap" for n in good]
    assert summary["comparison"]
    assert all(fs.exists(f"{BUCKET}/out/report/{n}/plots.js") for n in good)
    index = fs.cat_file(f"{BUCKET}/out/report/index.html").decode()
    assert all(n in index for n in good)
    assert len(fs.glob(f"{BUCKET}/out/cache/*.pickle")) == 2
    assert not fs.glob(f"{BUCKET}/out/cache/.slipdaq-probe-*")

    # a re-run, by the CLI in a child process with the endpoint from fsspec's variable only: every log up to date
    written = _objects(fs, f"{BUCKET}/out/estimates") | _objects(fs, f"{BUCKET}/out/cache")
    env = {k: v for k, v in os.environ.items() if k != "AWS_ENDPOINT_URL"} | {"FSSPEC_S3_ENDPOINT_URL": s3}
    cli = [sys.executable, "-c", "import sys; from slipdaq.cli import main; sys.exit(main())"]
    done = subprocess.run([*cli, "batch", *args], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert "0 processed, 2 up to date, 1 failed" in done.stdout
    assert sum("up to date" in line for line in done.stderr.splitlines()) == 2
    assert _objects(fs, f"{BUCKET}/out/estimates") | _objects(fs, f"{BUCKET}/out/cache") == written

    # sand-1 replaced by other contents: processed again, its older objects removed
    fs.put_file(str(logs["paved-1"]), f"{BUCKET}/day1/sand-1.mcap")
    rc, err, stdout = _batch([f"s3://{BUCKET}/day1/[ps]*.mcap", *args[1:]], capsys)
    assert rc == 0, err
    assert "1 processed, 1 up to date, 0 failed" in stdout
    fs.invalidate_cache()
    assert len(fs.glob(f"{BUCKET}/out/estimates/sand-1-*.parquet")) == 1
    assert len(fs.glob(f"{BUCKET}/out/cache/sand-1-*.pickle")) == 1
    _check_parquet(fs, logs, good, {"sand-1": "paved-1"})

    # a log URL that does not exist is a failed log, as a path is; the other one is up to date (no cluster started)
    rc, err, stdout = _batch([f"s3://{BUCKET}/day1/paved-1.mcap", f"s3://{BUCKET}/day1/nope.mcap", *args[1:]], capsys)
    assert rc == 1 and "0 processed, 1 up to date, 1 failed" in stdout
    assert err[-1] == f"slipdaq: batch: failed: s3://{BUCKET}/day1/nope.mcap: no such file"

    # a log at a URL, the outputs in a local directory
    local = tmp_path / "local"
    rc, err, stdout = _batch([f"s3://{BUCKET}/day1/paved-1.mcap", "-o", str(local), "--workers", "1"], capsys)
    assert rc == 0, err
    assert len(list((local / "estimates").glob("paved-1-*.parquet"))) == 1
    assert (local / "report" / "summary.json").is_file()


@pytest.mark.parametrize("logs_url,out_url,says", [
    ("nosuchproto://x/*.mcap", f"s3://{BUCKET}/out", "nosuchproto"),
    ("s3://no-such-bucket/day1/*.mcap", f"s3://{BUCKET}/out", "s3://no-such-bucket/day1/*.mcap"),
    (f"s3://{BUCKET}/day2/*.mcap", f"s3://{BUCKET}/out", "matches no file"),
    (f"s3://{BUCKET}/day1/paved-1.mcap", "s3://no-such-bucket/out", "s3://no-such-bucket/out: cannot write there"),
])
def test_bad_urls_are_one_line(s3: str, logs_url: str, out_url: str, says: str,
                               capsys: pytest.CaptureFixture[str]) -> None:
    rc, err, stdout = _batch([logs_url, "-o", out_url, "--workers", "1"], capsys)
    assert rc == 1
    assert len(err) == 1 and err[0].startswith("slipdaq: batch: ") and says in err[0], err
    assert stdout == ""


def test_tasks_of_the_local_cluster_write_their_own_files(logs: dict[str, Path], tmp_path: Path) -> None:
    """Local paths, a local DIR: each task writes its Parquet and cache files (the client gets the summary only)."""
    from slipdaq.fleet.batch import run_batch

    out = tmp_path / "fleet"
    with open(os.devnull, "w") as quiet:
        res = run_batch([logs["paved-1"], logs["sand-1"]], out, workers=1, stream=quiet)
    assert not res.failed and len(res.done) == 2
    assert all(r.written and r.parquet == b"" and r.summary is not None for r in res.done)
    assert sorted(p.name.rsplit("-", 1)[0] for p in (out / "estimates").glob("*.parquet")) == ["paved-1", "sand-1"]
    assert len(list((out / "cache").glob("*.pickle"))) == 2
    assert not [p for p in out.rglob(".*.part")]
    assert (out / "report" / "index.html").is_file() and res.report == out / "report" / "index.html"
    assert res.estimates == str(out / "estimates")
