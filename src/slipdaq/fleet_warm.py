"""Imported by a `slipdaq batch` worker before its first task (fleet_cluster): the task's modules, and its compiled
kernels loaded (compiled.prepare), so that the first task runs as fast as the others."""

from __future__ import annotations

import pyarrow.parquet  # noqa: F401  (the Parquet writer)

import slipdaq.fleet_task  # noqa: F401
import slipdaq.offline  # noqa: F401
import slipdaq.report.build  # noqa: F401
import slipdaq.sinks.parquet_export  # noqa: F401
from slipdaq.compiled import prepare

prepare()
