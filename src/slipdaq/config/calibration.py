"""The calibration file: what runs learned about one vehicle and tire set, kept between runs (TOML).

A run starts from it (r0 per wheel, GPS latency, fitted Cx per tire: sources `stored`), keeps calibrating, and at
its end the values it measured replace the stored ones (`merged`), each with when and from which log it was
learned. The file names the vehicle and tire set it belongs to (`vehicle.name`, `tire.size` or `tire.free_radius_m`,
`tire.set` of the config): a file of another vehicle or tire set is neither used nor written over.

    format = 1
    [vehicle]    name, tire, tire_set
    [latency]    latency_s, sigma_s, method ("wheels" or "utc"), reference ("serial" or "can:MSG.SIGNAL": the
                 reference speed it belongs to; a run with another does not use it), learned_at, learned_from
    [host_clock] offset_s (host clock minus UTC, when the fixes carried UTC), learned_at, learned_from
    [r0.FL]      radius_m, se_m, learned_at, learned_from         (one table per wheel)
    [cx.FL]      cx_n, confidence, learned_at, learned_from        (one table per tire)
    [imu]        gain, offset_mps2, windows, reference ("can:MSG.SIGNAL" or "serial": the IMU it belongs to),
                 learned_at, learned_from                          (an IMU without orientation: a = (a_imu - offset)/gain)
    [road_loads] road_load_f0_n, road_load_f1_n_per_mps, road_load_f2_n_per_mps2 (a coast-down's F0 + F1*v + F2*v^2),
                 runs_paired, learned_at, learned_from
Fx takes [road_loads] in place of the config's rolling_resistance_coeff and drag_area_m2 unless the config gives one
of those above 0 (estimator.run_calibration.stored_road_loads).
"""

from __future__ import annotations

import datetime as dt
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import tomli_w
from pydantic import Field

from slipdaq import WHEELS
from slipdaq.config import Config, ConfigError, _Section, parse_toml

CALIBRATION_FORMAT = 1
DEFAULT_FILE_NAME = "calibration.toml"
Wheel = Literal["FL", "FR", "RL", "RR"]


class CalibrationError(ConfigError):
    """A calibration file that cannot be used (not TOML, a bad key); the message names the file and the key."""


class Provenance(_Section):
    learned_at: str = ""
    """UTC time (ISO 8601) by the logging PC's clock when the value was saved."""
    learned_from: str = ""
    """The log the run wrote (or read, for replay)."""


class VehicleIdentity(_Section):
    name: str = ""
    tire: str = ""
    tire_set: str = ""


class StoredLatency(Provenance):
    latency_s: float = Field(ge=0, lt=5)
    sigma_s: float | None = Field(None, ge=0)
    method: Literal["wheels", "utc"] = "wheels"
    reference: str = "serial"
    """The reference speed it is the latency of (reference_of): a run with another one does not use it."""


def reference_of(config: Config) -> str:
    """The reference speed's identity: "serial" (the GNSS receiver on gps.port), or "can:MESSAGE.SIGNAL"."""
    return "serial" if config.gps.source == "serial" else f"can:{config.gps.message}.{config.gps.signal}"


class StoredClock(Provenance):
    offset_s: float
    """Host clock minus UTC."""


class StoredRadius(Provenance):
    radius_m: float = Field(gt=0, lt=2)
    se_m: float = Field(ge=0)


class StoredStiffness(Provenance):
    cx_n: float = Field(gt=0)
    confidence: float = Field(ge=0, le=1)


class StoredImuGain(Provenance):
    """An IMU without orientation against the GNSS speed (estimator/imu_gain.py): a_imu = gain*a + offset."""

    gain: float = Field(gt=0.5, lt=2.0)
    offset_mps2: float = Field(ge=-5.0, le=5.0)
    windows: int = Field(0, ge=0)
    """The windows it was fitted over."""
    reference: str = "can"
    """The IMU it is the gain of (imu_of): a run with another one does not use it."""


def imu_of(config: Config) -> str:
    """The IMU's identity: "serial" (an MTi), or "can:MESSAGE.SIGNAL"."""
    return "serial" if config.imu.source == "serial" else f"can:{config.imu.message}.{config.imu.signal}"
