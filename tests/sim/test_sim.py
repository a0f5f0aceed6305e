"""Simulator tests: tire curve, speed profiles, force/slip split, generated records, real-time playback."""

from __future__ import annotations

import asyncio
import fcntl
import math
import os
import tty
from datetime import UTC, datetime
from functools import cache
from pathlib import Path

import can
import cantools
import pynmea2
import pytest

from slipdaq import WHEELS
from slipdaq.config import Config, load_config
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim.emit import KNOT_MPS, SimEvent, SimSettings, generate
from slipdaq.sim.realtime import play
from slipdaq.sim.vehicle import (
    ACCEL_MPS2,
    CRUISE_SPEED_MPS,
    CYCLE_SPEED_MPS,
    DECEL_MPS2,
    ROADS,
    TireModel,
    TruthSample,
    VehicleSim,
    static_loads_n,
)

CONFIG_PATH = Path(__file__).parents[2] / "config" / "slipdaq.toml"
DBC_PATH = Path(__file__).parents[2] / "config" / "wpt.dbc"
START_UTC_S = SimSettings().start_utc_s


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config(CONFIG_PATH)


def with_vehicle(cfg: Config, **changes: object) -> Config:
    return cfg.model_copy(update={"vehicle": cfg.vehicle.model_copy(update=changes)})


@cache
def run(scenario: str, road: str, duration_s: float, dt_s: float = 0.01) -> list[TruthSample]:
    sim = VehicleSim(load_config(CONFIG_PATH), scenario, road)  # type: ignore[arg-type]
    return [sim.state] + [sim.step(dt_s) for _ in range(round(duration_s / dt_s))]


@cache
def events(scenario: str, duration_s: float, **settings: float) -> list[SimEvent]:
    cfg = load_config(CONFIG_PATH)
    return list(generate(cfg, scenario, "paved", SimSettings(**settings), duration_s))  # type: ignore[arg-type]


# --- tire model -------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("road", sorted(ROADS))
@pytest.mark.parametrize("fz_n", [2500.0, 3826.0])
def test_slip_for_force_inverts_the_curve(road: str, fz_n: float) -> None:
    tire = ROADS[road]
    for slip in (-0.99 * tire.peak_slip, -0.05, -0.001, 1e-5, 0.02, 0.08, 0.99 * tire.peak_slip):
        assert tire.slip_for_force(tire.force_n(slip, fz_n), fz_n) == pytest.approx(slip, abs=1e-9)


@pytest.mark.parametrize("tire", list(ROADS.values()))
def test_slip_for_force_zero_symmetric_and_clamped(tire: TireModel) -> None:
    assert tire.slip_for_force(0.0, 3000.0) == 0.0
    for fx_n in (10.0, 900.0, 1700.0):
        assert tire.slip_for_force(-fx_n, 3000.0) == -tire.slip_for_force(fx_n, 3000.0)
    peak_force_n = tire.mu * 3000.0
    assert tire.slip_for_force(2 * peak_force_n, 3000.0) == pytest.approx(tire.peak_slip)
    assert tire.force_n(tire.peak_slip, 3000.0) == pytest.approx(peak_force_n)


@pytest.mark.parametrize("tire", list(ROADS.values()))
def test_stiffness_is_the_initial_slope(tire: TireModel) -> None:
    fz_n, ds = 3500.0, 1e-7
    assert tire.stiffness_n(fz_n) == pytest.approx(tire.cx_per_fz * fz_n)
    assert tire.force_n(ds, fz_n) / ds == pytest.approx(tire.stiffness_n(fz_n), rel=1e-6)


