"""MF4 export (asammdf, ASAM MDF 4.10): the estimates, the high-rate wheel speeds and the GPS speed of a log.

Three channel groups, each with its own master channel `time` (s, relative to the file's time origin t0):
- "estimates": one channel per CSV column (csv_export.ALL_COLUMNS, same names), the numbers float64 with NaN where
  the CSV cell is empty (the same float64s: equal bit for bit to float(cell)), the texts as uint8 codes with a
  value-to-text conversion (read back as the texts); master = time_s - t0.
- "wheel speeds": the /slip/fast rows: wheel_speed_W_mps, fast_speed_mps (the fused vehicle speed), fast_slip_W;
  master = their time_s - t0.
- "GPS": the /gps/fix records: gps_speed_mps and gps_valid (uint8, 1 valid); master = their timestamp_s - t0.

t0 is the earliest time of the three, in the log's clock (UTC for live runs); the header's start_time is t0 as a
UTC datetime and its comment states t0 exactly, with the log's labels and config TOML.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, Column

GROUP_ESTIMATES, GROUP_WHEELS, GROUP_GPS = "estimates", "wheel speeds", "GPS"
MDF_VERSION = "4.10"
NAN_NOTE = "float64; NaN where the CSV cell is empty"

GPS_DESCRIPTIONS = {
    "gps_speed_mps": "GPS (reference) speed of the fix (/gps/fix speed_mps)",
    "gps_valid": "1: a valid fix (feeds the estimator), 0: invalid (logged only)",
}
"""The GPS group's channels' comments (the other channels': their columns' descriptions, records.py)."""


def unit_of(name: str) -> str:
    """The unit a column's name states: _mps2 m/s^2, _mps m/s, _s s, _n N, _m m; slip and _conf '1'; else ''."""
    for suffix, unit in (("_mps2", "m/s^2"), ("_mps", "m/s"), ("_s", "s"), ("_n", "N"), ("_m", "m"),
                         ("_conf", "1")):
        if name.endswith(suffix):
            return unit
    return "1" if name.startswith(("slip_", "fast_slip_")) else ""


def _columns() -> list[tuple[str, str, Column]]:
    """(name, wheel or '', Column) of each CSV column (csv_export.ALL_COLUMNS), in the CSV's order."""
    return [(c.key(w) if g.per_wheel else c.name, w, c) for csv in ("contract", "extra") for g in ESTIMATE_COLUMNS
            if g.csv == csv for w in (WHEELS if g.per_wheel else ("",)) for c in g.columns]


def _fast_column(name: str) -> Column:
    """The /slip/fast column of that name (FAST_SLIP_COLUMNS)."""
    return next(c for g in FAST_SLIP_COLUMNS for c in g.columns if c.name == name)


def _floats(values: list[Any]) -> np.ndarray:
    """float64, NaN for None: float(v) is what the CSV's repr(float(v)) reads back as."""
    return np.array([math.nan if v is None else float(v) for v in values], dtype=np.float64)


def _texts(values: list[Any], known: tuple[str, ...]) -> tuple[np.ndarray, dict[str, Any]]:
    """Codes and a value-to-text conversion: the known values first, then the others as they come; None is ''
    (the CSV's empty cell)."""
    texts = ["" if v is None else str(v) for v in values]
    table = list(dict.fromkeys([*known, *texts]))
    code = {t: i for i, t in enumerate(table)}
    dtype = np.uint8 if len(table) <= 256 else np.uint16
    conversion: dict[str, Any] = {}
    for i, t in enumerate(table):
        conversion[f"val_{i}"] = i
        conversion[f"text_{i}"] = t.encode("utf-8")
    return np.array([code[t] for t in texts], dtype=dtype), conversion


_XML_BAD = re.compile("[^\t\n\r\x20-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")


def _xml_safe(text: str) -> str:
    """text without the characters XML 1.0 cannot hold (each becomes U+FFFD) and without spaces at the ends of its
    lines (asammdf strips them when it writes the header comment). asammdf escapes <, > and &."""
    return "\n".join(line.strip() for line in _XML_BAD.sub("\ufffd", text).splitlines())


def header_text(metadata: Mapping[str, str], t0_s: float, log_name: str = "",
                labels: Mapping[str, str] | None = None) -> str:
    """The header comment's text: where the file comes from, t0, the log's labels and its config TOML."""
    labels = labels or {}
    lines = [f"slipdaq export of {log_name or 'a log'} (slipdaq {metadata.get('version', '?')}, "
             f"mode {metadata.get('mode', '?')})",
             f"t0_s = {t0_s!r}: the time origin, seconds in the log's clock (UTC for live runs); each group's master "
             "time is its time_s - t0_s; start_time is t0_s as a UTC date and time",
             "NaN in a float channel = an empty cell of the CSV export (undefined)",
             "labels:" + ("" if labels else " none")]
    lines += [f"label.{k} = {v}" for k, v in labels.items()]
    lines += ["config_toml:", metadata.get("config_toml", "").rstrip()]
    return _xml_safe("\n".join(lines))


