"""The columns of a flat record, declared once (name, attribute, kind, unit, description), and the estimate's and the
high-rate slip's declarations: their JSON, JSON Schema, CSV columns and MF4 channels are derived from these."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Any

_Getter = tuple[str | None, Callable[[Any], Any], bool]
"""Of one column group (of one wheel): the wheel (None: the record itself), the getter of its columns' attributes,
whether it is one column (the getter then gives the value, not a tuple)."""
_PLANS: dict[tuple[int, tuple[str, ...]], tuple[tuple[ColumnGroup, ...], list[str], list[_Getter]]] = {}


def _plan(groups: tuple[ColumnGroup, ...], wheels: tuple[str, ...]) -> tuple[list[str], list[_Getter]]:
    """The column names in order and the getters of a record's values, built once per groups and order of wheels."""
    got = _PLANS.get((id(groups), wheels))
    if got is None or got[0] is not groups:
        keys: list[str] = []
        getters: list[_Getter] = []
        for g in groups:
            get = attrgetter(*[c.attribute for c in g.columns])
            for w in wheels if g.per_wheel else (None,):
                keys += [c.key(w) if w is not None else c.name for c in g.columns]
                getters.append((w, get, len(g.columns) == 1))
        got = _PLANS[(id(groups), wheels)] = (groups, keys, getters)
    return got[1], got[2]


def record_values(record: Any, groups: tuple[ColumnGroup, ...]) -> tuple[list[str], list[Any]]:
    """A record's column names and values in order (a per-wheel group: each of record.wheels in its order); a name
    that comes twice has both values (record_row keeps the last in the first's place)."""
    wheels = getattr(record, "wheels", None) or {}
    keys, getters = _plan(groups, tuple(wheels))
    values: list[Any] = []
    for w, get, single in getters:
        got = get(record if w is None else wheels[w])
        if single:
            values.append(got)
        else:
            values += got
    return keys, values


def record_row(record: Any, groups: tuple[ColumnGroup, ...]) -> dict[str, float | str | None]:
    """A record's flat mapping by its column groups (a per-wheel group: each of record.wheels in its order)."""
    keys, values = record_values(record, groups)
    return dict(zip(keys, values))


@dataclass(frozen=True, slots=True)
class Column:
    """One column of a flat record: its name (`{w}` stands for the wheel), the attribute it holds, what kind of value
    it is, and its unit in the name's suffix (`_s`, `_mps`, `_n`, `_m`)."""

    name: str
    attribute: str
    kind: str
    """'number', 'number?' (or undefined: null, an empty CSV cell), 'integer', 'integer?', 'bool', 'text', 'text?', 'texts' (a
    list of texts), or 'enum'."""
    values: tuple[str, ...] = ()
    """enum: the values it takes."""
    description: str = ""
    """What it is (`{w}`: the wheel): the JSON Schema's description, the MF4 channel's comment."""

    def key(self, wheel: str) -> str:
        return self.name.format(w=wheel)

    def describe(self, wheel: str = "") -> str:
        return self.description.format(w=wheel)


@dataclass(frozen=True, slots=True)
class ColumnGroup:
    """Consecutive columns of a flat record: of the estimate itself, or of each wheel in turn (per_wheel)."""

    columns: tuple[Column, ...]
    per_wheel: bool
    csv: str
    """'contract' (the public CSV columns, in order), 'extra' (appended after them), '' (log only)."""


PHASES = ("standstill", "accelerate", "cruise", "brake")
QUALITIES = ("ok", "uncalibrated", "disturbed")
ACCEL_SOURCES = ("imu", "gps", "imu-orientation", "imu-free", "imu-calibrated")
FAST_ACCEL_SOURCES = ACCEL_SOURCES[:2]
"""The high-rate slip's: imu (the IMU fed its filter, whatever its kind) or gps."""

