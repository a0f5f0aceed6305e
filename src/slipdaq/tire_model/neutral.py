"""What a slipdaq .tir says about what slipdaq does not measure: every other MF 6.1 section and coefficient, so that
an evaluator that reads the whole parameter set (MFeval, TyreDyn, a simulator's tire block) finds each one.

Neutral: no lateral force (PDY1 = 0: no friction sideways), no aligning, overturning or rolling-resistance moment
(their peak and shift terms 0), no pressure or camber effect (PP*, P*3 terms 0), combined slip without interaction
(RBX1 = RBY1 = 0 make the weighting functions G_xa = G_yk = 1, 4.E51 and 4.E59). Where 0 would divide by zero in an
evaluator (the cornering stiffness's load at its peak PKY2, the trail's shape, the radius and stiffness of the
carcass), a typical passenger-car value stands, marked TYPICAL: not measured.
"""

from __future__ import annotations

TYPICAL = "typical value, not measured"
NEUTRAL = "neutral, not measured"

PRESSURE_LONGITUDINAL = {"PPX1": 0.0, "PPX2": 0.0, "PPX3": 0.0, "PPX4": 0.0}
COMBINED_LONGITUDINAL = {"RBX1": 0.0, "RBX2": 0.0, "RBX3": 0.0, "RCX1": 1.0, "REX1": 0.0, "REX2": 0.0, "RHX1": 0.0}
SCALING_OTHERS = ("LCY", "LMUY", "LEY", "LKY", "LKYC", "LKZC", "LHY", "LVY", "LTR", "LRES", "LXAL", "LYKA", "LVYKA",
                  "LS", "LMX", "LVMX", "LMY", "LMP")
"""The scaling factors besides the longitudinal ones (mf61.SCALING_NAMES): all 1."""

_Section = dict[str, tuple[float, str]]

SECTIONS_BEFORE: dict[str, _Section] = {
    "INERTIA": {"MASS": (9.3, TYPICAL), "IXX": (0.391, TYPICAL), "IYY": (0.736, TYPICAL), "BELT_MASS": (7.0, TYPICAL),
                "BELT_IXX": (0.34, TYPICAL), "BELT_IYY": (0.6, TYPICAL), "GRAVITY": (-9.81, "")},
}
"""Sections between [OPERATING_CONDITIONS] and [VERTICAL]."""

VERTICAL_OTHERS: _Section = {
    "VERTICAL_STIFFNESS": (200000.0, TYPICAL), "VERTICAL_DAMPING": (500.0, TYPICAL), "BREFF": (8.4, TYPICAL),
    "DREFF": (0.27, TYPICAL), "FREFF": (0.07, TYPICAL), "Q_RE0": (1.0, NEUTRAL), "Q_V1": (0.0, NEUTRAL),
    "Q_V2": (0.0, NEUTRAL), "Q_FZ2": (15.0, TYPICAL), "Q_FCX": (0.0, NEUTRAL), "Q_FCY": (0.0, NEUTRAL),
    "Q_CAM": (0.0, NEUTRAL), "PFZ1": (0.0, NEUTRAL), "BOTTOM_OFFST": (0.01, TYPICAL),
    "BOTTOM_STIFF": (2000000.0, TYPICAL),
}

