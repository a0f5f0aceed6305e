"""`slipdaq export`: a log's estimates, high-rate slip and GPS into other formats, one writer per format behind one
interface (a registry by name, as python-can's by suffix): csv, fast_csv, maneuvers_csv, imu_csv, mf4, parquet. A
writer takes the log's streams (LogStreams, read on demand) and a path, and returns how many rows it wrote."""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from slipdaq.logformat.reader import iter_estimates, iter_fast_slip, iter_topic, read_metadata
from slipdaq.logformat.salvage import ScanResult
from slipdaq.logformat.topics import TOPIC_GPS, TOPIC_MANEUVER, TOPIC_SENSORS, TOPIC_TEST_SET
from slipdaq.outputs import OutputError, refuse_inputs, same_file
from slipdaq.report.labels import labels_of
from slipdaq.sources.read_errors import guarded


class LogStreams:
    """What a writer takes of a log: its metadata and, each time asked, its estimates, /slip/fast rows and fixes."""

    def __init__(self, log: str | Path) -> None:
        self.log = Path(log)
        self.metadata = read_metadata(log)
        self.labels = labels_of(self.metadata)
        self.scanned = ScanResult(self.log)

    def estimates(self) -> Iterator[dict[str, Any]]:
        return guarded(self.log, iter_estimates(self.log, self.scanned))

    def fast_rows(self) -> Iterator[dict[str, Any]]:
        return guarded(self.log, iter_fast_slip(self.log, self.scanned))

    def fixes(self) -> Iterator[dict[str, Any]]:
        return guarded(self.log, (d for _topic, _t, d in iter_topic(self.log, (TOPIC_GPS,), self.scanned)))

    def imu_rows(self) -> Iterator[dict[str, Any]]:
        """The forward acceleration the estimator took from the IMU (on CAN or serial): time_s, accel_mps2."""
        return guarded(self.log, ({"time_s": d["time_s"], "accel_mps2": d["value"]}
                                  for _topic, _t, d in iter_topic(self.log, (TOPIC_SENSORS,), self.scanned)
                                  if d.get("kind") == "imu_accel"))

    def maneuvers(self) -> Iterator[dict[str, Any]]:
        return guarded(self.log, (d for _topic, _t, d in iter_topic(self.log, (TOPIC_MANEUVER,), self.scanned)))

    def test_sets(self) -> list[dict[str, Any]]:
        """The last /test_set record of each set, in the order the sets first came."""
        last: dict[str, dict[str, Any]] = {}
        for _topic, _t, d in guarded(self.log, iter_topic(self.log, (TOPIC_TEST_SET,), self.scanned)):
            last[d["procedure"]] = d
        return list(last.values())


def _csv(log: LogStreams, path: Path) -> int:
    from slipdaq.export.csv_file import ALL_COLUMNS, write_csv

    return write_csv(log.estimates(), path, ALL_COLUMNS)


def _fast_csv(log: LogStreams, path: Path) -> int:
    from slipdaq.export.csv_file import FAST_COLUMNS, write_csv

    return write_csv(log.fast_rows(), path, FAST_COLUMNS)


def _maneuvers_csv(log: LogStreams, path: Path) -> int:
    from slipdaq.export.csv_file import MANEUVER_CSV_COLUMNS, write_csv

    return write_csv(log.maneuvers(), path, MANEUVER_CSV_COLUMNS)


def _sets_csv(log: LogStreams, path: Path) -> int:
    from slipdaq.export.csv_file import write_csv
    from slipdaq.maneuver.test_set import TEST_SET_CSV_COLUMNS, csv_row

    return write_csv((csv_row(r) for r in log.test_sets()), path, TEST_SET_CSV_COLUMNS)


def _imu_csv(log: LogStreams, path: Path) -> int:
    from slipdaq.export.csv_file import IMU_CSV_COLUMNS, write_csv

    return write_csv(log.imu_rows(), path, IMU_CSV_COLUMNS)


def _mf4(log: LogStreams, path: Path) -> int:
    from slipdaq.export.mf4_file import write_mf4

    return write_mf4(log.estimates(), path, fast_rows=log.fast_rows(), fixes=log.fixes(), metadata=log.metadata,
                     log_name=log.log.name, labels=log.labels)


def _parquet(log: LogStreams, path: Path) -> int:
    from slipdaq.export.parquet_file import write_parquet

    return write_parquet(log.estimates(), path, log_name=log.log.stem, labels=log.labels)


@dataclass(frozen=True)
class ExportFormat:
    flag: str
    what: str
    """What a row is, for messages ("estimates")."""
    write: Callable[[LogStreams, Path], int]
    needs: tuple[str, str] | None = None
    """(module, extra) it needs installed."""
    empty_note: str = ""
    """Said when the log has no rows for it."""


FORMATS: dict[str, ExportFormat] = {
    "csv": ExportFormat("--csv", "estimates", _csv),
    "fast_csv": ExportFormat("--fast-csv", "high-rate slip rows", _fast_csv, empty_note=(
        " (a log recorded with estimator.fast_rate_hz = 0, or before there was one: `slipdaq replay` it)")),
    "maneuvers_csv": ExportFormat("--maneuvers-csv", "maneuvers", _maneuvers_csv, empty_note=(
        " (no accelerate or brake maneuver ended in it, or a log recorded before they were logged: `slipdaq replay` "
        "it)")),
    "sets_csv": ExportFormat("--sets-csv", "test sets", _sets_csv, empty_note=(
        " (no [[test.procedure]] in its config took a maneuver)")),
    "imu_csv": ExportFormat("--imu-csv", "IMU samples", _imu_csv, empty_note=(
        " (no IMU: neither [imu] on CAN nor an MTi on serial)")),
    "mf4": ExportFormat("--mf4", "estimates", _mf4, needs=("asammdf", "mdf")),
    "parquet": ExportFormat("--parquet", "estimates", _parquet, needs=("pyarrow", "fleet")),
}
"""By the CLI option's name (its dest)."""


def check_outputs(outputs: dict[str, str], log: str | Path, tir_dir: str | None = None) -> None:
    """OutputError (usage) for no output, two outputs naming one file, an output that is the log, a format whose
    library is not installed; before anything is read or written. tir_dir: --tir's directory."""
    if not outputs and not tir_dir:
        raise OutputError("export: give " + ", ".join(f.flag for f in FORMATS.values()) + ", --tir"
                          " (any of them at once)")
    if tir_dir:
        refuse_inputs([tir_dir], [log])
    named = [(FORMATS[k].flag, out) for k, out in outputs.items()]
    for i, (flag, out) in enumerate(named):
        for other, earlier in named[:i]:
            if same_file(out, earlier):
                raise OutputError(f"export: {other} and {flag} name the same file {out}")
    refuse_inputs(list(outputs.values()), [log])
    for k, out in outputs.items():
        needs = FORMATS[k].needs
        if needs is not None and importlib.util.find_spec(needs[0]) is None:
            raise OutputError(f"export {out}: needs {needs[0]}: pip install 'slipdaq[{needs[1]}]'")