class StoredRoadLoads(Provenance):
    road_load_f0_n: float = Field(ge=0, lt=1e5)
    road_load_f1_n_per_mps: float = Field(gt=-1e4, lt=1e4)
    road_load_f2_n_per_mps2: float = Field(ge=0, lt=100)
    runs_paired: int = Field(0, ge=0)
    """Coast runs the loads average, in pairs of opposite directions (0: one run, wind and grade not cancelled)."""


class Calibration(_Section):
    format: int = CALIBRATION_FORMAT
    vehicle: VehicleIdentity = VehicleIdentity()
    latency: StoredLatency | None = None
    host_clock: StoredClock | None = None
    r0: dict[Wheel, StoredRadius] = {}
    cx: dict[Wheel, StoredStiffness] = {}
    imu: StoredImuGain | None = None
    road_loads: StoredRoadLoads | None = None

    @property
    def empty(self) -> bool:
        return self.latency is None and self.host_clock is None and not self.r0 and not self.cx and self.imu is None \
            and self.road_loads is None


@dataclass(frozen=True)
class Learned:
    """What one run measured (SlipEstimator.learned()): only the values it measured itself."""

    latency: tuple[float, float | None, str] | None = None
    """(latency_s, sigma_s, method)."""
    host_clock_offset_s: float | None = None
    r0: dict[str, tuple[float, float]] = field(default_factory=dict)
    """wheel -> (radius_m, se_m)."""
    cx: dict[str, tuple[float, float]] = field(default_factory=dict)
    """wheel -> (cx_n, confidence)."""
    imu_gain: tuple[float, float, int] | None = None
    """(gain, offset_mps2, windows) of an IMU without orientation."""
    road_loads: tuple[float, float, float, int] | None = None
    """A coast-down's (F0 [N], F1 [N/(m/s)], F2 [N/(m/s)^2], runs paired)."""


def vehicle_identity(config: Config) -> VehicleIdentity:
    tire = config.tire.size if config.tire.size is not None and config.tire.free_radius_m is None \
        else f"free radius {config.tire.radius_m} m"
    return VehicleIdentity(name=config.vehicle.name, tire=tire, tire_set=config.tire.set)


def belongs_to(cal: Calibration, config: Config) -> str | None:
    """None when the calibration is the config's vehicle and tire set's (or names none); else why not."""
    mine = vehicle_identity(config)
    if cal.empty or cal.vehicle == mine:
        return None
    theirs = cal.vehicle
    return (f"it is for vehicle {theirs.name!r}, tire {theirs.tire!r}, tire set {theirs.tire_set!r}; the config is "
            f"vehicle {mine.name!r}, tire {mine.tire!r}, tire set {mine.tire_set!r}")


def default_path(log_dir: Path, config: Config) -> Path:
    """calibration.path of the config (relative to the config file), else calibration.toml in the log directory."""
    if config.calibration.path:
        return config.resolve(config.calibration.path)
    return log_dir / DEFAULT_FILE_NAME


def parse_calibration(text: str, source: str = "<calibration>") -> Calibration:
    cal = parse_toml(Calibration, text, source, CalibrationError)
    if cal.format != CALIBRATION_FORMAT:
        raise CalibrationError(f"{source}: format: {cal.format} is not a format this slipdaq reads "
                               f"({CALIBRATION_FORMAT})")
    return cal


