"""Imported by a `slipdaq batch` worker before its first task (fleet_cluster): the task's modules, and its compiled
kernels loaded (compiled.prepare), so that the first task runs as fast as the others. Neither python-can nor
cantools: a task imports them (without asammdf, slipdaq.__main__.import_cantools) only where it parses a DBC whose
wheel layout is not in the cache (decode/layout_cache.py). pyarrow imports pandas at its first array (0.5 s): made
here, not in the first task's Parquet export."""

from __future__ import annotations

import pyarrow
import pyarrow.parquet  # noqa: F401  (the Parquet writer)

import slipdaq.export.parquet_file  # noqa: F401
import slipdaq.fleet.task  # noqa: F401
import slipdaq.offline.run  # noqa: F401
import slipdaq.report.build  # noqa: F401
from slipdaq.compiled import prepare

prepare()
pyarrow.array([0.0])
