"""The calibration a run works with: the stored one it starts from (latency, r0 and Cx per wheel) and its own radius
and stiffness fits; which of them is in use, where the run contradicts a stored value (dropped, with an event), and
what the run learned (Learned)."""

from __future__ import annotations

import math

from slipdaq import WHEELS
from slipdaq.config.calibration import Calibration, Learned
from slipdaq.estimator.force import RoadLoads
from slipdaq.estimator.latency import LatencyEstimate, UtcLatency, WheelLatency
from slipdaq.estimator.params import EstimatorParams
from slipdaq.estimator.phase import PHASE_ACCEL_MPS2
from slipdaq.estimator.radius import RadiusCalibration, r0_per_wheel
from slipdaq.estimator.stiffness import StiffnessFit
from slipdaq.records import SourceEvent

STORED_LATENCY_SIGMA_S = 0.01
"""A stored latency without its sigma counts as this uncertain."""
UTC_LATENCY_SIGMA_S = 0.005
"""The UTC method's latency counts as this uncertain (NMEA times to 0.01 s, the host clock's own jitter)."""
LATENCY_TOLERANCE_S = 0.005
R0_TOLERANCE_M = 0.001
"""A radius changes by this much with tire temperature and pressure within a day (0.3 bar: about 1 mm), and a run's
own radius early on can be a few tenths of a mm off by more than its standard error says: not a contradiction."""
CX_CONFIDENT = 0.5
"""A stiffness fit this confident is stored."""
CX_CONTRADICTS = 0.8
CX_TOLERANCE = 0.2
"""A fit this confident contradicts a stored Cx when they differ by more than 3 sigma and CX_TOLERANCE: the fit's
confidence understates its spread from run to run (the same car and road: +-15 % within the first half minute), and
Cx changes with the road and the tire's temperature."""


def cx_relative_se(confidence: float) -> float:
    """The relative standard error of a fitted Cx from its confidence (stiffness.py: 1 - 10 * relative SE)."""
    return (1.0 - confidence) / 10.0