ESTIMATE_COLUMNS: tuple[ColumnGroup, ...] = (
    ColumnGroup((
        Column("time_s", "time_s", "number",
               description="centre of the estimate's window, seconds in the log's clock"),
        Column("speed_mps", "speed_mps", "number", description="vehicle speed: the mean reference speed over the window"),
        Column("accel_mps2", "accel_mps2", "number?",
               description="longitudinal acceleration over the window (see accel_source); undefined: none"),
        Column("force_n", "force_n", "number?",
               description="total longitudinal force Fx = M*a (plus the road loads when configured)"),
    ), per_wheel=False, csv="contract"),
    ColumnGroup((
        Column("slip_{w}", "slip", "number?",
               description="slip of the {w} wheel, SAE, a fraction; undefined below the minimum speed, across a gap "
                           "in the wheel's samples, or while the latency is unknown and the speed changes"),
        Column("re_{w}_m", "re_m", "number?", description="effective rolling radius Re of the {w} wheel"),
        Column("r0_{w}_m", "r0_m", "number", description="reference radius r0 of the {w} wheel, the one slip was "
                                                         "computed with"),
        Column("cx_{w}_n", "cx_n", "number?", description="longitudinal stiffness Cx = Fx/s of the {w} wheel (N per "
                                                          "unit slip); undefined outside the linear slip region"),
    ), per_wheel=True, csv="contract"),
    ColumnGroup((
        Column("phase", "phase", "enum", PHASES, "maneuver phase"),
        Column("source", "source", "text", description="gps: centred on a reference fix; wheels: GPS lost, speed "
                                                       "from the non-driven wheels"),
        Column("gps_latency_s", "gps_latency_s", "number", description="the GPS latency the estimate used"),
        Column("latency_source", "latency_source", "text",
               description="where the latency came from: fixed, utc, wheels, stored, none"),
    ), per_wheel=False, csv="extra"),
    ColumnGroup((
        Column("r0_source_{w}", "r0_source", "text", description="where r0 of the {w} wheel came from: tire_size, "
               "configured, other_wheels, calibrating, calibrated, stored"),
        Column("slip_nd_{w}", "slip_nd", "number?",
               description="slip of the {w} wheel against the non-driven wheels' speed (driven wheels only)"),
        Column("cx_fit_{w}_n", "cx_fit_n", "number?",
               description="stiffness of the {w} wheel fitted over the run so far (or the stored one)"),
        Column("cx_fit_{w}_conf", "cx_fit_conf", "number?", description="confidence of cx_fit_{w}_n, 0..1"),
    ), per_wheel=True, csv="extra"),
    ColumnGroup((Column("quality", "quality", "enum", QUALITIES, "ok; uncalibrated (latency unknown, or a radius "
                        "from the tire size or the other wheels); disturbed (a gap in the samples, GPS lost)"),),
                per_wheel=False, csv="extra"),
    ColumnGroup((Column("accel_source", "accel_source", "enum", ACCEL_SOURCES, "where accel_mps2 comes from: imu "
                        "(the IMU's mean over the window, as it read: gravity and the body's pitch in it), "
                        "imu-orientation (an MTi's Acceleration less gravity by its orientation), imu-free (an MTi's "
                        "FreeAcceleration on the heading), imu-calibrated (imu corrected by the calibration's gain "
                        "and offset) or gps (the reference speed's central difference)"),),
                per_wheel=False, csv="extra"),
    ColumnGroup((Column("window_s", "window_s", "number", description="the window's length"),),
                per_wheel=False, csv=""),
    ColumnGroup((Column("force_{w}_n", "force_n", "number?", description="the {w} tire's share of Fx"),
                 Column("wheel_speed_{w}_mps", "speed_mps", "number?",
                        description="circumferential speed omega*r0 of the {w} wheel over the window")),
                per_wheel=True, csv=""),
)
"""An estimate's columns, declared once, in the order of its /estimate JSON and its CSV row: the log's JSON, its JSON
Schema, the CSV's columns, the MF4 export's channels and Estimate.as_row are derived from this."""

FAST_SLIP_COLUMNS: tuple[ColumnGroup, ...] = (
    ColumnGroup((Column("time_s", "time_s", "number", description="the instant, seconds in the log's clock"),
                 Column("speed_mps", "speed_mps", "number",
                        description="vehicle speed fused from the reference speed and the IMU")),
                per_wheel=False, csv="contract"),
    ColumnGroup((Column("slip_{w}", "slip", "number?", description="high-rate slip of the {w} wheel, SAE, a fraction; "
                        "undefined below the minimum speed or without the wheel's samples around the instant"),),
                per_wheel=True, csv="contract"),
    ColumnGroup((Column("accel_mps2", "accel_mps2", "number", description="the fused longitudinal acceleration"),
                 Column("accel_source", "accel_source", "enum", FAST_ACCEL_SOURCES,
                        "imu when the IMU's samples fed the filter, else gps")), per_wheel=False, csv=""),
    ColumnGroup((Column("wheel_speed_{w}_mps", "speed_mps", "number?",
                        description="circumferential speed omega*r0 of the {w} wheel at the instant"),),
                per_wheel=True, csv=""),
)
"""A FastSlip's columns (the /slip/fast JSON, its schema, `export --fast-csv`)."""


def column_names(groups: Sequence[ColumnGroup], wheels: Sequence[str], csv: str | None = None) -> tuple[str, ...]:
    """The column names of the groups (those of one CSV class when csv is given), for these wheels."""
    return tuple(c.key(w) if g.per_wheel else c.name for g in groups if csv is None or g.csv == csv
                 for w in (wheels if g.per_wheel else ("",)) for c in g.columns)