# --- profiles ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_accelerate_reaches_cruise_speed_and_stays(road: str) -> None:
    samples = run("accelerate", road, 20.0)
    assert samples[0].speed_mps == 0.0
    reached = next(i for i, s in enumerate(samples) if s.speed_mps >= CRUISE_SPEED_MPS - 0.1)
    assert samples[reached].time_s < 2.0 + CRUISE_SPEED_MPS / ACCEL_MPS2[road] + 1.0
    assert all(abs(s.speed_mps - CRUISE_SPEED_MPS) < 0.1 for s in samples[reached:])
    assert samples[-1].accel_mps2 == 0.0


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_brake_ends_at_standstill_never_negative(road: str) -> None:
    samples = run("brake", road, 15.0)
    assert samples[0].speed_mps == CRUISE_SPEED_MPS
    assert min(s.speed_mps for s in samples) >= 0.0
    assert samples[-1].speed_mps == pytest.approx(0.0, abs=0.1)
    stopped = next(i for i, s in enumerate(samples) if s.speed_mps <= 0.1)
    assert all(s.speed_mps <= 0.1 and s.accel_mps2 <= 0.0 for s in samples[stopped:])
    distances = [s.distance_m for s in samples]
    assert distances == sorted(distances)


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_peak_acceleration_equals_the_road_levels(road: str) -> None:
    accel = max(s.accel_mps2 for s in run("accelerate", road, 20.0))
    decel = -min(s.accel_mps2 for s in run("brake", road, 15.0))
    assert accel == pytest.approx(ACCEL_MPS2[road], rel=0.01)
    assert decel == pytest.approx(DECEL_MPS2[road], rel=0.01)
    cycle = run("cycle", road, 30.0)
    assert max(s.accel_mps2 for s in cycle) == pytest.approx(ACCEL_MPS2[road], rel=0.01)
    assert -min(s.accel_mps2 for s in cycle) == pytest.approx(DECEL_MPS2[road], rel=0.01)


def test_acceleration_is_jerk_limited() -> None:
    samples = run("accelerate", "paved", 4.0, dt_s=0.001)
    jerk = [(b.accel_mps2 - a.accel_mps2) / 0.001 for a, b in zip(samples, samples[1:])]
    assert max(jerk) == pytest.approx(ACCEL_MPS2["paved"] / 0.5, rel=0.01)
    start = next(s for s in samples if s.accel_mps2 >= ACCEL_MPS2["paved"] - 1e-9)
    assert start.time_s == pytest.approx(2.5, abs=0.002)


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_cycle_repeats(cfg: Config, road: str) -> None:
    sim = VehicleSim(cfg, "cycle", road)
    period_s = sim.profile.period_s
    assert period_s is not None
    for t in (0.0, 1.0, 2.3, 4.0, 7.7, period_s - 0.3):
        x0, v0, a0 = sim.profile.at(t)
        x1, v1, a1 = sim.profile.at(t + 2 * period_s)
        assert (v1, a1) == pytest.approx((v0, a0), abs=1e-9)
        assert x1 - x0 == pytest.approx(2 * sim.profile.period_distance_m, abs=1e-6)
    samples = run("cycle", road, 3 * period_s)
    for lap in range(3):
        in_lap = [s for s in samples if lap * period_s <= s.time_s < (lap + 1) * period_s]
        assert max(s.speed_mps for s in in_lap) == pytest.approx(CYCLE_SPEED_MPS, abs=0.1)
        assert in_lap[0].speed_mps == pytest.approx(0.0, abs=0.1)
        assert min(s.speed_mps for s in in_lap) >= 0.0


# --- forces and slips -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("axle", "driven"), [("front", "FL FR"), ("rear", "RL RR"), ("all", "FL FR RL RR")])
def test_drive_force_and_slip_on_driven_wheels(cfg: Config, axle: str, driven: str) -> None:
    sim = VehicleSim(with_vehicle(cfg, driven_axle=axle), "accelerate", "paved")
    state = sim.step(5.0)  # steady acceleration
    assert state.accel_mps2 == pytest.approx(ACCEL_MPS2["paved"])
    assert state.force_n == pytest.approx(cfg.vehicle.mass_kg * state.accel_mps2)
    for w, wheel in state.wheels.items():
        if w in driven.split():
            assert wheel.slip > 0
            assert wheel.force_n == pytest.approx(state.force_n / len(driven.split()))
        else:
            assert wheel.slip == 0.0 and wheel.force_n == 0.0
    assert sum(wh.force_n for wh in state.wheels.values()) == pytest.approx(state.force_n)


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_brake_force_split_and_negative_slip(cfg: Config, road: str) -> None:
    share = cfg.vehicle.brake_front_share
    state = VehicleSim(cfg, "brake", road).step(5.0)  # steady braking
    assert state.accel_mps2 == pytest.approx(-DECEL_MPS2[road])
    assert all(wheel.slip < 0 for wheel in state.wheels.values())
    front_n = state.wheels["FL"].force_n + state.wheels["FR"].force_n
    rear_n = state.wheels["RL"].force_n + state.wheels["RR"].force_n
    assert front_n / rear_n == pytest.approx(share / (1 - share))
    assert front_n + rear_n == pytest.approx(state.force_n)


