"""The estimator: pure (arrays and numbers in, estimates out; no clock, no I/O)."""

from slipdaq.estimator.slip import EstimatorParams, SlipEstimator

__all__ = ["EstimatorParams", "SlipEstimator"]
