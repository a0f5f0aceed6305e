"""Imported by a `slipdaq batch` worker before its first task (fleet_cluster): the task's modules, and its compiled
kernels loaded (compiled.prepare), so that the first task runs as fast as the others. python-can is imported as the
CLI imports it for every verb but `import` (slipdaq.__main__): without asammdf, whose import (pandas, sympy) took
0.9 s of a worker's 2.6 s of imports, and which no task uses. pyarrow imports pandas at its first array (0.5 s):
made here, not in the first task's Parquet export."""

from __future__ import annotations

from slipdaq.__main__ import import_python_can

import_python_can(with_mf4=False)

import pyarrow  # noqa: E402
import pyarrow.parquet  # noqa: E402, F401  (the Parquet writer)

import slipdaq.export.parquet_file  # noqa: E402, F401
import slipdaq.fleet.task  # noqa: E402, F401
import slipdaq.offline.run  # noqa: E402, F401
import slipdaq.report.build  # noqa: E402, F401
from slipdaq.compiled import prepare  # noqa: E402

prepare()
pyarrow.array([0.0])
