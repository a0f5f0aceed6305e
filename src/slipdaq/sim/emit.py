"""The vehicle model turned into raw records: WPT CAN frames, NMEA lines and truth samples. No I/O, no clock.

WPT:   PulseCount = (start_count + floor(theta/(2*pi) * pulses_per_rev)) mod 2^32 at the nominal sampling instant,
       Seq = frame index mod 256 per wheel; wheel i of WHEELS is sampled at k/rate + i/(4*rate).
GPS:   epoch k at k/gps_rate describes the truth at that instant; its RMC, GGA, VTG lines arrive gps_latency_s later.
       With brake_timemark_edge, the brake's press is that edge on the receiver's EXTINT pin: a UBX TIM-TM2 of it
       (its exact instant in GPS time) follows the first epoch at or after it.
CAN sensors (each only with its SimSettings rate > 0 and the config naming its message and signal; sensors.py):
       IMU at k/imu_rate: truth a + N(0, imu_noise); brake switch at k/brake_rate: truth brake_pressed;
       reference speed measured at k/ref_rate: truth V + N(0, ref_noise), sent ref_speed_latency_s later.
       Their frames arrive with CAN jitter from their own generator; the WPT's random draws are not disturbed.
MTi:   with [imu] source = "serial", the IMU's samples (the same values and arrival jitter) are an Xsens MTi's MTData2
       messages instead (XbusBytes; xbus_encode.SimulatedMti), not affected by a CAN stall.
Pitch: with pitch_deg_per_g or grade_deg, the IMUs read the pitched body's specific force (sim/pitch.py): the CAN
       IMU a*cos(theta) + g*sin(theta + grade), the MTi its tilted axes' with its Quaternion.
Truth: a TruthSample every 10 ms, at every GPS epoch and at the brake's press (where the model knows it).
Event times are seconds since the simulation start; record timestamps are start_utc_s + time_s.
Stall: with SimSettings.can_stall, frames are stamped when a stalled reader reads them (_StalledReader).
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial

import cantools
import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.decode.can_wheels import load_dbc
from slipdaq.records import CanFrame, NmeaLine, UbxFrame, XbusBytes
from slipdaq.sim import Scenario
from slipdaq.sim.pitch import BodyPitch
from slipdaq.sim.road_loads import RoadLoadTruth
from slipdaq.sim.scenarios import vehicle_model
from slipdaq.sim.sensors import SensorEncoder
from slipdaq.sim.vehicle import Road, TruthSample
from slipdaq.sim.xbus_encode import SimulatedMti

TRUTH_RATE_HZ = 100.0
"""Truth samples per second (plus one at every GPS epoch)."""
COUNT_MODULUS = 2**32
SEQ_MODULUS = 256
KNOT_MPS = 1852.0 / 3600.0
EARTH_RADIUS_M = 6_371_008.8
"""Mean Earth radius, for the local flat-earth position x -> (lat, lon)."""


@dataclass(frozen=True)
class SimSettings:
    wpt_rate_hz: float = 100.0
    """Frames per second per wheel (<= 0: no WPT frames)."""
    gps_rate_hz: float = 10.0
    """GPS epochs per second (<= 0: no GPS lines)."""
    gps_latency_s: float = 0.0
    """Delay from the fix's epoch time to the arrival of its sentences."""
    gps_noise_mps: float = 0.02
    """Standard deviation of the Gaussian speed noise."""
    can_jitter_s: float = 0.0
    """Frames arrive at the sampling time plus uniform [0, can_jitter_s)."""
    start_count: int = 2**32 - 20000
    """PulseCount at angle 0 (close to 2^32, so counts wrap early in every run)."""
    seed: int = 1
    step_s: float = 0.001
    """Largest model integration step."""
    start_utc_s: float = 1_767_225_600.0
    """Wall-clock time of sim time 0 (2026-01-01T00:00:00Z)."""
    gps_protocol: str = "nmea"
    """What the receiver sends each epoch: "nmea" (RMC, GGA, VTG), "ubx" (UBX NAV-PVT) or "both"."""
    host_clock_offset_s: float = 0.0
    """Host clock minus true UTC: added to every record's timestamp (the NMEA UTC fields stay true)."""
    can_stall: tuple[float, float] | None = None
    """(start_s, duration_s) in sim time: the CAN reader stalls. Frames arriving in [start, start + duration) are
    stamped when it reads them: all at start + duration, in arrival order, 1 us apart; a frame arriving while that
    backlog is read is read after it (1 us after the backlog's last). GPS is not affected. None: no stall."""
    origin_lat_deg: float = 52.0
    origin_lon_deg: float = 10.0
    heading_deg: float = 90.0
    imu_rate_hz: float = 0.0
    """IMU frames per second ([imu] message/signal; <= 0: none)."""
    imu_noise_mps2: float = 0.05
    """Standard deviation of the Gaussian noise on the IMU's acceleration."""
    brake_rate_hz: float = 0.0
    """Brake switch frames per second ([brake] message/signal; <= 0: none)."""
    ref_speed_rate_hz: float = 0.0
    """Reference speed frames per second on CAN ([gps] message/signal; <= 0: none)."""
    ref_speed_latency_s: float = 0.02
    """A reference speed frame sent at t carries the speed at t - ref_speed_latency_s."""
    ref_speed_noise_mps: float = 0.02
    """Standard deviation of the Gaussian noise on the reference speed (also its reported accuracy)."""
    brake_speed_kmh: float | None = None
    """brake-abs, brake-abs-all, brake-lock: the speed the brake is applied at (None: the scenario's, 80 km/h)."""
    brake_onset_s: float | None = None
    """... and when, in sim time (None: the scenario's, 3 s); off the sensors' sampling grid, as a driver's foot is."""
    brake_timemark_edge: str | None = None
    """"rising" or "falling": the GPS stream carries a UBX TIM-TM2 time mark of the brake's press as this edge (the
    brake-light switch on the receiver's EXTINT pin); None: no time mark."""
    pitch_deg_per_g: float = 0.0
    """The body's pitch per g of acceleration, nose up accelerating (sim/pitch.py): in the IMUs' readings."""
    grade_deg: float = 0.0
    """The road's grade as the IMUs see it (sim/pitch.py; the vehicle model's road stays level)."""