def test_wheel_truth_follows_the_slip_definition(cfg: Config) -> None:
    offsets = {"FL": 0.002, "FR": -0.001, "RL": 0.0, "RR": 0.003}
    sim = VehicleSim(cfg, "brake", "sand", r0_offset_m=offsets)
    loads = static_loads_n(cfg.vehicle.mass_kg)
    assert loads["FL"] + loads["FR"] == pytest.approx(0.6 * cfg.vehicle.mass_kg * 9.81)
    before = sim.step(4.5)
    after = sim.step(0.001)
    for w in WHEELS:
        wheel = after.wheels[w]
        assert wheel.r0_m == pytest.approx(cfg.tire.radius_m + offsets[w])
        assert wheel.omega_radps == pytest.approx(after.speed_mps * (1 + wheel.slip) / wheel.r0_m)
        assert (wheel.omega_radps * wheel.r0_m - after.speed_mps) / after.speed_mps == pytest.approx(wheel.slip)
        assert wheel.cx_n == pytest.approx(ROADS["sand"].cx_per_fz * loads[w])
        mean_omega = (wheel.omega_radps + before.wheels[w].omega_radps) / 2
        assert (wheel.angle_rad - before.wheels[w].angle_rad) / 0.001 == pytest.approx(mean_omega, rel=1e-6)
    stopped = sim.step(20.0)
    assert all(wheel.omega_radps == 0.0 for wheel in stopped.wheels.values())


# --- generate() -------------------------------------------------------------------------------------------------


def decoded_frames(evs: list[SimEvent]) -> dict[str, list[tuple[float, int, int]]]:
    """(time_s, PulseCount, Seq) per wheel, decoded with cantools from the DBC."""
    db = cantools.database.load_file(DBC_PATH)
    names = {db.get_message_by_name(f"WPT_{w}").frame_id: w for w in WHEELS}
    out: dict[str, list[tuple[float, int, int]]] = {w: [] for w in WHEELS}
    for ev in evs:
        if isinstance(ev.record, CanFrame):
            signals = db.decode_message(ev.record.arbitration_id, ev.record.data)
            out[names[ev.record.arbitration_id]].append((ev.time_s, signals["PulseCount"], signals["Seq"]))
    return out


def unwrap(counts: list[int]) -> list[int]:
    """Cumulative pulses since the first count, across 2^32 wraps."""
    total, out = 0, [0]
    for a, b in zip(counts, counts[1:]):
        total += (b - a) % 2**32
        out.append(total)
    return out


def truths(evs: list[SimEvent]) -> dict[float, TruthSample]:
    return {ev.time_s: ev.truth for ev in evs if ev.truth is not None}


def test_events_are_ordered_and_stamped() -> None:
    for evs in (events("accelerate", 10.0), events("cycle", 5.0, can_jitter_s=0.004, gps_latency_s=0.085)):
        times = [ev.time_s for ev in evs]
        assert times == sorted(times)
        assert 0.0 <= times[0] and times[-1] < 10.0
        for ev in evs:
            assert (ev.record is None) != (ev.truth is None)
            if ev.record is not None:
                assert ev.record.timestamp_s == START_UTC_S + ev.time_s
            else:
                assert ev.truth is not None and ev.truth.time_s == ev.time_s


def test_frames_per_wheel_and_seq() -> None:
    frames = decoded_frames(events("accelerate", 10.0))
    for w, rows in frames.items():
        assert abs(len(rows) - 100.0 * 10) <= 1, w
        seqs = [seq for _, _, seq in rows]
        assert seqs[0] == 0
        assert all(b == (a + 1) % 256 for a, b in zip(seqs, seqs[1:]))
        period = [b[0] - a[0] for a, b in zip(rows, rows[1:])]
        assert min(period) == pytest.approx(0.01) and max(period) == pytest.approx(0.01)
    offsets = [frames[w][0][0] for w in WHEELS]
    assert offsets == pytest.approx([0.0, 0.0025, 0.005, 0.0075])


