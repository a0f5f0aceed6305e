"""TOML config -> typed, validated Config. One clear error per bad key (ConfigError names file and key).

Paths in the file (can.dbc, log.dir) are relative to the config file.
"""

from __future__ import annotations

import re
import tomllib
from importlib import resources
from pathlib import Path
from typing import ClassVar, Literal, TypeVar

import tomli_w
from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from slipdaq.config.section import ConfigError, _Section
from slipdaq.config.test_procedures import PROCEDURE_KINDS as PROCEDURE_KINDS
from slipdaq.config.test_procedures import ProcedureConfig as ProcedureConfig
from slipdaq.config.test_procedures import TestConfig
from slipdaq.config.tire_size import TireSizeError, free_radius_m, parse_tire_size


class VehicleConfig(_Section):
    name: str = Field("", description="the vehicle's name: part of its calibration's identity")
    mass_kg: float = Field(1300.0, gt=0, description="total vehicle mass M in Fx = M*a")
    driven_axle: Literal["front", "rear", "all"] = Field("front", description="the axle the engine drives (all: every wheel)")
    brake_front_share: float = Field(0.7, ge=0, le=1, description="share of braking force on the front axle")
    rolling_resistance_coeff: float = Field(0.0, ge=0, lt=0.1, description="f_rr: F_rr = f_rr*M*g (0 = off); "
                                            "above 0 (or drag_area_m2), the two win over the calibration's [road_loads]")
    drag_area_m2: float = Field(0.0, ge=0, lt=20, description="Cd*A: F_drag = rho/2*CdA*v^2 (0 = off); above 0 (or "
                                "rolling_resistance_coeff), the two win over the calibration's [road_loads]")
    rotating_mass_factor: float = Field(1.03, ge=1, lt=1.5, description="the equivalent mass of the wheels and "
                                        "driveline per unit of M (SAE J2263: 1.03; 1.0 = off): Fx = M*factor*a + road "
                                        "loads, and the coast-down's deceleration carries M*factor")
    air_density_kgpm3: float = Field(1.2, gt=0, lt=2, description="rho in the drag force")
    wheelbase_m: float = Field(2.6, gt=0.5, lt=10, description="L in the load transfer M*a*h/L")
    cg_height_m: float = Field(0.55, gt=0, lt=5, description="h, the centre of gravity's height above the road")
    front_axle_load_share: float = Field(0.6, gt=0, lt=1, description="share of M*g on the front axle at rest")


