"""CAN frames -> the vehicle's other sensors, by DBC message and signal names (cantools): the reference speed
([gps] source = "can": a VBOX, an OxTS RT, a CAN GNSS module), the longitudinal acceleration ([imu]) and the brake
([brake]). Each decoded value is a SensorSample, in frame order; the unit is converted to SI here (m/s, m/s^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from slipdaq.config import Config
from slipdaq.decode.can_wheels import MPS_PER_UNIT, DbcError, load_dbc
from slipdaq.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_REMOTE, SENSOR_KINDS, CanFrameBatch, SensorSample

if TYPE_CHECKING:
    import cantools

REFERENCE, IMU, BRAKE = SENSOR_KINDS[:3]
STANDARD_GRAVITY_MPS2 = 9.80665
"""1 g, for an acceleration signal in g."""
_MPS2_PER_UNIT = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "mps2": 1.0, "g": STANDARD_GRAVITY_MPS2}


@dataclass(slots=True)
class _Read:
    kind: str
    signal: str
    scale: float
    """SI units per signal unit (times the IMU's sign)."""
    valid_signal: str | None = None
    accuracy_signal: str | None = None
    accuracy_scale: float = 1.0


def _unit_scale(table: dict[str, float], unit: str | None, key: str, what: str, allowed: str) -> float:
    u = (unit or "").strip().lower().replace(" ", "")
    if u in table:
        return table[u]
    raise DbcError(f"{key}: {what} has unit {unit!r}: set {key.rsplit('.', 1)[0]}.unit to one of {allowed}")


def _message(db: cantools.database.Database, name: str, key: str) -> cantools.database.Message:
    try:
        return db.get_message_by_name(name)
    except KeyError:
        raise DbcError(f"{key}: message {name} not found in DBC") from None


def _signal(msg: cantools.database.Message, name: str, key: str) -> cantools.database.Signal:
    for s in msg.signals:
        if s.name == name:
            return s
    raise DbcError(f"{key}: signal {msg.name}.{name} not found in DBC")


class SignalDecoder:
    """Stateless: the configured sensor signals of a batch's frames, in frame order (a frame's reference speed, then
    its acceleration, then its brake)."""

    def __init__(self, config: Config, dbc_text: str | None = None) -> None:
        self._reads: dict[int, tuple[cantools.database.Message, list[_Read]]] = {}
        self.bad_frames = 0
        g, imu, brake = config.gps, config.imu, config.brake
        if g.source != "can" and imu.message is None and brake.message is None:
            return
        db = load_dbc(dbc_text if dbc_text is not None else config.load_dbc_text())
        if g.source == "can":
            assert g.message is not None and g.signal is not None  # GpsConfig's validator
            msg = _message(db, g.message, "gps.message")
            sig = _signal(msg, g.signal, "gps.signal")
            scale = _unit_scale(MPS_PER_UNIT, g.unit or sig.unit, "gps.unit", f"{msg.name}.{sig.name}",
                                "km/h, m/s, mph, kn")
            read = _Read(REFERENCE, sig.name, scale)
            if g.valid_signal is not None:
                read.valid_signal = _signal(msg, g.valid_signal, "gps.valid_signal").name
            if g.accuracy_signal is not None:
                acc = _signal(msg, g.accuracy_signal, "gps.accuracy_signal")
                read.accuracy_signal = acc.name
                read.accuracy_scale = MPS_PER_UNIT.get((acc.unit or "").strip().lower(), scale)
            self._add(msg, read)
        if imu.message is not None:
            assert imu.signal is not None
            msg = _message(db, imu.message, "imu.message")
            sig = _signal(msg, imu.signal, "imu.signal")
            scale = _unit_scale(_MPS2_PER_UNIT, imu.unit or sig.unit, "imu.unit", f"{msg.name}.{sig.name}", "m/s^2, g")
            self._add(msg, _Read(IMU, sig.name, scale * imu.sign))
        if brake.message is not None:
            assert brake.signal is not None
            msg = _message(db, brake.message, "brake.message")
            self._add(msg, _Read(BRAKE, _signal(msg, brake.signal, "brake.signal").name, 1.0))
        self._ids = np.array(sorted(self._reads), dtype=np.int64)
        self._extended = {fid: m.is_extended_frame for fid, (m, _) in self._reads.items()}

    def _add(self, msg: cantools.database.Message, read: _Read) -> None:
        self._reads.setdefault(msg.frame_id, (msg, []))[1].append(read)

    def __bool__(self) -> bool:
        return bool(self._reads)

    def sensor_frames(self, batch: CanFrameBatch) -> np.ndarray:
        """Indices of the frames that carry a configured signal (by ID, data frames only)."""
        if not self._reads:
            return np.empty(0, dtype=np.int64)
        ids = batch.arbitration_id.astype(np.int64)
        hit = np.isin(ids, self._ids) & ((batch.flags & (FLAG_ERROR | FLAG_REMOTE)) == 0)
        sel = np.flatnonzero(hit)
        if len(sel):
            ext = (batch.flags[sel] & FLAG_EXTENDED) != 0
            want = np.array([self._extended[int(i)] for i in ids[sel]], dtype=bool)
            sel = sel[ext == want]
        return sel

    def decode(self, batch: CanFrameBatch, frames: np.ndarray | None = None) -> list[tuple[int, SensorSample]]:
        """(frame index in the batch, sample) of the batch's configured signals, in frame order; frames:
        sensor_frames(batch), when the caller has it already."""
        out: list[tuple[int, SensorSample]] = []
        for i in (self.sensor_frames(batch) if frames is None else frames).tolist():
            msg, reads = self._reads[int(batch.arbitration_id[i])]
            try:
                values = msg.decode_simple(batch.payload(i), decode_choices=False, scaling=True)
            except Exception:  # wrong DLC or bytes cantools cannot decode
                self.bad_frames += 1
                continue
            t = float(batch.timestamp_s[i])
            for r in reads:
                raw = values.get(r.signal)
                if not isinstance(raw, int | float):  # multiplexed out
                    continue
                value = float(raw) * r.scale
                if r.kind == BRAKE:
                    value = 1.0 if raw != 0 else 0.0
                valid = math.isfinite(value)
                if r.valid_signal is not None:
                    flag = values.get(r.valid_signal)
                    valid = valid and isinstance(flag, int | float) and flag != 0
                accuracy = None
                if r.accuracy_signal is not None:
                    acc = values.get(r.accuracy_signal)
                    if isinstance(acc, int | float):
                        accuracy = float(acc) * r.accuracy_scale
                out.append((i, SensorSample(t, r.kind, value, valid, accuracy)))
        return out