def test_counts_wrap_early() -> None:
    for w, rows in decoded_frames(events("accelerate", 10.0)).items():
        counts = [c for _, c, _ in rows]
        assert counts[0] == SimSettings().start_count
        wraps = [t for (t, a, _), (_, b, _) in zip(rows, rows[1:]) if b < a]
        assert len(wraps) == 1 and wraps[0] < 9.0, w


def test_counts_match_the_truth_angle_to_the_pulse(cfg: Config) -> None:
    """With 25 frames/s per wheel every frame falls on a 10 ms truth instant: the count is exact there."""
    ppr, start = cfg.wpt.pulses_per_rev, SimSettings().start_count
    offsets = {"FL": 0.002, "FR": -0.001, "RL": 0.0005, "RR": 0.0}
    for scenario in ("accelerate", "brake"):
        evs = list(generate(cfg, scenario, "paved", SimSettings(wpt_rate_hz=25.0), 12.0, r0_offset_m=offsets))
        truth = truths(evs)
        for w, rows in decoded_frames(evs).items():
            for t, count, _ in rows:
                expected = math.floor(truth[t].wheels[w].angle_rad / (2 * math.pi) * ppr)
                assert count == (start + expected) % 2**32, (scenario, w, t)
            last = truth[rows[-1][0]].wheels[w]
            pulse_m = 2 * math.pi * last.r0_m / ppr
            counted_m = unwrap([start] + [c for _, c, _ in rows])[-1] / ppr * 2 * math.pi * last.r0_m
            assert abs(counted_m - last.angle_rad * last.r0_m) <= pulse_m
            assert last.angle_rad * last.r0_m > 50.0


def test_default_rate_counts_exact_where_frames_meet_truth(cfg: Config) -> None:
    evs = events("accelerate", 10.0)
    truth, ppr = truths(evs), cfg.wpt.pulses_per_rev
    rows = decoded_frames(evs)["FL"]
    for t, count, _ in rows:
        pulses = math.floor(truth[t].wheels["FL"].angle_rad / (2 * math.pi) * ppr)
        assert count == (SimSettings().start_count + pulses) % 2**32
    totals = unwrap([c for _, c, _ in rows])
    last = truth[rows[-1][0]].wheels["FL"]
    assert abs(totals[-1] / ppr * 2 * math.pi * last.r0_m - last.angle_rad * last.r0_m) <= 2 * math.pi * last.r0_m / ppr


def test_truth_every_10_ms_and_at_gps_epochs() -> None:
    evs = events("cycle", 5.0, gps_rate_hz=8.0)
    times = sorted(truths(evs))
    expected = sorted({k / 100 for k in range(500)} | {k / 8 for k in range(40)})
    assert times == pytest.approx(expected)
    assert len(times) == len(expected)


def test_nmea_lines_parse_and_carry_the_truth_speed() -> None:
    evs = events("accelerate", 10.0, gps_noise_mps=0.0)
    truth = truths(evs)
    lines = [ev for ev in evs if isinstance(ev.record, NmeaLine)]
    assert len(lines) == 3 * 100
    for i in range(0, len(lines), 3):
        group = [ev.record for ev in lines[i : i + 3]]
        msgs = [pynmea2.parse(r.line, check=True) for r in group]
        assert [m.sentence_type for m in msgs] == ["RMC", "GGA", "VTG"]
        assert all(m.talker == "GP" for m in msgs)
        assert len({r.timestamp_s for r in group}) == 1
        rmc, gga, vtg = msgs
        epoch_s = lines[i].time_s
        speed_mps = truth[epoch_s].speed_mps
        assert float(rmc.spd_over_grnd) * KNOT_MPS == pytest.approx(speed_mps, abs=0.001)
        assert float(vtg.spd_over_grnd_kts) * KNOT_MPS == pytest.approx(speed_mps, abs=0.001)
        assert float(vtg.spd_over_grnd_kmph) / 3.6 == pytest.approx(speed_mps, abs=0.001)
        assert rmc.status == "A" and float(rmc.true_course) == 90.0
        assert gga.gps_qual == 1 and int(gga.num_sats) == 12 and gga.altitude == 100.0
        assert rmc.latitude == pytest.approx(52.0, abs=1e-6)
        east_m = (rmc.longitude - 10.0) * math.radians(1) * 6_371_008.8 * math.cos(math.radians(52.0))
        assert east_m == pytest.approx(truth[epoch_s].distance_m, abs=0.02)
        fix_utc_s = datetime.combine(rmc.datestamp, rmc.timestamp, tzinfo=UTC).timestamp()
        assert fix_utc_s == pytest.approx(START_UTC_S + epoch_s, abs=1e-6)