def load_calibration(path: str | os.PathLike[str]) -> Calibration | None:
    """The calibration in `path`, or None when there is no such file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as e:
        raise CalibrationError(f"{p}: cannot read calibration: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise CalibrationError(f"{p}: not UTF-8 text (byte {e.start})") from None
    return parse_calibration(text, str(p))


HEADER = ("# slipdaq calibration: learned by the runs of one vehicle and tire set, read at the start of the next.\n"
          "# `slipdaq calibration show` prints it; `slipdaq calibration reset [--wheel W]` clears it (tires changed).\n")


def to_toml(cal: Calibration) -> str:
    return HEADER + tomli_w.dumps(cal.model_dump(exclude_none=True))


def save_calibration(path: str | os.PathLike[str], cal: Calibration) -> None:
    """Written complete or not at all (a temporary file renamed into place)."""
    from slipdaq.outputs import atomic_output

    with atomic_output(path) as tmp:
        tmp.write_text(to_toml(cal), encoding="utf-8")


def utc_now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds").replace("+00:00", "Z")


def merged(stored: Calibration | None, learned: Learned, config: Config, learned_from: str,
           learned_at: str | None = None) -> Calibration:
    """The stored calibration with every value the run measured replacing the stored one."""
    base = stored if stored is not None and belongs_to(stored, config) is None else Calibration()
    prov = {"learned_at": learned_at or utc_now(), "learned_from": learned_from}
    latency = base.latency
    if learned.latency is not None:
        value, sigma, method = learned.latency
        latency = StoredLatency.model_validate({"latency_s": value, "sigma_s": sigma, "method": method,
                                                "reference": reference_of(config)} | prov)
    clock = base.host_clock if learned.host_clock_offset_s is None \
        else StoredClock(offset_s=learned.host_clock_offset_s, **prov)
    r0: dict[str, StoredRadius] = {str(w): v for w, v in base.r0.items()}
    r0 |= {w: StoredRadius(radius_m=r, se_m=se, **prov) for w, (r, se) in learned.r0.items()}
    cx: dict[str, StoredStiffness] = {str(w): v for w, v in base.cx.items()}
    cx |= {w: StoredStiffness(cx_n=c, confidence=conf, **prov) for w, (c, conf) in learned.cx.items()}
    imu = base.imu
    if learned.imu_gain is not None:
        gain, offset, windows = learned.imu_gain
        imu = StoredImuGain.model_validate({"gain": gain, "offset_mps2": offset, "windows": windows,
                                            "reference": imu_of(config)} | prov)
    loads = base.road_loads
    if learned.road_loads is not None:
        f0, f1, f2, runs = learned.road_loads
        loads = StoredRoadLoads(road_load_f0_n=f0, road_load_f1_n_per_mps=f1, road_load_f2_n_per_mps2=f2,
                                runs_paired=runs, **prov)
    return Calibration.model_validate({
        "vehicle": vehicle_identity(config), "latency": latency, "host_clock": clock,
        "r0": {w: r0[w] for w in WHEELS if w in r0}, "cx": {w: cx[w] for w in WHEELS if w in cx}, "imu": imu,
        "road_loads": loads})


def reset(cal: Calibration, wheels: list[str] | None) -> Calibration:
    """Without wheels: nothing kept but the identity; with wheels: their r0 and Cx cleared (those tires changed)."""
    if not wheels:
        return Calibration(vehicle=cal.vehicle)
    return cal.model_copy(update={"r0": {w: v for w, v in cal.r0.items() if w not in wheels},
                                  "cx": {w: v for w, v in cal.cx.items() if w not in wheels}})


def summary(cal: Calibration) -> str:
    """One line: what the calibration holds."""
    parts = []
    if cal.latency is not None:
        parts.append(f"GPS latency {cal.latency.latency_s * 1000:.1f} ms ({cal.latency.method})")
    if cal.r0:
        parts.append("r0 " + ", ".join(f"{w} {r.radius_m * 1000:.2f} mm" for w, r in cal.r0.items()))
    if cal.cx:
        parts.append("Cx " + ", ".join(f"{w} {c.cx_n / 1000:.1f} kN" for w, c in cal.cx.items()))
    if cal.imu is not None:
        parts.append(f"IMU gain {cal.imu.gain:.4f}, offset {cal.imu.offset_mps2:+.3f} m/s^2")
    if cal.road_loads is not None:
        parts.append(f"road loads {road_loads_text(cal.road_loads)}")
    return "; ".join(parts) or "nothing learned yet"


def road_loads_text(loads: StoredRoadLoads) -> str:
    return (f"F0 {loads.road_load_f0_n:.1f} N, F1 {loads.road_load_f1_n_per_mps:.2f} N/(m/s), "
            f"F2 {loads.road_load_f2_n_per_mps2:.4f} N/(m/s)^2")


def show(cal: Calibration, path: str) -> str:
    """The calibration as a table for `slipdaq calibration show`."""
    v = cal.vehicle
    lines = [f"{path}: vehicle {v.name or '(unnamed)'}, tire {v.tire or '?'}, tire set {v.tire_set or '(unnamed)'}"]

    def when(p: Provenance) -> str:
        return f"learned {p.learned_at or '?'} from {p.learned_from or '?'}"

    if cal.latency is not None:
        sig = f" +- {cal.latency.sigma_s * 1000:.1f}" if cal.latency.sigma_s is not None else ""
        lines.append(f"  GPS latency  {cal.latency.latency_s * 1000:8.1f}{sig} ms ({cal.latency.method}), "
                     f"{when(cal.latency)}")
    if cal.host_clock is not None:
        lines.append(f"  host clock   {cal.host_clock.offset_s:+.3f} s from UTC, {when(cal.host_clock)}")
    for w in WHEELS:
        if (r := cal.r0.get(w)) is not None:  # type: ignore[call-overload]  # w is one of the Literal keys
            lines.append(f"  r0 {w}        {r.radius_m * 1000:8.2f} +- {r.se_m * 1000:.2f} mm, {when(r)}")
    for w in WHEELS:
        if (c := cal.cx.get(w)) is not None:  # type: ignore[call-overload]  # w is one of the Literal keys
            lines.append(f"  Cx {w}        {c.cx_n / 1000:8.1f} kN (confidence {c.confidence:.2f}), {when(c)}")
    if cal.imu is not None:
        i = cal.imu
        lines.append(f"  IMU {i.reference}  gain {i.gain:.4f}, offset {i.offset_mps2:+.3f} m/s^2 ({i.windows} "
                     f"windows), {when(i)}")
    if cal.road_loads is not None:
        lines.append(f"  road loads   {road_loads_text(cal.road_loads)} ({cal.road_loads.runs_paired} runs paired), "
                     f"{when(cal.road_loads)}")
    if cal.empty:
        lines.append("  nothing learned yet")
    return "\n".join(lines)


@dataclass
class RunCalibration:
    """A run's calibration: what it starts from and where what it learns is saved."""

    start: Calibration | None
    save_to: Path | None
    """None: --no-calibration, or a file of another vehicle (neither used nor written over)."""
    note: str = ""
    base: Calibration | None = None
    """What the values learned are merged into: the file as it was when the run started (default: start)."""

    def finish(self, learned: Learned, config: Config, learned_from: str) -> str:
        """Save the file's calibration with what the run learned; a line saying what was saved (or '')."""
        if self.save_to is None:
            return ""
        cal = merged(self.base if self.base is not None else self.start, learned, config, learned_from)
        save_calibration(self.save_to, cal)
        return f"calibration saved: {self.save_to} ({summary(cal)})"


