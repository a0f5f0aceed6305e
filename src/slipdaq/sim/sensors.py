"""The simulated vehicle's other CAN sensors as frames, encoded with cantools by the config's DBC names: the IMU's
longitudinal acceleration ([imu]), the brake switch ([brake]) and a reference speed ([gps] message/signal).

Each value is written as the reader would decode it back: physical = raw*scale + offset in the signal's unit, so
    IMU:       value = a * sign / (m/s^2 per unit)        ([imu].unit, else the DBC's; sign: reader's a = sign*value)
    reference: value = V / (m/s per unit),  valid = 1,  accuracy = sigma / (m/s per accuracy unit)
The message's other signals are 0 (or their minimum when 0 is out of range). Values are clamped to the signal's range.
"""

from __future__ import annotations

from collections.abc import Mapping

import cantools

from slipdaq.config import Config
from slipdaq.decode.can_wheels import MPS_PER_UNIT, DbcError, load_dbc
from slipdaq.records import CanFrame

G_MPS2 = 9.80665
"""Standard gravity, for an acceleration signal in g."""
MPS2_PER_UNIT = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "mps2": 1.0, "g": G_MPS2}
"""m/s^2 per unit of an acceleration signal (lower case)."""


def _unit_scale(table: Mapping[str, float], unit: str | None, what: str) -> float:
    key = (unit or "").strip().lower().replace(" ", "")
    if key not in table:
        raise DbcError(f"{what}: unit {unit!r} is not one of {', '.join(table)}: set the config's unit")
    return table[key]


def _resting_value(signal: cantools.database.can.Signal) -> float:
    """0, or the signal's minimum (maximum) when 0 is below (above) its range."""
    if signal.minimum is not None and signal.minimum > 0:
        return float(signal.minimum)
    if signal.maximum is not None and signal.maximum < 0:
        return float(signal.maximum)
    return 0.0


class SignalMessage:
    """One DBC message, encoded with the named signals set and every other signal at its resting value."""

    def __init__(self, db: cantools.database.can.Database, message: str, key: str) -> None:
        try:
            self.message = db.get_message_by_name(message)
        except KeyError:
            raise DbcError(f"{key}: message {message} not found in DBC") from None
        self.resting = {s.name: _resting_value(s) for s in self.message.signals}

    def signal(self, name: str, key: str) -> cantools.database.can.Signal:
        try:
            return self.message.get_signal_by_name(name)
        except KeyError:
            raise DbcError(f"{key}: signal {self.message.name}.{name} not found in DBC") from None

    def frame(self, timestamp_s: float, values: Mapping[str, float]) -> CanFrame:
        """The frame with values (physical, clamped to each signal's [minimum, maximum])."""
        data = dict(self.resting)
        for name, value in values.items():
            sig = self.message.get_signal_by_name(name)
            if sig.minimum is not None:
                value = max(float(sig.minimum), value)
            if sig.maximum is not None:
                value = min(float(sig.maximum), value)
            data[name] = value
        msg = self.message
        return CanFrame(timestamp_s, msg.frame_id, bytes(msg.encode(data)), msg.is_extended_frame)


class SensorEncoder:
    """The sensors the config names ([imu], [brake], [gps] message/signal); each is None when not named."""

    def __init__(self, config: Config) -> None:
        self.imu: SignalMessage | None = None
        self.brake: SignalMessage | None = None
        self.reference: SignalMessage | None = None
        self._imu_signal = self._brake_signal = self._speed_signal = ""
        self._imu_per_mps2 = self._speed_per_mps = self._accuracy_per_mps = 1.0
        self._valid_signal: str | None = None
        self._accuracy_signal: str | None = None
        imu, brake, gps = config.imu, config.brake, config.gps
        if imu.message is None and brake.message is None and gps.message is None:
            return
        db = load_dbc(config.load_dbc_text())
        if imu.message is not None and imu.signal is not None:
            self.imu = SignalMessage(db, imu.message, "imu.message")
            sig = self.imu.signal(imu.signal, "imu.signal")
            self._imu_signal = sig.name
            self._imu_per_mps2 = imu.sign / _unit_scale(MPS2_PER_UNIT, imu.unit or sig.unit, f"imu.signal {sig.name}")
        if brake.message is not None and brake.signal is not None:
            self.brake = SignalMessage(db, brake.message, "brake.message")
            self._brake_signal = self.brake.signal(brake.signal, "brake.signal").name
        if gps.message is not None and gps.signal is not None:
            self.reference = SignalMessage(db, gps.message, "gps.message")
            sig = self.reference.signal(gps.signal, "gps.signal")
            self._speed_signal = sig.name
            speed_scale = _unit_scale(MPS_PER_UNIT, gps.unit or sig.unit, f"gps.signal {sig.name}")
            self._speed_per_mps = 1.0 / speed_scale
            self._valid_signal = None if gps.valid_signal is None else \
                self.reference.signal(gps.valid_signal, "gps.valid_signal").name
            self._accuracy_per_mps = self._speed_per_mps
            if gps.accuracy_signal is not None:
                acc = self.reference.signal(gps.accuracy_signal, "gps.accuracy_signal")
                self._accuracy_signal = acc.name
                self._accuracy_per_mps = 1.0 / MPS_PER_UNIT.get((acc.unit or "").strip().lower(), speed_scale)

    def imu_frame(self, timestamp_s: float, accel_mps2: float) -> CanFrame:
        """The IMU's frame carrying the longitudinal acceleration a (value = a*sign in the signal's unit)."""
        assert self.imu is not None
        return self.imu.frame(timestamp_s, {self._imu_signal: accel_mps2 * self._imu_per_mps2})

    def brake_frame(self, timestamp_s: float, pressed: bool) -> CanFrame:
        """The brake message with its signal 1 (pressed) or 0."""
        assert self.brake is not None
        return self.brake.frame(timestamp_s, {self._brake_signal: 1.0 if pressed else 0.0})

    def reference_frame(self, timestamp_s: float, speed_mps: float, accuracy_mps: float) -> CanFrame:
        """The reference-speed message: speed, valid = 1, accuracy (1 sigma), each in its signal's unit."""
        assert self.reference is not None
        values = {self._speed_signal: speed_mps * self._speed_per_mps}
        if self._valid_signal is not None:
            values[self._valid_signal] = 1.0
        if self._accuracy_signal is not None:
            values[self._accuracy_signal] = accuracy_mps * self._accuracy_per_mps
        return self.reference.frame(timestamp_s, values)