@dataclass(frozen=True, slots=True)
class SimEvent:
    time_s: float
    """Seconds since the simulation start at which the record arrives (or the truth holds)."""
    record: CanFrame | NmeaLine | UbxFrame | XbusBytes | None
    truth: TruthSample | None


class WptEncoder:
    """Encodes WPT frames with the DBC's messages WPT_<wheel> and signals PulseCount, Seq (looked up by name).

    When both signals are plain little-endian unsigned raw values, the payload is packed directly as
    PulseCount << start | Seq << start (checked against cantools' encode at construction); otherwise cantools encodes.
    """

    _CHECK_VALUES = ((0, 0), (2**32 - 1, 255), (0x12345678, 0xA5))

    def __init__(self, config: Config) -> None:
        db = load_dbc(config.load_dbc_text())
        self.messages = [db.get_message_by_name(f"WPT_{w}") for w in WHEELS]
        self._shifts = [self._packing_shifts(m) for m in self.messages]

    @classmethod
    def _packing_shifts(cls, msg: cantools.database.can.Message) -> tuple[int, int] | None:
        """(PulseCount start bit, Seq start bit) if direct packing reproduces cantools' encode, else None."""
        signals = [msg.get_signal_by_name(name) for name in ("PulseCount", "Seq")]
        if any(s.byte_order != "little_endian" or s.is_signed or s.scale != 1 or s.offset != 0 for s in signals):
            return None
        shifts = (signals[0].start, signals[1].start)
        for count, seq in cls._CHECK_VALUES:
            packed = ((count << shifts[0]) | (seq << shifts[1])).to_bytes(msg.length, "little")
            try:
                if bytes(msg.encode({"PulseCount": count, "Seq": seq})) != packed:
                    return None
            except (ValueError, KeyError, cantools.database.errors.Error):
                return None
        return shifts

    def frame(self, wheel_index: int, timestamp_s: float, count: int, seq: int) -> CanFrame:
        """The CanFrame of WPT_<WHEELS[wheel_index]> carrying count and seq."""
        msg, shifts = self.messages[wheel_index], self._shifts[wheel_index]
        if shifts is None:
            data = bytes(msg.encode({"PulseCount": count, "Seq": seq}))
        else:
            data = ((count << shifts[0]) | (seq << shifts[1])).to_bytes(msg.length, "little")
        return CanFrame(timestamp_s, msg.frame_id, data, msg.is_extended_frame)


