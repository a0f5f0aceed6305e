"""Imported by a `slipdaq batch` worker before its first task (fleet_cluster): the task's modules, and its compiled
kernels loaded (compiled.prepare), so that the first task runs as fast as the others."""

from __future__ import annotations

import pyarrow.parquet  # noqa: F401  (the Parquet writer)

import slipdaq.export.parquet_file  # noqa: F401
import slipdaq.fleet.task  # noqa: F401
import slipdaq.offline.run  # noqa: F401
import slipdaq.report.build  # noqa: F401
from slipdaq.compiled import prepare

prepare()