def test_gps_latency_delays_the_sentences() -> None:
    evs = events("cycle", 5.0, gps_latency_s=0.085)
    rmcs = [ev.record for ev in evs if isinstance(ev.record, NmeaLine) and "RMC" in ev.record.line]
    assert len(rmcs) == 50
    for record in rmcs:
        rmc = pynmea2.parse(record.line, check=True)
        fix_utc_s = datetime.combine(rmc.datestamp, rmc.timestamp, tzinfo=UTC).timestamp()
        assert record.timestamp_s - fix_utc_s == pytest.approx(0.085, abs=1e-5)


def test_gps_noise_is_seeded_and_sized() -> None:
    evs = events("accelerate", 30.0)
    truth = truths(evs)
    errors = [
        float(pynmea2.parse(ev.record.line).spd_over_grnd) * KNOT_MPS - truth[ev.time_s].speed_mps
        for ev in evs
        if isinstance(ev.record, NmeaLine) and "RMC" in ev.record.line and ev.time_s > 15.0
    ]
    sd = math.sqrt(sum(e * e for e in errors) / len(errors))
    assert 0.015 < sd < 0.025
    again = list(generate(load_config(CONFIG_PATH), "accelerate", "paved", SimSettings(), 30.0))
    assert [ev.record for ev in again] == [ev.record for ev in evs]
    other_seed = list(generate(load_config(CONFIG_PATH), "accelerate", "paved", SimSettings(seed=2), 30.0))
    assert [ev.record for ev in other_seed] != [ev.record for ev in evs]


def test_can_jitter_delays_frames_but_keeps_counts() -> None:
    plain, jittered = events("cycle", 5.0), events("cycle", 5.0, can_jitter_s=0.004)
    frames_plain = decoded_frames(plain)
    frames_jittered = decoded_frames(jittered)
    for w in WHEELS:
        assert 0 <= len(frames_plain[w]) - len(frames_jittered[w]) <= 1  # a late last frame falls past the end
        kept = len(frames_jittered[w])
        assert [(c, s) for _, c, s in frames_jittered[w]] == [(c, s) for _, c, s in frames_plain[w][:kept]]
        delays = [tj - tp for (tj, _, _), (tp, _, _) in zip(frames_jittered[w], frames_plain[w])]
        assert 0.0 <= min(delays) and max(delays) < 0.004 and max(delays) > 0.003


# --- realtime.play() --------------------------------------------------------------------------------------------


def _drain(fd: int, into: bytearray) -> None:
    while True:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            return
        if not chunk:
            return
        into.extend(chunk)