class RunCalibration:
    """The stored calibration (used until the run measures better, dropped where the run contradicts it) and the
    run's own radius and stiffness fits per wheel. frozen: the stored latency and radii throughout, nothing learned
    (the second pass of a replay)."""

    def __init__(self, params: EstimatorParams, stored: Calibration | None, frozen: bool,
                 reference: tuple[str, ...]) -> None:
        self.p = params
        self.frozen = frozen and stored is not None
        self.reference = reference
        """The non-driven wheels."""
        self.stored_latency = (stored.latency.latency_s, stored.latency.sigma_s or STORED_LATENCY_SIGMA_S) \
            if stored is not None and stored.latency is not None and params.gps_latency_s is None else None
        self.stored_r0: dict[str, tuple[float, float]] = {w: (r.radius_m, r.se_m) for w, r in stored.r0.items()} \
            if stored is not None and params.calibrate_r0 else {}
        self.stored_cx: dict[str, tuple[float, float]] = \
            {w: (c.cx_n, c.confidence) for w, c in stored.cx.items()} if stored is not None else {}
        self.radius = {w: RadiusCalibration() for w in WHEELS}
        self.stiffness = {w: StiffnessFit() for w in WHEELS}
        self.events: list[SourceEvent] = []
        """Stored values the run replaced, for /diagnostics/events."""
        self.road_loads_learned: tuple[float, float, float, int] | None = None
        """A paired coast-down's (F0, F1, F2, runs) measured in this run (SlipEstimator.road_loads_measured)."""
        self._r0: dict[str, tuple[float, str]] | None = None
        """r0_all's answer until a radius fit or the stored radii change."""

    def latency(self, utc: UtcLatency, lag: WheelLatency, time_s: float) -> LatencyEstimate:
        """The GPS latency to use: fixed, else the run's own (wheels or UTC) or the stored one, whichever is surer;
        a stored one the run contradicts is dropped (an event at time_s)."""
        utc_s = utc.estimate()
        wheels = lag.latency_s if lag.converged() else None
        if self.p.gps_latency_s is not None:
            return LatencyEstimate(self.p.gps_latency_s, "fixed", utc_s, wheels, lag.sigma_s)
        stored = self.stored_latency
        if stored is not None and self.frozen:
            return LatencyEstimate(stored[0], "stored", utc_s, wheels, lag.sigma_s)
        if wheels is not None and (utc_s is None or (abs(utc_s - wheels) > 3.0 * (lag.sigma_s or 0.0) + 0.02
                                                     and not lag.slip_terms)):
            # measured alignment beats an assumption about the host clock when the two disagree (not when it rests
            # on a model of the wheels' slip: every wheel driven)
            own = LatencyEstimate(wheels, "wheels", utc_s, wheels, lag.sigma_s)
            own_sigma = lag.sigma_s or 0.0
        elif utc_s is not None:
            own, own_sigma = LatencyEstimate(utc_s, "utc", utc_s, wheels, lag.sigma_s), UTC_LATENCY_SIGMA_S
        elif stored is not None:
            return LatencyEstimate(stored[0], "stored", utc_s, wheels, lag.sigma_s)
        else:
            return LatencyEstimate(0.0, "none", utc_s, wheels, lag.sigma_s)
        if stored is None:
            return own
        if abs(own.latency_s - stored[0]) > 3.0 * math.hypot(own_sigma, stored[1]) + LATENCY_TOLERANCE_S:
            self._replaced(time_s, f"GPS latency: stored {stored[0] * 1000:.1f} ms, this run "
                                   f"{own.latency_s * 1000:.1f} ms ({own.source})")
            self.stored_latency = None
            return own
        return own if own_sigma < stored[1] else LatencyEstimate(stored[0], "stored", utc_s, wheels, lag.sigma_s)

    def _replaced(self, time_s: float, detail: str) -> None:
        self.events.append(SourceEvent(time_s, "calibration", "replaced", detail))

    def take_events(self) -> list[SourceEvent]:
        events, self.events = self.events, []
        return events

    def add_free_rolling(self, arcs: dict[str, float | None], d_gps: float | None, accel: float | None, speed: float,
                         weight: float, latency_known: bool, road_n: float = 0.0) -> None:
        """A window into the radius fit of each wheel that rolled freely over it (not frozen, r0 calibrated, above
        r0_min_speed). While accelerating, the GPS latency must be known; at steady speed it does not matter. road_n:
        the force each driven tire carries (driven_tire_force_n: its slip corrects those wheels' radius, with the
        tire's Cx: radius.py)."""
        p = self.p
        if not p.calibrate_r0 or self.frozen or accel is None or d_gps is None or speed < p.r0_min_speed_mps:
            return
        steady = abs(accel) <= PHASE_ACCEL_MPS2
        for w in WHEELS:
            arc = arcs[w]
            if arc is not None and self._free_rolling(w, accel) and (steady or latency_known):
                carried = road_n if road_n and w not in self.reference else 0.0
                if carried:
                    self.radius[w].cx_n = self._cx_n(w)
                self.radius[w].add(d_gps, arc, weight, carried)
                self._r0 = None

    def _cx_n(self, w: str) -> float | None:
        """The tire's Cx for the road loads' slip: the run's fit once confident, else the stored one."""
        fit = self.stiffness[w]
        if fit.cx_n is not None and fit.confidence >= CX_CONFIDENT:
            return fit.cx_n
        stored = self.stored_cx.get(w)
        return stored[0] if stored is not None else self.radius[w].cx_n

    def _free_rolling(self, w: str, accel: float) -> bool:
        """The tire carries little force: a non-driven wheel when not braking, any wheel when coasting."""
        thr = PHASE_ACCEL_MPS2
        return abs(accel) <= thr or (w in self.reference and accel >= -thr)

    def r0_all(self) -> dict[str, tuple[float, str]]:
        """Per wheel: the radius in use and its source (the same dict until a radius fit or the stored radii
        change: not to be modified)."""
        if self._r0 is None:
            p = self.p
            stored = {w: r for w, (r, _) in self.stored_r0.items()}
            self._r0 = r0_per_wheel(self.radius, p.r_ref_m, p.r_ref_configured, p.calibrate_r0, stored,
                                    own=not self.frozen)
        return self._r0

    def check_stored(self, time_s: float) -> None:
        """Stored radii and stiffnesses that the run's own converged values contradict beyond both uncertainties
        are dropped (the run's own are used from then on), each with an event. Converged, not just usable: early in
        a run a radius's standard error understates its spread (overlapping windows), which made false alarms."""
        if self.frozen or not (self.stored_r0 or self.stored_cx):
            return
        for w, (radius, se) in list(self.stored_r0.items()):
            cal = self.radius[w]
            own, own_se = cal.radius_m, cal.standard_error_m
            if own is not None and own_se is not None and cal.converged \
                    and abs(own - radius) > 3.0 * math.hypot(own_se, se) + R0_TOLERANCE_M:
                del self.stored_r0[w]
                self._r0 = None
                self._replaced(time_s, f"r0 {w}: stored {radius * 1000:.2f} mm, this run {own * 1000:.2f} mm "
                                       f"(+- {own_se * 1000:.2f} mm)")
        for w, (cx, conf) in list(self.stored_cx.items()):
            fit = self.stiffness[w]
            if fit.cx_n is not None and fit.confidence >= CX_CONTRADICTS and abs(fit.cx_n / cx - 1.0) > max(
                    3.0 * math.hypot(cx_relative_se(fit.confidence), cx_relative_se(conf)), CX_TOLERANCE):
                del self.stored_cx[w]
                self._replaced(time_s, f"Cx {w}: stored {cx / 1000:.1f} kN, this run {fit.cx_n / 1000:.1f} kN")

    def learned(self, lat: LatencyEstimate, utc_offset_s: float | None) -> Learned:
        """What this run measured itself: the latency by the wheels or UTC, the host clock's offset from UTC, the
        radii that converged (or replaced a stored one), the stiffness fits with confidence >= CX_CONFIDENT. Nothing
        when frozen."""
        if self.frozen:
            return Learned()
        latency = None
        if lat.source == "wheels":
            latency = (lat.latency_s, lat.wheels_sigma_s, "wheels")
        elif lat.source == "utc":
            latency = (lat.latency_s, UTC_LATENCY_SIGMA_S, "utc")
        offset = utc_offset_s
        clock = offset - lat.latency_s if offset is not None and math.isfinite(offset) and lat.source != "none" \
            else None
        r0 = {}
        for w, cal in self.radius.items():
            radius, se = cal.radius_m, cal.standard_error_m
            if radius is not None and se is not None and (cal.converged or (cal.usable and w not in self.stored_r0)):
                r0[w] = (radius, se)
        cx = {w: (f.cx_n, f.confidence) for w, f in self.stiffness.items()
              if f.cx_n is not None and f.confidence >= CX_CONFIDENT}
        return Learned(latency, clock, r0, cx, road_loads=self.road_loads_learned)


def stored_road_loads(stored: Calibration | None, params: EstimatorParams) -> RoadLoads | None:
    """The calibration's [road_loads] for Fx, unless the config gives rolling_resistance_coeff or drag_area_m2 above 0
    (a manual override: then those); None: none stored (Fx takes the config's coefficients, 0 unless set)."""
    if stored is None or stored.road_loads is None or params.road_loads_configured:
        return None
    loads = stored.road_loads
    return RoadLoads(loads.road_load_f0_n, loads.road_load_f1_n_per_mps, loads.road_load_f2_n_per_mps2)


def driven_tire_force_n(params: EstimatorParams, road_loads: RoadLoads | None, force_n: float | None, driven: int
                        ) -> float:
    """What each driven tire carries in a window whose force is force_n (Fx = M*k*a + F_road + grade: in cruise the
    road loads, in a coast about 0), when road loads are known (the calibration's or the config's coefficients);
    0 without them (the radius as before) or while Fx < 0 (the brakes')."""
    known = road_loads is not None or params.rolling_resistance_coeff or params.drag_area_m2
    if not known or force_n is None or force_n <= 0.0:
        return 0.0
    return force_n / driven