def for_run(path: Path | None, config: Config) -> RunCalibration:
    """The calibration in `path` to start from (None: --no-calibration)."""
    if path is None:
        return RunCalibration(None, None)
    cal = load_calibration(path)
    if cal is None:
        return RunCalibration(None, path, f"calibration: {path} not there yet: starting cold")
    why = belongs_to(cal, config)
    if why:
        return RunCalibration(None, None, f"calibration: {path} neither used nor written over: {why} (give another "
                                          f"with --calibration, or `slipdaq calibration reset {path}`)")
    start = usable(cal, config)
    other = "".join(f"; its {what} is {stored.reference}'s, not used" for what, stored, kept in (
        ("GPS latency", cal.latency, start.latency), ("IMU gain", cal.imu, start.imu)) if stored and kept is None)
    return RunCalibration(start, path, f"calibration: starting from {path} ({summary(start)}{other})", base=cal)


def usable(cal: Calibration, config: Config) -> Calibration:
    """cal without a latency stored for another reference speed (reference_of), nor an IMU gain stored for another
    IMU (imu_of): those stay in the file."""
    update: dict[str, None] = {}
    if cal.latency is not None and cal.latency.reference != reference_of(config):
        update["latency"] = None
    if cal.imu is not None and cal.imu.reference != imu_of(config):
        update["imu"] = None
    return cal.model_copy(update=update) if update else cal


def for_replay(logged: Calibration | None, path: Path, config: Config) -> RunCalibration:
    """A replay's: it starts from the calibration its log started from (`logged`), so that it gives the run's
    estimates, and saves what it learns into the file at `path` as that file is now (or, without one, into
    `logged`); a file of another vehicle is not written over."""
    file = for_run(path, config)
    if file.save_to is None:
        return RunCalibration(logged, None, file.note)
    return RunCalibration(logged, path, base=file.start if file.start is not None else logged)