class TireConfig(_Section):
    size: str | None = Field("195/60 R15", description="the tire size (ISO metric, e.g. 195/60 R15): the free radius r0 before "
                                                       "calibration")
    free_radius_m: float | None = Field(None, gt=0, lt=2, description="the free radius itself, in place of size")
    set: str = Field("", description="the tire set's name (e.g. 'summer 2026'): part of the calibration's identity")
    mu_max: float = Field(1.5, gt=0, le=5, description="the most a road tire can give: a fitted mu peak above it is "
                          "flagged (mu_flag), never given as a result")

    @field_validator("size")
    @classmethod
    def _size_parses(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                parse_tire_size(v)
            except TireSizeError as e:
                raise ValueError(str(e)) from None
        return v

    @model_validator(mode="after")
    def _one_given(self) -> TireConfig:
        if self.size is None and self.free_radius_m is None:
            raise ValueError("give tire.size (for example '195/60 R15') or tire.free_radius_m")
        return self

    @property
    def radius_m(self) -> float:
        """free_radius_m when set, else the radius from the tire size."""
        if self.free_radius_m is not None:
            return self.free_radius_m
        assert self.size is not None
        return free_radius_m(self.size)


class WptConfig(_Section):
    pulses_per_rev: int = Field(1000, gt=0, description="pulses per revolution of every WPT (a wheel's own pulses_per_rev "
                                                        "overrides it)")


class WheelSourceConfig(_Section):
    """Where one wheel's motion comes from: a cumulative pulse count or a wheel-speed signal, by DBC names."""

    kind: Literal["count", "speed"] = Field("count", description="count: a cumulative pulse counter (unsigned, wraps at 2^(its "
                                                                 "bit length), counter node resets detected); speed: a "
                                                                 "wheel-speed signal, integrated over time")
    message: str = Field(min_length=1, description="the DBC message (several wheels may share one)")
    signal: str = Field(min_length=1, description="the signal in that message")
    seq_signal: str | None = Field(None, description='count: a rolling counter signal whose gaps are lost frames (optional).')
    pulses_per_rev: int | None = Field(None, gt=0, description='count: pulses per revolution (default wpt.pulses_per_rev).')
    unit: Literal["km/h", "kph", "m/s", "mph", "rpm", "rad/s", "deg/s"] | None = Field(None, description=(
        "speed: the signal's unit (default: the DBC's unit for the signal)."))

    @model_validator(mode="after")
    def _kind_fields(self) -> WheelSourceConfig:
        if self.kind == "speed" and (self.pulses_per_rev is not None or self.seq_signal is not None):
            raise ValueError("pulses_per_rev and seq_signal are for kind = \"count\"")
        if self.kind == "count" and self.unit is not None:
            raise ValueError("unit is for kind = \"speed\"")
        return self


def default_wheel_source(wheel: str) -> WheelSourceConfig:
    """The WPT contract: message WPT_<W>, signals PulseCount and Seq."""
    return WheelSourceConfig(kind="count", message=f"WPT_{wheel}", signal="PulseCount", seq_signal="Seq")


class CanConfig(_Section):
    interface: str = Field("socketcan", description="any python-can interface: socketcan, virtual, pcan, kvaser, slcan, ...")
    channel: str = Field("can0", description="the interface's channel")
    bitrate: int = Field(500000, gt=0, description="bit/s (where the interface sets it)")
    dbc: str | list[str] = Field("wpt.dbc", description=(
        'One DBC, or several (the wheels\' and the sensors\', e.g. ["wpt.dbc", "canmod-gps.dbc"]) read as one.'))
    receive_buffer_bytes: int = Field(8 * 1024 * 1024, ge=0, description="SO_RCVBUF asked for on SocketCAN")
    read_interval_s: float = Field(
        0.02, ge=0, le=0.1,
        description="shortest time between two reads of a socket bus (SocketCAN): frames wait in the kernel's "
                    "buffer, keep its receive stamps, and are handled in larger batches (except while an estimate waits for "
                    "wheel frames); 0 reads every frame as it comes: about twice the CPU",
    )


class GpsConfig(_Section):
    """The reference speed: a GNSS receiver on a serial port (NMEA/UBX), or a speed signal on CAN (VBOX, OxTS RT,
    a CAN GNSS module), decoded by the DBC."""

    source: Literal["serial", "can"] = Field("serial", description="serial: NMEA/UBX on gps.port; can: a speed signal by its "
                                                                   "DBC names (gps.message, gps.signal)")
    port: str = Field("/dev/ttyUSB0", description="serial: the receiver's port (a /dev/serial/by-id/ link is followed when it "
                                                  "reconnects)")
    baudrate: int = Field(115200, gt=0, description="serial: the port's baud rate")
    latency_s: Literal["auto"] | float = Field("auto", description="seconds from the speed's instant to its arrival; auto: "
                                                                   "estimated online (from the fixes' UTC time when the host "
                                                                   "clock keeps UTC, else by aligning the reference speed with "
                                                                   "the free-rolling wheels)")
    velocity: Literal["nmea", "ubx"] = Field("nmea", description=(
        'Which messages give the GPS velocity: NMEA sentences, or u-blox UBX NAV-PVT (with its speed accuracy).'))
    message: str | None = Field(None, min_length=1, description="source = 'can': the DBC message with the speed")
    signal: str | None = Field(None, min_length=1, description="source = 'can': the speed signal")
    unit: Literal["km/h", "kph", "m/s", "mph", "kn"] | None = Field(None, description=(
        'source = "can": the speed signal\'s unit (default: the DBC\'s).'))
    valid_signal: str | None = Field(None, min_length=1, description="a signal that is 0 when the speed is invalid")
    accuracy_signal: str | None = Field(None, min_length=1, description="the speed's 1-sigma accuracy (as UBX sAcc)")

    @model_validator(mode="after")
    def _can_fields(self) -> GpsConfig:
        if self.source == "can" and (self.message is None or self.signal is None):
            raise ValueError('source = "can" needs gps.message and gps.signal (the DBC names of the speed signal)')
        return self

    @field_validator("latency_s")
    @classmethod
    def _latency_nonneg(cls, v: str | float) -> str | float:
        if not isinstance(v, str) and not 0 <= v < 5:
            raise ValueError("must be 'auto' or a number of seconds from 0 to 5")
        return v


class _CanSignalSection(_Section):
    """A sensor signal on CAN by its DBC names: both message and signal, or neither (no such sensor)."""

    section: ClassVar[str]
    message: str | None = Field(None, min_length=1, description="the DBC message with the signal")
    signal: str | None = Field(None, min_length=1, description="the signal in that message")

    @model_validator(mode="after")
    def _both(self) -> _CanSignalSection:
        if (self.message is None) != (self.signal is None):
            raise ValueError(f"give both {self.section}.message and {self.section}.signal, or neither")
        return self


class ImuConfig(_CanSignalSection):
    """The longitudinal acceleration from an inertial sensor (positive forward, after `sign`): on CAN by its DBC
    names, or (source = "serial") an Xsens MTi's Xbus output on a serial port; unset: the GPS speed differences."""

    section: ClassVar[str] = "imu"
    source: Literal["can", "serial"] = Field("can", description="can: a signal by its DBC names; serial: an Xsens MTi on "
                                                                "imu.port")
    unit: Literal["m/s^2", "g"] | None = Field(None, description="The signal's unit (default: the DBC's).")
    sign: Literal[1, -1] = Field(1, description='-1 for a sensor mounted backwards.')
    port: str | None = Field(None, min_length=1, description="serial: the MTi's port, e.g. /dev/ttyUSB1")
    baudrate: int = Field(115200, gt=0, description="serial: the MTi port's baud rate")
    protocol: Literal["xbus"] = Field("xbus", description=(
        "serial: the MTi's MTData2 messages: Acceleration less gravity by the packet's orientation, else "
        'FreeAcceleration on the heading, else Acceleration as sent (decode/mti_accel.py).'))
    axis: Literal["x", "y", "z"] = Field("x", description='serial: the sensor axis that points forward (backwards: sign = -1).')

    @model_validator(mode="after")
    def _serial(self) -> ImuConfig:
        if self.source == "serial" and (self.port is None or self.message is not None):
            raise ValueError("imu.source = \"serial\" takes imu.port (and no imu.message or imu.signal)")
        return self


class BrakeConfig(_CanSignalSection):
    """The brake onset: a brake signal on CAN (a pedal switch, or a pressure: nonzero = pressed; the onset lies
    between its last released and first pressed sample), or the GPS receiver's time mark of the brake-light switch
    (source = "gps-timemark": UBX-TIM-TM2 of the edge on its EXTINT pin)."""

    section: ClassVar[str] = "brake"
    source: Literal["can", "gps-timemark"] = Field(
        "can", description="where the onset comes from: 'can' (message and signal, sampled) or 'gps-timemark' (the "
        "receiver's UBX-TIM-TM2 time mark of the brake-light switch's edge, placed on the host's clock as a fix's "
        "UTC is; a CAN signal, if also given, is the fallback for a stop without a mark)")
    edge: Literal["rising", "falling"] = Field(
        "rising", description="gps-timemark: the edge that the brake's press gives on the receiver's EXTINT pin")


class EstimatorConfig(_Section):
    window_s: float = Field(0.5, gt=0, le=10, description="length of an estimate's window")
    fast_rate_hz: float = Field(100.0, ge=0, le=1000, description="rate of the high-rate slip (/slip/fast); 0 = off")
    min_speed_mps: float = Field(1.0, gt=0, description="below this GPS speed, slip, Re and Cx are undefined")
    cx_slip_min: float = Field(0.005, ge=0, description="|slip| below this gives no Cx (Fx/s ill-conditioned)")
    cx_slip_max: float = Field(0.10, gt=0, description="|slip| above this is outside the linear region: no Cx")
    cx_fit_slip_spread_max: float = Field(0.015, gt=0, description="a window in which any wheel's slip varies more "
                                          "than this (RMS about the window's trend over 50 ms parts: ABS cycling, "
                                          "a brake's onset) stays out of the fitted stiffness cx_fit_W_n")
    calibrate_r0: bool = Field(True, description="calibrate the free-rolling radius online (else the tire's)")
    r0_min_speed_mps: float = Field(3.0, ge=0.5, description="slowest window used to calibrate r0")
    fit_min_speed_mps: float = Field(5.0, ge=0.5, description="slowest window used in the stiffness fit")
    max_latency_s: float = Field(0.4, gt=0, le=2, description="largest GPS latency the 'auto' estimate looks for")
    grade_from_altitude: bool = Field(False, description="add M*g*sin(grade) from GPS altitude to Fx")


class LogConfig(_Section):
    dir: str = Field("logs", description="where `run` writes its logs")
    chunk_size_bytes: int = Field(1024 * 1024, gt=0, description="MCAP chunk size (a chunk is also closed at least every second "
                                                                 "in live runs)")
    rotate_size_bytes: int | None = Field(None, ge=1_000_000, description="start a new log file at this size (unset: no "
                                                                          "rotation)")
    rotate_duration_s: float | None = Field(None, ge=10, description="start a new log file after this long (unset: no rotation)")


class CalibrationConfig(_Section):
    path: str | None = Field(None, description=(
        'The calibration file a run starts from and saves to (relative to the config file); default '
        'calibration.toml in the log directory.'))


DEFAULT_LIVE_HOST = "127.0.0.1"


def parse_host_port(text: str) -> tuple[str, int]:
    """`[HOST:]PORT` -> (host, port): HOST defaults to 127.0.0.1 (this machine only), an IPv6 address in brackets
    ([::1]:8765); PORT 0 to 65535 (0: any free port). ValueError naming what is wrong."""
    host, sep, port = text.strip().rpartition(":")
    if not sep:
        host = ""
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise ValueError(f"{text!r}: write an IPv6 address in brackets, e.g. [::1]:8765")
    if not (port.isascii() and port.isdigit()) or not 0 <= int(port) <= 65535:
        raise ValueError(f"{text!r}: expected [HOST:]PORT, PORT a number from 0 to 65535")
    if any(c.isspace() for c in host):
        raise ValueError(f"{text!r}: the host has a space in it")
    return host or DEFAULT_LIVE_HOST, int(port)


class LiveConfig(_Section):
    foxglove: str | None = Field(None, description="[HOST:]PORT: serve the run live to Foxglove over WebSocket "
                                 "(host default 127.0.0.1, port 0 any free port); unset: no server")

    @field_validator("foxglove")
    @classmethod
    def _address(cls, v: str | None) -> str | None:
        if v is not None:
            parse_host_port(v)
        return v


class Config(_Section):
    wheels: dict[Literal["FL", "FR", "RL", "RR"], WheelSourceConfig] = Field({}, description=(
        'Per-wheel sources; a wheel not named here reads the WPT default (WPT_<W>.PulseCount, Seq).'))
    vehicle: VehicleConfig = VehicleConfig()
    tire: TireConfig = TireConfig()
    wpt: WptConfig = WptConfig()
    can: CanConfig = CanConfig()
    gps: GpsConfig = GpsConfig()
    imu: ImuConfig = ImuConfig()
    brake: BrakeConfig = BrakeConfig()
    estimator: EstimatorConfig = EstimatorConfig()
    log: LogConfig = LogConfig()
    calibration: CalibrationConfig = CalibrationConfig()
    live: LiveConfig = LiveConfig()
    test: TestConfig = TestConfig()

    source_path: Path | None = Field(None, exclude=True, description=(
        'The file this config was read from (None for one made in code).'))
    source_text: str = Field("", exclude=True, description=(
        'The TOML text as read, stored in every log so that replay needs no other input.'))
    dbc_text: str | None = Field(None, exclude=True, description=(
        'DBC text, when the config was read from a log rather than from disk.'))

    @model_validator(mode="after")
    def _time_mark_from_the_receiver(self) -> Config:
        if self.brake.source == "gps-timemark" and self.gps.source == "can":
            raise ValueError('brake.source = "gps-timemark" needs the GPS receiver on its serial port ([gps] source = '
                             '"serial"): the time mark is its UBX-TIM-TM2, placed by its fixes\' UTC')
        return self

    def resolve(self, path: str) -> Path:
        """A path from the config, relative to the config file's folder."""
        p = Path(path).expanduser()
        if p.is_absolute() or self.source_path is None:
            return p
        return self.source_path.parent / p

    @property
    def latency_fixed_s(self) -> float | None:
        """The configured GPS latency in seconds, or None for 'auto' (estimated online)."""
        return None if self.gps.latency_s == "auto" else float(self.gps.latency_s)

    def wheel_source(self, wheel: str) -> WheelSourceConfig:
        return self.wheels.get(wheel) or default_wheel_source(wheel)  # type: ignore[call-overload]  # wheel is one of WHEELS, the Literal keys of the dict

    def to_toml(self) -> str:
        """The effective config as TOML (what a log stores, so that replay runs with exactly these values)."""
        return tomli_w.dumps(self.model_dump(exclude_none=True))

    def with_overrides(self, **sections: dict[str, object]) -> Config:
        """A copy with some keys replaced, e.g. with_overrides(can={"interface": "virtual"})."""
        update = {name: getattr(self, name).model_copy(update=values) for name, values in sections.items()}
        return self.model_copy(update=update)

    def dbc_paths(self) -> list[Path]:
        """can.dbc's files (one or several), resolved."""
        return [self.resolve(n) for n in ([self.can.dbc] if isinstance(self.can.dbc, str) else self.can.dbc)]

    def load_dbc_text(self) -> str:
        """The DBC's text: from the log it was stored in, else from can.dbc on disk (several DBCs: merged into one
        by cantools, so that a log stores one text)."""
        if self.dbc_text is not None:
            return self.dbc_text
        paths = self.dbc_paths()
        texts = []
        for path in paths:
            try:
                texts.append(path.read_text(encoding="utf-8", errors="replace"))
            except OSError as e:
                raise ConfigError(f"{self.source_path or '<config>'}: can.dbc: cannot read {path}: {e.strerror}") \
                    from None
        if len(texts) == 1:
            return texts[0]
        from slipdaq.__main__ import import_cantools

        cantools = import_cantools()

        db = cantools.database.can.Database(strict=False)
        for path, text in zip(paths, texts):
            try:
                db.add_dbc_string(text)
            except Exception as e:  # cantools raises several parse error types
                raise ConfigError(f"{self.source_path or '<config>'}: can.dbc: cannot parse {path}: {e}") from None
        return str(db.as_dbc_string())


def packaged_config_path() -> Path:
    """The example config shipped with the package (used when no --config and no ./slipdaq.toml)."""
    return Path(str(resources.files("slipdaq") / "data" / "slipdaq.toml"))


def default_config_path() -> Path:
    local = Path("slipdaq.toml")
    return local if local.is_file() else packaged_config_path()


_UNION_MEMBER = re.compile(r"^(literal\[.*\]|float|int|str|bool|none|[a-z-]+\[.*\])$")


def _key(loc: tuple[int | str, ...]) -> str:
    """The TOML key of an error's location, without pydantic's tags of union members (`float`, `literal['auto']`)."""
    return ".".join(str(p) for p in loc if not (isinstance(p, str) and _UNION_MEMBER.match(p))) or "<top level>"


def _format_error(source: str, err: ValidationError) -> str:
    errors = err.errors()
    e = errors[0]
    key = _key(e["loc"])
    if e["type"] == "extra_forbidden":
        return f"{source}: {key}: unknown key"
    got = e.get("input")
    shown = f" (got {got!r})" if got is not None and not isinstance(got, dict) else ""
    same_key = [x for x in errors if _key(x["loc"]) == key]  # a union's members: one message for the key
    msg = ", or ".join(dict.fromkeys(x["msg"].removeprefix("Value error, ") for x in same_key))
    rest = len(errors) - len(same_key)
    more = f" (and {rest} more)" if rest else ""
    return f"{source}: {key}: {msg}{shown}{more}"


M = TypeVar("M", bound=BaseModel)


def parse_toml(model: type[M], text: str, source: str, error: type[ConfigError] = ConfigError) -> M:
    """TOML text validated into `model`; `error` with one line naming the file (source) and the key otherwise."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{source}: not valid TOML: {e}") from None
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise error(_format_error(source, e)) from None


def parse_config(text: str, source_path: Path | None = None, dbc_text: str | None = None) -> Config:
    """Parse TOML text into a Config; raises ConfigError with one line naming the file and key."""
    cfg = parse_toml(Config, text, str(source_path) if source_path is not None else "<config>")
    return cfg.model_copy(update={"source_path": source_path, "source_text": text, "dbc_text": dbc_text})


def parse_logged_config(text: str, source_path: Path | None = None, dbc_text: str | None = None) -> Config:
    """The config a log stored (every key written out): parse_config, but a log written before
    `vehicle.rotating_mass_factor` existed ran without rotating masses, so 1.0 (its replay gives its estimates)."""
    cfg = parse_config(text, source_path, dbc_text)
    if text and "rotating_mass_factor" not in tomllib.loads(text).get("vehicle", {}):
        cfg = cfg.with_overrides(vehicle={"rotating_mass_factor": 1.0})
    return cfg


def load_config(path: str | Path | None = None) -> Config:
    """Read and validate a config file (default: ./slipdaq.toml, else the packaged example)."""
    p = Path(path) if path is not None else default_config_path()
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{p}: cannot read config: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{p}: not UTF-8 text (byte {e.start}): save the config as UTF-8") from None
    return parse_config(text, p.resolve())
