"""Estimator parameters for unit tests of the estimator alone."""

from __future__ import annotations

from typing import Any

from slipdaq.config import Config
from slipdaq.estimator import EstimatorParams


def params(**overrides: Any) -> EstimatorParams:
    """The config's defaults, except what these tests isolate: a fixed GPS latency of 0 and the tire's radius as r0
    (no online calibration); then the test's own values."""
    return EstimatorParams.from_config(Config(), **({"gps_latency_s": 0.0, "calibrate_r0": False} | overrides))
