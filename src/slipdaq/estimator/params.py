"""The estimator's inputs from the config, flat (EstimatorParams)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from slipdaq.config import Config

CAN_EPOCH_INTERVAL_S = 0.1
"""Windows of a reference speed on CAN are centred this far apart (EstimatorParams.epoch_interval_s)."""


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """The estimator's inputs from the config, flat. No defaults here: they are the config models' (config.py)."""

    window_s: float
    min_speed_mps: float
    cx_slip_min: float
    cx_slip_max: float
    cx_fit_slip_spread_max: float
    """A window whose wheel slip varies more than this within it stays out of the stiffness fit (linear_region.py)."""
    mass_kg: float
    driven_axle: str
    brake_front_share: float
    pulses_per_rev: int
    r_ref_m: float
    r_ref_configured: bool
    """True when r_ref is tire.free_radius_m rather than the tire size."""
    gps_latency_s: float | None
    """Fixed GPS latency; None estimates it online ('auto')."""
    max_latency_s: float
    calibrate_r0: bool
    r0_min_speed_mps: float
    fit_min_speed_mps: float
    rolling_resistance_coeff: float
    drag_area_m2: float
    air_density_kgpm3: float
    road_loads_configured: bool
    """The config gives rolling_resistance_coeff or drag_area_m2 (above 0): they win over a calibration's road loads
    (by value, not by key: a log stores its config with every key)."""
    rotating_mass_factor: float
    grade_from_altitude: bool
    fast_rate_hz: float
    """The high-rate slip's grid (0: none)."""
    epoch_interval_s: float
    """Reference fixes closer than this to the last estimated one make no window of their own (a CAN reference at
    100 Hz: windows at 10 Hz, as from a GPS receiver); 0: every fix."""

    @classmethod
    def from_config(cls, cfg: Config, **overrides: Any) -> EstimatorParams:
        """The parameters of cfg; overrides replace single values (tests)."""
        v, e = cfg.vehicle, cfg.estimator
        return replace(cls(
            window_s=e.window_s, min_speed_mps=e.min_speed_mps, cx_slip_min=e.cx_slip_min, cx_slip_max=e.cx_slip_max,
            cx_fit_slip_spread_max=e.cx_fit_slip_spread_max,
            mass_kg=v.mass_kg, driven_axle=v.driven_axle, brake_front_share=v.brake_front_share,
            pulses_per_rev=cfg.wpt.pulses_per_rev, r_ref_m=cfg.tire.radius_m,
            r_ref_configured=cfg.tire.free_radius_m is not None, gps_latency_s=cfg.latency_fixed_s,
            max_latency_s=e.max_latency_s, calibrate_r0=e.calibrate_r0, r0_min_speed_mps=e.r0_min_speed_mps,
            fit_min_speed_mps=e.fit_min_speed_mps, rolling_resistance_coeff=v.rolling_resistance_coeff,
            drag_area_m2=v.drag_area_m2, air_density_kgpm3=v.air_density_kgpm3,
            road_loads_configured=v.rolling_resistance_coeff > 0.0 or v.drag_area_m2 > 0.0,
            rotating_mass_factor=v.rotating_mass_factor,
            grade_from_altitude=e.grade_from_altitude, fast_rate_hz=e.fast_rate_hz,
            epoch_interval_s=CAN_EPOCH_INTERVAL_S if cfg.gps.source == "can" else 0.0,
        ), **overrides)
