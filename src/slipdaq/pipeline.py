"""Raw records in -> decoded -> estimator -> sinks. Live, replay and import all call Pipeline.process.

Records are processed in the order given; the estimates depend on nothing else, so a log replayed in
the order it was recorded gives the same estimates, bit for bit.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from slipdaq.config import Config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.decode.ubx import UbxDecoder
from slipdaq.estimator import EstimatorParams, SlipEstimator
from slipdaq.records import CanFrame, Diagnostics, GpsFix, NmeaLine, RawRecord, UbxFrame
from slipdaq.sinks import Sink

DIAGNOSTICS_PERIOD_S = 1.0


class Pipeline:
    def __init__(self, config: Config, sinks: Sequence[Sink]) -> None:
        self.config = config
        self.sinks = list(sinks)
        self.wheels = WheelDecoder(config)
        self.nmea = NmeaDecoder()
        self.ubx = UbxDecoder()
        self._velocity_from = NmeaLine if config.gps.velocity == "nmea" else UbxFrame
        self.estimator = SlipEstimator(EstimatorParams.from_config(config))
        self.can_frames = 0
        self.unknown_frames = 0
        self.error_frames = 0
        self.estimates = 0
        self.last_time_s: float | None = None
        self._next_diag_s: float | None = None

    def process(self, record: RawRecord) -> None:
        """One raw record through decode and estimator to every sink."""
        sinks = self.sinks
        for s in sinks:
            s.on_raw(record)
        t = record.timestamp_s
        if isinstance(record, CanFrame):
            self.can_frames += 1
            if record.is_error_frame:
                self.error_frames += 1
                estimates = []
            else:
                samples = self.wheels.decode(record)
                if not samples and not self.wheels.is_wheel_frame(record):
                    self.unknown_frames += 1
                estimates = []
                for sample in samples:
                    for s in sinks:
                        s.on_wheel(sample)
                    estimates += self.estimator.add_wheel(sample)
        else:
            fix: GpsFix | None = self.nmea.decode(record) if isinstance(record, NmeaLine) else self.ubx.decode(record)
            if fix is None or not isinstance(record, self._velocity_from):
                estimates = []  # gps.velocity names the other protocol: decoded and counted only
            else:
                for s in sinks:
                    s.on_fix(fix)
                estimates = self.estimator.add_gps(fix)
        for e in estimates:
            self.estimates += 1
            for s in sinks:
                s.on_estimate(e, t)
        self.last_time_s = t
        if self._next_diag_s is None:
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S
        elif t >= self._next_diag_s:
            self.emit_diagnostics()
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S

    def run(self, records: Iterable[RawRecord]) -> None:
        for r in records:
            self.process(r)
        self.finish()

    def finish(self) -> None:
        """A last diagnostics snapshot, so that the log ends with the final counters."""
        if self.last_time_s is not None:
            self.emit_diagnostics()

    def diagnostics(self) -> Diagnostics:
        return Diagnostics(
            time_s=self.last_time_s or 0.0,
            can_frames=self.can_frames,
            wpt_frames=dict(self.wheels.frames),
            lost_frames=dict(self.wheels.lost_frames),
            count_wraps=dict(self.wheels.count_wraps),
            counter_resets=dict(self.wheels.counter_resets),
            unknown_frames=self.unknown_frames,
            error_frames=self.error_frames,
            bad_frames=self.wheels.bad_frames,
            nmea_lines=self.nmea.lines,
            bad_sentences=self.nmea.bad_sentences,
            gps_fixes=self.nmea.fixes + self.ubx.fixes,
            ubx_frames=self.ubx.frames,
            bad_ubx_frames=self.ubx.bad_frames,
            estimates=self.estimates,
            estimator=self.estimator.status(),
        )

    def emit_diagnostics(self) -> None:
        d = self.diagnostics().as_dict()
        for s in self.sinks:
            s.on_diagnostics(d, d["time_s"])  # type: ignore[arg-type]