SECTIONS_AFTER_VERTICAL: dict[str, _Section] = {
    "STRUCTURAL": {"LONGITUDINAL_STIFFNESS": (300000.0, TYPICAL), "LATERAL_STIFFNESS": (100000.0, TYPICAL),
                   "YAW_STIFFNESS": (5000.0, TYPICAL), "FREQ_LONG": (80.0, TYPICAL), "FREQ_LAT": (40.0, TYPICAL),
                   "FREQ_YAW": (50.0, TYPICAL), "FREQ_WINDUP": (70.0, TYPICAL), "DAMP_LONG": (0.04, TYPICAL),
                   "DAMP_LAT": (0.04, TYPICAL), "DAMP_YAW": (0.04, TYPICAL), "DAMP_WINDUP": (0.04, TYPICAL),
                   "DAMP_RESIDUAL": (0.002, TYPICAL), "DAMP_VLOW": (0.001, TYPICAL), "Q_BVX": (0.0, NEUTRAL),
                   "Q_BVT": (0.0, NEUTRAL), "PCFX1": (0.0, NEUTRAL), "PCFX2": (0.0, NEUTRAL), "PCFX3": (0.0, NEUTRAL),
                   "PCFY1": (0.0, NEUTRAL), "PCFY2": (0.0, NEUTRAL), "PCFY3": (0.0, NEUTRAL), "PCMZ1": (0.0, NEUTRAL)},
    "CONTACT_PATCH": {"Q_RA1": (0.6, TYPICAL), "Q_RA2": (0.8, TYPICAL), "Q_RB1": (1.0, TYPICAL),
                      "Q_RB2": (-1.0, TYPICAL), "ELLIPS_SHIFT": (0.8, TYPICAL), "ELLIPS_LENGTH": (1.0, TYPICAL),
                      "ELLIPS_HEIGHT": (1.0, TYPICAL), "ELLIPS_ORDER": (1.8, TYPICAL),
                      "ELLIPS_MAX_STEP": (0.025, TYPICAL), "ELLIPS_NWIDTH": (10.0, TYPICAL),
                      "ELLIPS_NLENGTH": (10.0, TYPICAL)},
}
"""Sections between [VERTICAL] and the ranges."""

RANGES_OTHER: dict[str, _Section] = {
    "SLIP_ANGLE_RANGE": {"ALPMIN": (-1.5708, "no lateral data: the evaluator's whole range"),
                         "ALPMAX": (1.5708, "no lateral data: the evaluator's whole range")},
    "INCLINATION_ANGLE_RANGE": {"CAMMIN": (-0.1, "camber not measured"), "CAMMAX": (0.1, "camber not measured")},
}

COEFFICIENT_SECTIONS: dict[str, _Section] = {
    "OVERTURNING_COEFFICIENTS": {n: (0.0, NEUTRAL) for n in (
        "QSX1", "QSX2", "QSX3", "QSX4", "QSX5", "QSX6", "QSX7", "QSX8", "QSX9", "QSX10", "QSX11", "QSX12", "QSX13",
        "QSX14", "PPMX1")},
    "LATERAL_COEFFICIENTS": {n: (0.0, NEUTRAL) for n in (
        "PDY1", "PDY2", "PDY3", "PEY1", "PEY2", "PEY3", "PEY4", "PEY5", "PKY3", "PKY5", "PKY6", "PKY7", "PHY1", "PHY2",
        "PVY1", "PVY2", "PVY3", "PVY4", "PPY1", "PPY2", "PPY3", "PPY4", "PPY5", "RBY1", "RBY2", "RBY3", "RBY4", "REY1",
        "REY2", "RHY1", "RHY2", "RVY1", "RVY2", "RVY3", "RVY4", "RVY5", "RVY6")}
    | {"PCY1": (1.3, TYPICAL), "PKY1": (-15.0, TYPICAL), "PKY2": (1.7, TYPICAL), "PKY4": (2.0, TYPICAL),
       "RCY1": (1.0, NEUTRAL)},
    "ROLLING_COEFFICIENTS": {n: (0.0, NEUTRAL) for n in ("QSY1", "QSY2", "QSY3", "QSY4", "QSY5", "QSY6")}
    | {"QSY7": (1.0, NEUTRAL), "QSY8": (0.0, NEUTRAL)},
    "ALIGNING_COEFFICIENTS": {n: (0.0, NEUTRAL) for n in (
        "QBZ2", "QBZ3", "QBZ4", "QBZ5", "QBZ9", "QBZ10", "QDZ1", "QDZ2", "QDZ3", "QDZ4", "QDZ6", "QDZ7", "QDZ8", "QDZ9",
        "QDZ10", "QDZ11", "QEZ1", "QEZ2", "QEZ3", "QEZ4", "QEZ5", "QHZ1", "QHZ2", "QHZ3", "QHZ4", "PPZ1", "PPZ2",
        "SSZ1", "SSZ2", "SSZ3", "SSZ4")}
    | {"QBZ1": (10.0, TYPICAL), "QCZ1": (1.1, TYPICAL)},
}
"""The coefficient sections after [LONGITUDINAL_COEFFICIENTS]."""
