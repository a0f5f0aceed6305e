"""`[test]`: a maneuver's validity and the test's procedures (`[[test.procedure]]`, the test sets)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from slipdaq.config.section import _Section

PROCEDURE_KINDS = ("brake", "accelerate", "coast")


class ProcedureConfig(_Section):
    """One `[[test.procedure]]`: a set of runs to a procedure (maneuver.test_set)."""

    name: str = Field(min_length=1, description="the set's name, e.g. 'brake 100-0' (/maneuver procedure, /test_set)")
    kind: Literal["brake", "accelerate", "coast"] = Field(
        description="the maneuvers it takes: brake (main figure: stopping_distance_corrected_m), accelerate "
                    "(time_to_speed_s) or coast (road_load_f0_n)")
    target_speed_kmh: float = Field(gt=0, lt=1000, description="braking: the speed at the brake onset; "
                                    "accelerating: the speed to reach; the stopping distance is corrected to it")
    speed_tolerance_kmh: float | None = Field(None, ge=0, description="how far a run's speed may lie from the target "
                                              "to count; default: [test] speed_tolerance_kmh")
    runs: int = Field(3, ge=1, le=1000, description="valid runs the set needs (it counts no more than these)")
    mfdd_window_kmh: list[float] | None = Field(
        None, description="[from, to]: the MFDD's speed window (e.g. [80, 20] as UN R117); default ECE R13-H: "
                          "0.8*v0 to 0.1*v0")
    max_cv_percent: float | None = Field(None, gt=0, description="a complete set whose main figure's coefficient "
                                         "of variation is larger is not ok; unset: no limit")

    @field_validator("mfdd_window_kmh")
    @classmethod
    def _window(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and (len(v) != 2 or not v[0] > v[1] >= 0):
            raise ValueError("expected [from, to] with from > to >= 0 (km/h)")
        return v


class TestConfig(_Section):
    """The test day's targets: a maneuver's validity (maneuver.record.judge), and its procedures (test sets)."""

    target_speeds_kmh: list[float] = Field([], description="the maneuvers' target speeds; empty: speed not judged")
    speed_tolerance_kmh: float = Field(2.0, ge=0, description="how far a brake speed may lie from a target")
    coast_from_kmh: float = Field(100.0, gt=0, lt=400, description="a coast (no brake, no drive force) starts at this "
                                  "speed or above to make a `coast` maneuver (the road loads' fit)")
    coast_to_kmh: float = Field(20.0, gt=0, lt=400, description="... and runs down to this speed (the fit's low end)")

    procedure: list[ProcedureConfig] = Field(
        [], description="[[test.procedure]]: the test's sets of runs; each decided maneuver of a procedure's kind "
                        "belongs to the one whose target speed is nearest")

    @field_validator("procedure")
    @classmethod
    def _unique(cls, v: list[ProcedureConfig]) -> list[ProcedureConfig]:
        names = [p.name for p in v]
        if len(set(names)) != len(names):
            raise ValueError("procedure names must be unique")
        return v

    def tolerance_kmh(self, procedure: ProcedureConfig) -> float:
        """The procedure's speed tolerance, else the test's."""
        t = procedure.speed_tolerance_kmh
        return self.speed_tolerance_kmh if t is None else t

    @model_validator(mode="after")
    def _coast_span(self) -> TestConfig:
        if self.coast_to_kmh >= self.coast_from_kmh:
            raise ValueError("coast_to_kmh must be below coast_from_kmh")
        return self

    @field_validator("target_speeds_kmh")
    @classmethod
    def _positive(cls, v: list[float]) -> list[float]:
        if any(not (0 < x < 1000) for x in v):
            raise ValueError("target speeds must be between 0 and 1000 km/h")
        return v