def pulse_count(angle_rad: float, start_count: int, pulses_per_rev: int) -> int:
    """(start_count + floor(theta/(2*pi) * pulses_per_rev)) mod 2^32."""
    return (start_count + math.floor(angle_rad / (2.0 * math.pi) * pulses_per_rev)) % COUNT_MODULUS


def nmea_sentence(body: str) -> str:
    """'$' + body + '*HH', HH = XOR of the body's bytes (NMEA 0183 checksum)."""
    checksum = 0
    for byte in body.encode("ascii"):
        checksum ^= byte
    return f"${body}*{checksum:02X}"


def _nmea_angle(value_deg: float, degree_digits: int, positive: str, negative: str) -> tuple[str, str]:
    """Degrees -> ('ddmm.mmmmm' or 'dddmm.mmmmm', hemisphere), rounded to 1e-5 minute."""
    units = round(abs(value_deg) * 60 * 100_000)
    degrees, rem = divmod(units, 60 * 100_000)
    minutes, frac = divmod(rem, 100_000)
    return f"{degrees:0{degree_digits}d}{minutes:02d}.{frac:05d}", positive if value_deg >= 0 else negative


def _nmea_time_date(utc_s: float) -> tuple[str, str]:
    """UTC seconds -> ('hhmmss.ss', 'ddmmyy')."""
    seconds, hundredths = divmod(round(utc_s * 100), 100)
    t = datetime.fromtimestamp(seconds, UTC)
    return f"{t:%H%M%S}.{hundredths:02d}", f"{t:%d%m%y}"


def position_deg(distance_m: float, settings: SimSettings) -> tuple[float, float]:
    """(lat, lon) after distance_m along heading from the origin (local flat earth)."""
    heading = math.radians(settings.heading_deg)
    north_m, east_m = distance_m * math.cos(heading), distance_m * math.sin(heading)
    lat = settings.origin_lat_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = settings.origin_lon_deg + math.degrees(
        east_m / (EARTH_RADIUS_M * math.cos(math.radians(settings.origin_lat_deg)))
    )
    return lat, lon


def course_deg(truth: TruthSample, settings: SimSettings) -> float:
    """The course over ground: the settings' heading, turned by 180 degrees on a return run (truth.outbound False;
    the position keeps running along the heading)."""
    return (settings.heading_deg + (0.0 if truth.outbound else 180.0)) % 360.0


def gps_epoch_lines(truth: TruthSample, speed_mps: float, settings: SimSettings) -> list[str]:
    """RMC, GGA, VTG sentences (talker GP) for a fix at truth.time_s with the given speed over ground."""
    hms, ddmmyy = _nmea_time_date(settings.start_utc_s + truth.time_s)
    lat, lon = position_deg(truth.distance_m, settings)
    lat_s, ns = _nmea_angle(lat, 2, "N", "S")
    lon_s, ew = _nmea_angle(lon, 3, "E", "W")
    knots, kmh, course = speed_mps / KNOT_MPS, speed_mps * 3.6, course_deg(truth, settings)
    return [
        nmea_sentence(f"GPRMC,{hms},A,{lat_s},{ns},{lon_s},{ew},{knots:.3f},{course:.1f},{ddmmyy},,,A"),
        nmea_sentence(f"GPGGA,{hms},{lat_s},{ns},{lon_s},{ew},1,12,0.8,100.0,M,0.0,M,,"),
        nmea_sentence(f"GPVTG,{course:.1f},T,,M,{knots:.3f},N,{kmh:.3f},K,A"),
    ]


def nav_pvt_frame(truth: TruthSample, speed_mps: float, settings: SimSettings) -> bytes:
    """A UBX NAV-PVT frame for a fix at truth.time_s: ground speed to 1 mm/s, its accuracy = the noise's sigma."""
    from pyubx2 import GET, UBXMessage

    utc_s = settings.start_utc_s + truth.time_s
    seconds = math.floor(utc_s)
    t = datetime.fromtimestamp(seconds, UTC)
    lat, lon = position_deg(truth.distance_m, settings)
    msg = UBXMessage(
        "NAV", "NAV-PVT", GET, iTOW=int(round((utc_s % 604800) * 1000)), year=t.year, month=t.month, day=t.day,
        hour=t.hour, min=t.minute, second=t.second, validDate=1, validTime=1, fullyResolved=1,
        nano=int(round((utc_s - seconds) * 1e9)), fixType=3, gnssFixOk=1, numSV=12, lat=lat, lon=lon,
        hMSL=100000, gSpeed=int(round(speed_mps * 1000)), sAcc=max(int(round(settings.gps_noise_mps * 1000)), 1),
        headMot=course_deg(truth, settings),
    )
    return bytes(msg.serialize())