def test_play_on_virtual_bus_and_pty(cfg: Config) -> None:
    master_fd, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    os.set_blocking(master_fd, False)
    os.set_blocking(slave_fd, False)
    received = bytearray()
    truth_times: list[float] = []
    channel = f"simtest-{os.getpid()}"
    try:
        with (
            can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as tx,
            can.Bus(interface="virtual", channel=channel, receive_own_messages=False) as rx,
        ):

            async def main() -> int:
                loop = asyncio.get_running_loop()
                loop.add_reader(slave_fd, _drain, slave_fd, received)
                try:
                    return await play(
                        generate(cfg, "cycle", "paved"),
                        bus=tx,
                        nmea_write=lambda data: os.write(master_fd, data),
                        duration_s=1.0,
                        on_truth=lambda truth: truth_times.append(truth.time_s),
                    )
                finally:
                    loop.remove_reader(slave_fd)

            sent = asyncio.run(main())
            got = []
            while (msg := rx.recv(timeout=0)) is not None:
                got.append((msg.arbitration_id, bytes(msg.data), msg.is_extended_id))
        _drain(slave_fd, received)
    finally:
        os.close(master_fd)
        os.close(slave_fd)
    expected = list(generate(cfg, "cycle", "paved", duration_s=1.0))
    frames = [(e.record.arbitration_id, e.record.data, False) for e in expected if isinstance(e.record, CanFrame)]
    lines = [e.record.line for e in expected if isinstance(e.record, NmeaLine)]
    assert sent == len(got) == len(frames) == 400
    assert got == frames
    text = received.decode("ascii")
    assert text.endswith("\r\n")
    assert text.split("\r\n")[:-1] == lines
    assert all(pynmea2.parse(line, check=True) for line in lines)
    assert truth_times == sorted(truths(expected))


def test_play_retries_writes_that_would_block(cfg: Config) -> None:
    """A pipe shrunk to one page fills before the reader starts: EAGAIN is retried and no byte is lost."""
    read_fd, write_fd = os.pipe()
    fcntl.fcntl(write_fd, fcntl.F_SETPIPE_SZ, 4096)
    os.set_blocking(write_fd, False)
    os.set_blocking(read_fd, False)
    received = bytearray()
    would_block = 0

    def write(data: bytes) -> int:
        nonlocal would_block
        try:
            return os.write(write_fd, data)
        except BlockingIOError:
            would_block += 1
            raise

    settings = SimSettings(wpt_rate_hz=0.0, gps_rate_hz=100.0)
    try:
        with can.Bus(interface="virtual", channel=f"simtest-pipe-{os.getpid()}") as bus:

            async def main() -> int:
                loop = asyncio.get_running_loop()
                loop.call_later(0.3, loop.add_reader, read_fd, _drain, read_fd, received)
                try:
                    return await play(
                        generate(cfg, "cycle", "paved", settings), bus=bus, nmea_write=write, duration_s=0.6
                    )
                finally:
                    loop.remove_reader(read_fd)

            assert asyncio.run(main()) == 0
        _drain(read_fd, received)
    finally:
        os.close(read_fd)
        os.close(write_fd)
    lines = [e.record.line for e in generate(cfg, "cycle", "paved", settings, 0.6) if isinstance(e.record, NmeaLine)]
    assert would_block > 0
    assert received.decode("ascii").split("\r\n")[:-1] == lines


class _LinkDownBus(can.BusABC):
    """A virtual bus whose link is down for frames 10-19: send raises ENETDOWN there, as SocketCAN does."""

    def __init__(self, channel: str) -> None:
        self.inner = can.Bus(interface="virtual", channel=channel)
        self.calls = 0
        super().__init__(channel)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.calls += 1
        if 10 <= self.calls < 20:
            raise can.CanOperationError("Failed to transmit: Network is down", error_code=100)
        self.inner.send(msg)

    def _recv_internal(self, timeout):  # type: ignore[no-untyped-def]
        return None, False

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


def test_play_goes_on_when_the_link_is_down() -> None:
    """Frames the bus refuses (link down) go to on_refused at once, without the 0.5 s retry, and the rest are sent."""
    channel = f"slipdaq-linkdown-{os.getpid()}"
    events = [SimEvent(0.0, CanFrame(0.0, 0x310, bytes(8)), None) for _ in range(30)]
    refused: list[can.CanError] = []
    with _LinkDownBus(channel) as bus, can.Bus(interface="virtual", channel=channel) as rx:
        sent = asyncio.run(play(iter(events), bus=bus, nmea_write=lambda b: len(b), on_refused=refused.append))
        got = 0
        while rx.recv(timeout=0.1) is not None:
            got += 1
    assert sent == got == 20 and len(refused) == 10
    assert all(getattr(e, "error_code", None) == 100 for e in refused)
    with _LinkDownBus(channel + "-b") as bus, pytest.raises(can.CanOperationError):
        asyncio.run(play(iter(events), bus=bus, nmea_write=lambda b: len(b)))  # without on_refused: raised