def write_mf4(rows: Iterable[Mapping[str, Any]], path: str | Path, *, fast_rows: Iterable[Mapping[str, Any]],
              fixes: Iterable[Mapping[str, Any]], metadata: Mapping[str, str], log_name: str = "",
              labels: Mapping[str, str] | None = None) -> int:
    """Write the estimate rows, the /slip/fast rows and the /gps/fix records (the log's JSON dicts), the log's
    metadata and labels to an MF4 file at path (written as named: no suffix added); returns the number of
    estimates."""
    from asammdf import MDF, Signal

    columns = _columns()
    est: dict[str, list[Any]] = {name: [] for name, _w, _c in columns}
    for r in rows:
        for name, values in est.items():
            values.append(r.get(name))
    fast: dict[str, list[Any]] = {k: [] for k in ("time_s", "speed_mps", *(f"slip_{w}" for w in WHEELS),
                                                  *(f"wheel_speed_{w}_mps" for w in WHEELS))}
    for r in fast_rows:
        for name, values in fast.items():
            values.append(r.get(name))
    gps: dict[str, list[Any]] = {"timestamp_s": [], "speed_mps": [], "valid": []}
    for r in fixes:
        for name, values in gps.items():
            values.append(r.get(name))

    times = [_floats(est["time_s"]), _floats(fast["time_s"]), _floats(gps["timestamp_s"])]
    t0_s = min((float(np.nanmin(t)) for t in times if np.isfinite(t).any()), default=0.0)

    signals = []
    for name, wheel, c in columns:
        comment = c.describe(wheel)
        if c.kind.startswith("number"):
            signals.append(Signal(_floats(est[name]), times[0] - t0_s, name=name, unit=unit_of(name),
                                  comment=f"{comment} ({NAN_NOTE})"))
        else:
            codes, conversion = _texts(est[name], c.values)
            signals.append(Signal(codes, times[0] - t0_s, name=name, unit="", conversion=conversion,
                                  comment=f"{comment} (text: integer codes with a value-to-text conversion)"))

    wheel_signals = [Signal(_floats(fast[f"wheel_speed_{w}_mps"]), times[1] - t0_s, name=f"wheel_speed_{w}_mps",
                            unit="m/s", comment=f"{_fast_column('wheel_speed_{w}_mps').describe(w)} ({NAN_NOTE})")
                     for w in WHEELS]
    wheel_signals.append(Signal(_floats(fast["speed_mps"]), times[1] - t0_s, name="fast_speed_mps", unit="m/s",
                                comment=f"{_fast_column('speed_mps').describe()} (/slip/fast speed_mps)"))
    wheel_signals += [Signal(_floats(fast[f"slip_{w}"]), times[1] - t0_s, name=f"fast_slip_{w}", unit="1",
                             comment=f"{_fast_column('slip_{w}').describe(w)} (/slip/fast slip_{w}; {NAN_NOTE})")
                      for w in WHEELS]

    gps_signals = [
        Signal(_floats(gps["speed_mps"]), times[2] - t0_s, name="gps_speed_mps", unit="m/s",
               comment=f"{GPS_DESCRIPTIONS['gps_speed_mps']} (float64)"),
        Signal(np.array([bool(v) for v in gps["valid"]], dtype=np.uint8), times[2] - t0_s, name="gps_valid",
               unit="", comment=f"{GPS_DESCRIPTIONS['gps_valid']} (uint8)"),
    ]

    mdf = MDF(version=MDF_VERSION)
    try:
        mdf.header.start_time = dt.datetime.fromtimestamp(t0_s, dt.UTC)
        mdf.header.comment = header_text(metadata, t0_s, log_name, labels)
        mdf.append(signals, acq_name=GROUP_ESTIMATES, comment="one channel per CSV column (export --csv)")
        mdf.append(wheel_signals, acq_name=GROUP_WHEELS, comment="the high-rate wheel speeds and slip (/slip/fast)")
        mdf.append(gps_signals, acq_name=GROUP_GPS, comment="the GPS fixes' speed (/gps/fix)")
        with open(path, "wb+") as f:  # a file object: asammdf would give a path the suffix .mf4
            mdf.save(f, overwrite=True)
    finally:
        mdf.close()
    return len(est["time_s"])