def tim_tm2_frame(edge_utc_s: float, edge: str, count: int) -> bytes:
    """A UBX TIM-TM2 frame marking an edge ("rising" or "falling") at edge_utc_s (UTC seconds since 1970) in GPS
    time (time base GNSS, UTC available, time valid); the other edge's fields 0."""
    from pyubx2 import GET, UBXMessage

    from slipdaq.decode.timemark import GPS_EPOCH_UNIX_S, SECONDS_PER_WEEK, utc_to_gps_s

    since_epoch_s = utc_to_gps_s(edge_utc_s) - GPS_EPOCH_UNIX_S
    week = math.floor(since_epoch_s / SECONDS_PER_WEEK)
    tow_ms_f = (since_epoch_s - week * SECONDS_PER_WEEK) * 1000.0
    tow_ms = math.floor(tow_ms_f)
    sub_ns = min(round((tow_ms_f - tow_ms) * 1e6), 999_999)
    key = "R" if edge == "rising" else "F"
    msg = UBXMessage("TIM", "TIM-TM2", GET, ch=0, mode=1, run=1, newFallingEdge=int(key == "F"), timeBase=1, utc=1,
                     time=1, newRisingEdge=int(key == "R"), count=count, accEst=20,
                     **{f"wn{key}": week, f"towMs{key}": tow_ms, f"towSubMs{key}": sub_ns})
    return bytes(msg.serialize())


class _Jitter:
    """Uniform [0, jitter_s) delays from a seeded generator, drawn in blocks."""

    def __init__(self, jitter_s: float, rng: np.random.Generator) -> None:
        self.jitter_s, self.rng = jitter_s, rng
        self._block: list[float] = []

    def next_s(self) -> float:
        if self.jitter_s <= 0.0:
            return 0.0
        if not self._block:
            self._block = (self.rng.random(1024) * self.jitter_s).tolist()[::-1]
        return self._block.pop()


FrameMaker = Callable[[float], CanFrame]
"""Builds a CAN frame given its record timestamp (start_utc_s + host offset + stamp time), for frames whose stamp
is known only when a (stalled) reader reads them."""


class _StalledReader:
    """CAN frame times as a reader that stalls over [start_s, end_s) and stamps frames when it reads them: the
    frames that arrived in the stall are read at end_s, in arrival order, READ_SPACING_S apart (a driver that stamps
    on read, draining its buffer); a frame arriving before the last of them is read is queued behind it.

    Frames arriving from start_s on are held until the stall's end is reached (flush): only then are all the
    stalled frames, and so the backlog's length, known."""

    READ_SPACING_S = 1e-6

    def __init__(self, start_s: float, duration_s: float) -> None:
        if not (duration_s >= 0.0 and math.isfinite(start_s) and math.isfinite(duration_s)):
            raise ValueError(f"can_stall must be (start_s, duration_s >= 0), finite: {(start_s, duration_s)}")
        self.start_s, self.end_s = start_s, start_s + duration_s
        self.held: list[tuple[float, int, FrameMaker]] = []
        """(arrival_s, order, frame maker) of the frames arriving from start_s on, until the flush."""
        self.flushed = False
        self.last_read_s = -math.inf
        """The read time of the backlog's last frame."""

    def holds(self, arrival_s: float) -> bool:
        return not self.flushed and arrival_s >= self.start_s

    def read_time(self, arrival_s: float) -> float:
        """A frame's stamp after the flush: its arrival, or behind the backlog when it arrives before its end."""
        if arrival_s <= self.last_read_s:
            self.last_read_s += self.READ_SPACING_S
            return self.last_read_s
        return arrival_s

    def flush(self) -> list[tuple[float, FrameMaker]]:
        """(stamp_s, frame maker) of the held frames, in read order."""
        self.flushed = True
        out = []
        stalled = 0
        for arrival_s, _, make in sorted(self.held, key=lambda held: held[:2]):
            if arrival_s < self.end_s:
                self.last_read_s = stamp_s = self.end_s + stalled * self.READ_SPACING_S
                stalled += 1
            else:
                stamp_s = self.read_time(arrival_s)
            out.append((stamp_s, make))
        self.held = []
        return out


