"""The kernels of slipdaq: every Kernel made so far (compiled.kernel appends), and the modules that define them,
imported by name where every kernel is needed (the module compiled ahead of time and its key: ahead.py)."""

from __future__ import annotations

import importlib
from typing import Any

KERNELS: list[Any] = []
"""Every compiled.Kernel made so far, in the order made."""

KERNEL_MODULES = (
    "slipdaq.decode.wheel_unwrap",
    "slipdaq.estimator.fast_slip",
    "slipdaq.estimator.gps_track",
    "slipdaq.estimator.latency",
    "slipdaq.estimator.linear_region",
    "slipdaq.estimator.readiness",
    "slipdaq.estimator.reference_speed",
    "slipdaq.estimator.ring",
    "slipdaq.estimator.smoother",
    "slipdaq.estimator.wheel_revolutions",
    "slipdaq.maneuver.linearity",
)
"""The modules that define a kernel (tests/compiled/test_ahead.py checks the list against every module of
slipdaq). Named, not imported: they import this package."""


def all_kernels() -> list[Any]:
    """Every kernel of slipdaq (KERNEL_MODULES imported)."""
    for name in KERNEL_MODULES:
        importlib.import_module(name)
    return list(KERNELS)