def _instant(index: int, rate_hz: float) -> float:
    """index/rate as one correctly rounded division, so coinciding instants of different streams compare equal."""
    return index / rate_hz if rate_hz > 0 else math.inf


def generate(
    config: Config,
    scenario: Scenario,
    road: Road,
    settings: SimSettings = SimSettings(),
    duration_s: float | None = None,
    r0_offset_m: float | Mapping[str, float] = 0.0,
    road_loads: RoadLoadTruth | None = None,
) -> Iterator[SimEvent]:
    """Events in nondecreasing time_s over [0, duration_s) (forever when duration_s is None); road_loads: the car's
    road loads and rotating masses (sim/road_loads.py; none unless given, but coast-down's own car)."""
    sim = vehicle_model(config, scenario, road, r0_offset_m, max_step_s=settings.step_s,
                        brake_speed_mps=None if settings.brake_speed_kmh is None else settings.brake_speed_kmh / 3.6,
                        brake_onset_s=settings.brake_onset_s, road_loads=road_loads)
    # the brake's press: a truth sample then; with brake_timemark_edge, its TIM-TM2 after the next epoch
    t_press = sim.brake_onset_s if sim.brake_onset_s is not None else math.inf
    marked: float | None = None
    encoder = WptEncoder(config)
    wants_sensors = settings.imu_rate_hz > 0 or settings.brake_rate_hz > 0 or settings.ref_speed_rate_hz > 0
    sensors = SensorEncoder(config) if wants_sensors else None
    body = BodyPitch(settings.pitch_deg_per_g, settings.grade_deg)
    mti = SimulatedMti(config.imu.axis, config.imu.sign, settings.start_utc_s, settings.heading_deg, body) \
        if config.imu.source == "serial" and settings.imu_rate_hz > 0 else None
    imu_rate_hz = settings.imu_rate_hz if mti is not None or (sensors is not None and sensors.imu is not None) else 0.0
    brake_rate_hz = settings.brake_rate_hz if sensors is not None and sensors.brake is not None else 0.0
    ref_rate_hz = settings.ref_speed_rate_hz if sensors is not None and sensors.reference is not None else 0.0
    sensor_jitter = _Jitter(settings.can_jitter_s, np.random.default_rng([settings.seed, 5]))
    imu_rng = np.random.default_rng([settings.seed, 3])
    ref_rng = np.random.default_rng([settings.seed, 4])
    jitter = _Jitter(settings.can_jitter_s, np.random.default_rng([settings.seed, 1]))
    noise_rng = np.random.default_rng([settings.seed, 2])
    pulses_per_rev, wheel_count = config.wpt.pulses_per_rev, len(WHEELS)
    slot_rate_hz = settings.wpt_rate_hz * wheel_count
    end_s = math.inf if duration_s is None else duration_s
    host_t0_s = settings.start_utc_s + settings.host_clock_offset_s
    pending: list[tuple[float, int, SimEvent]] = []
    order = itertools.count()
    stall = None if settings.can_stall is None else _StalledReader(*settings.can_stall)
    held_order = itertools.count()

    def push(time_s: float, record: CanFrame | NmeaLine | UbxFrame | XbusBytes | None,
             truth: TruthSample | None = None) -> None:
        heapq.heappush(pending, (time_s, next(order), SimEvent(time_s, record, truth)))

    def push_can(arrival_s: float, make: FrameMaker) -> None:
        """A frame arriving at arrival_s: stamped then, or held and stamped when a stalled reader reads it."""
        if stall is None:
            push(arrival_s, make(host_t0_s + arrival_s))
        elif stall.holds(arrival_s):
            stall.held.append((arrival_s, next(held_order), make))
        else:
            stamp_s = stall.read_time(arrival_s)
            push(stamp_s, make(host_t0_s + stamp_s))

    def wpt_maker(wheel: int, count: int, seq: int) -> FrameMaker:
        return lambda timestamp_s: encoder.frame(wheel, timestamp_s, count, seq)

    n_slot = n_truth = n_gps = n_imu = n_brake = n_ref = 0
    t_slot, t_truth, t_gps = _instant(0, slot_rate_hz), 0.0, _instant(0, settings.gps_rate_hz)
    t_imu, t_brake, t_ref = _instant(0, imu_rate_hz), _instant(0, brake_rate_hz), _instant(0, ref_rate_hz)
    while True:
        t = min(t_slot, t_truth, t_gps, t_imu, t_brake, t_ref, t_press)
        if stall is not None and not stall.flushed and t >= stall.end_s:  # all frames of the stall known
            for stamp_s, make in stall.flush():
                push(stamp_s, make(host_t0_s + stamp_s))
        while pending and pending[0][0] <= t and pending[0][0] < end_s:
            yield heapq.heappop(pending)[2]
        if t >= end_s:
            return
        sim.advance_to(t)
        if t_truth == t or t_gps == t or t_press == t:
            push(t, None, sim.state)
        if t_press == t:
            marked, t_press = (t if settings.brake_timemark_edge else None), math.inf
        if t_slot == t:
            frame_index, wheel = divmod(n_slot, wheel_count)
            count = pulse_count(sim.angles_rad()[wheel], settings.start_count, pulses_per_rev)
            arrival_s = t + jitter.next_s()
            if stall is None:
                push(arrival_s, encoder.frame(wheel, host_t0_s + arrival_s, count, frame_index % SEQ_MODULUS))
            else:
                push_can(arrival_s, wpt_maker(wheel, count, frame_index % SEQ_MODULUS))
            n_slot += 1
            t_slot = _instant(n_slot, slot_rate_hz)
        if t_gps == t:
            speed_mps = max(0.0, sim.state.speed_mps + float(noise_rng.normal(0.0, settings.gps_noise_mps)))
            arrival_s = t + settings.gps_latency_s
            if settings.gps_protocol in ("ubx", "both"):
                push(arrival_s, UbxFrame(host_t0_s + arrival_s, nav_pvt_frame(sim.state, speed_mps, settings)))
            if settings.gps_protocol in ("nmea", "both"):
                for line in gps_epoch_lines(sim.state, speed_mps, settings):
                    push(arrival_s, NmeaLine(host_t0_s + arrival_s, line))
            if marked is not None and settings.brake_timemark_edge is not None:
                push(arrival_s, UbxFrame(host_t0_s + arrival_s, tim_tm2_frame(
                    settings.start_utc_s + marked, settings.brake_timemark_edge, 1)))
                marked = None
            n_gps += 1
            t_gps = _instant(n_gps, settings.gps_rate_hz)
        if sensors is not None:
            if t_imu == t:
                accel_mps2 = sim.state.accel_mps2 + float(imu_rng.normal(0.0, settings.imu_noise_mps2))
                arrival_s = t + sensor_jitter.next_s()
                if mti is not None:
                    push(arrival_s, XbusBytes(host_t0_s + arrival_s, mti.message(t, accel_mps2, sim.state.accel_mps2)))
                else:
                    reading = body.forward_reading(sim.state.accel_mps2, accel_mps2) if body.active else accel_mps2
                    push_can(arrival_s, partial(sensors.imu_frame, accel_mps2=reading))
                n_imu += 1
                t_imu = _instant(n_imu, imu_rate_hz)
            if t_brake == t:
                pressed = sim.state.brake_pressed
                push_can(t + sensor_jitter.next_s(), partial(sensors.brake_frame, pressed=pressed))
                n_brake += 1
                t_brake = _instant(n_brake, brake_rate_hz)
            if t_ref == t:  # measured now, sent ref_speed_latency_s later
                speed_mps = max(0.0, sim.state.speed_mps + float(ref_rng.normal(0.0, settings.ref_speed_noise_mps)))
                arrival_s = t + settings.ref_speed_latency_s + sensor_jitter.next_s()
                push_can(arrival_s, partial(sensors.reference_frame, speed_mps=speed_mps,
                                            accuracy_mps=settings.ref_speed_noise_mps))
                n_ref += 1
                t_ref = _instant(n_ref, ref_rate_hz)
        if t_truth == t:
            n_truth += 1
            t_truth = _instant(n_truth, TRUTH_RATE_HZ)
