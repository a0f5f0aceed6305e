"""`slipdaq demo`: simulator and daemon in one process, on python-can's virtual bus and a pseudo-terminal."""

from __future__ import annotations

import asyncio
import os
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import TextIO, get_args

import can

from slipdaq.config import Config, ProcedureConfig, load_config, packaged_config_path
from slipdaq.config.calibration import Calibration, default_path, for_run
from slipdaq.live.daemon import RunResult, new_log_path, open_bus, run_daemon
from slipdaq.live.simulate import BRAKE_RATE_HZ, IMU_RATE_HZ, PtyGps
from slipdaq.logformat.reader import iter_estimates
from slipdaq.report.labels import labels_metadata
from slipdaq.sim import SlipScenario
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.realtime import play
from slipdaq.sim.truth import SlipError, slip_error, truth_series
from slipdaq.sim.vehicle import TruthSample
from slipdaq.sinks.maneuver_text import maneuver_line, test_set_line

SENSOR_SCENARIOS: tuple[str, ...] = get_args(SlipScenario)
"""Scenarios whose demo adds the IMU and the brake switch on CAN (sensors.dbc)."""
SENSORS_DBC = "sensors.dbc"
ABS_WPT_RATE_HZ = 500.0
"""WPT frames per second per wheel in the brake-abs demo: several samples per ABS cycle."""


DEMO_PROCEDURES = [
    *(ProcedureConfig(name=f"brake {v}-0", kind="brake", target_speed_kmh=v, runs=3) for v in (33, 60, 80, 90)),
    *(ProcedureConfig(name=f"accelerate 0-{v}", kind="accelerate", target_speed_kmh=v, runs=3) for v in (33, 60)),
]
"""The demo's test sets (when the packaged config has none): the scenarios' stops and accelerations."""


def demo_config(gps_port: str, channel: str, scenario: str = "cycle", imu_port: str | None = None) -> Config:
    """The packaged example config, on a virtual bus and the given GPS port; for the sensor scenarios also the DBC
    of the sensors (sensors.dbc) and its IMU (IMU_ACCEL.AccelX) and brake switch (BRAKE.BrakePressed). imu_port: the
    IMU is an Xsens MTi on that serial port instead ([imu] source = "serial", x forward), in every scenario."""
    cfg = load_config(packaged_config_path())
    cfg = cfg.with_overrides(can={"interface": "virtual", "channel": channel}, gps={"port": gps_port})
    if not cfg.test.procedure:
        cfg = cfg.with_overrides(test={"procedure": DEMO_PROCEDURES})
    if imu_port is not None:
        cfg = cfg.with_overrides(imu={"source": "serial", "port": imu_port, "axis": "x", "sign": 1})
    if scenario not in SENSOR_SCENARIOS:
        return cfg
    wheels_dbc = [cfg.can.dbc] if isinstance(cfg.can.dbc, str) else list(cfg.can.dbc)
    return cfg.with_overrides(
        can={"dbc": [*wheels_dbc, SENSORS_DBC]},
        imu={"message": "IMU_ACCEL", "signal": "AccelX"} if imu_port is None else {},
        brake={"message": "BRAKE", "signal": "BrakePressed"},
    )


def demo_settings(scenario: str, imu: str = "can") -> SimSettings:
    """The simulator's settings for the demo: the defaults; the sensor scenarios add the IMU (IMU_RATE_HZ) and the
    brake switch (BRAKE_RATE_HZ), brake-abs and brake-abs-all also WPT at ABS_WPT_RATE_HZ; imu "serial": the IMU
    (an MTi) in every scenario."""
    imu_rate_hz = IMU_RATE_HZ if imu == "serial" else 0.0
    if scenario not in SENSOR_SCENARIOS:
        return SimSettings(imu_rate_hz=imu_rate_hz)
    wpt_rate_hz = ABS_WPT_RATE_HZ if scenario in ("brake-abs", "brake-abs-all") else SimSettings().wpt_rate_hz
    return SimSettings(imu_rate_hz=IMU_RATE_HZ, brake_rate_hz=BRAKE_RATE_HZ, wpt_rate_hz=wpt_rate_hz)


async def run_demo_async(
    duration_s: float, scenario: str, road: str, log_dir: Path, *, status_stream: TextIO | None = None,
    status_every_s: float = 5.0, settings: SimSettings | None = None, labels: dict[str, str] | None = None,
    calibration: Calibration | None = None, foxglove: str | None = None, imu: str = "can",
    truth: list[TruthSample] | None = None,
) -> tuple[RunResult, SlipError, Config]:
    """labels: free-form {KEY: VALUE} stored in the log's metadata as `label.KEY` (`--label KEY=VALUE`);
    calibration: the stored calibration the daemon starts from; foxglove: `[HOST:]PORT` of a Foxglove live server
    (live.foxglove); imu: "serial" sends the IMU as an MTi's messages on a second pseudo-terminal (demo_config);
    truth: a list the simulator's truth samples are appended to."""
    gps = PtyGps()
    mti = PtyGps() if imu == "serial" else None
    channel = f"slipdaq-demo-{os.getpid()}-{id(gps)}"
    cfg = demo_config(gps.path, channel, scenario, mti.path if mti is not None else None)
    if foxglove is not None:
        cfg = cfg.with_overrides(live={"foxglove": foxglove})
    truth = [] if truth is None else truth
    started: list[SimSettings] = []
    log_path = new_log_path(log_dir, "demo")

    async def simulate(bus: can.BusABC) -> None:
        """Start the drive once the daemon is reading: sim time 0 is then a wall time both sides share."""
        while not log_path.exists():
            await asyncio.sleep(0.02)
        await asyncio.sleep(0.2)
        run = replace(settings or demo_settings(scenario, imu), start_utc_s=time.time() + 0.1)
        started.append(run)
        events = generate(cfg, scenario, road, run, duration_s=duration_s)  # type: ignore[arg-type]  # the scenario and road names are the Literal's values
        await play(events, bus=bus, nmea_write=gps.write, on_truth=truth.append, start_wall_s=run.start_utc_s,
                   stamp_frames=True, imu_write=mti.write if mti is not None else None)

    try:
        # The simulator stamps each frame with its nominal time, as a CAN adapter's hardware timestamp would; the
        # virtual bus would otherwise stamp it when sent, however late the shared event loop gets to it.
        with open_bus(cfg) as daemon_bus, \
                can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as sim_bus:
            async with asyncio.TaskGroup() as tg:
                sim = tg.create_task(simulate(sim_bus))
                result = await run_daemon(
                    cfg, daemon_bus, log_path, duration_s=duration_s,
                    status_stream=status_stream, status_every_s=status_every_s,
                    metadata={"demo_scenario": scenario, "demo_road": road} | labels_metadata(labels or {}),
                    calibration=calibration,
                )
                sim.cancel()
    finally:
        gps.close()
        if mti is not None:
            mti.close()
    error = slip_error(iter_estimates(result.log_path), truth_series(truth, started[0].start_utc_s)) if truth else \
        SlipError(0, *[float("nan")] * 4)
    return result, error, cfg


def run_demo(duration_s: float, scenario: str, road: str, log_dir: Path, out: TextIO = sys.stdout,
             labels: dict[str, str] | None = None, calibration_path: Path | None = None,
             no_calibration: bool = False, foxglove: str | None = None, imu: str = "can") -> int:
    """calibration_path: the calibration file (default calibration.toml in log_dir); no_calibration: start cold and
    save nothing; foxglove: `[HOST:]PORT` of a Foxglove live server; imu: "serial" for an MTi on a pseudo-terminal."""
    mti = " and an Xsens MTi on a second one" if imu == "serial" else ""
    print(f"demo: {scenario} on {road} road for {duration_s:.0f} s — simulator and daemon on a virtual CAN bus "
          f"and a pseudo-terminal GPS{mti}; Ctrl-C stops early.", file=out, flush=True)
    cfg = load_config(packaged_config_path())
    cal = for_run(None if no_calibration else calibration_path or default_path(log_dir, cfg), cfg)
    if cal.note:
        print(cal.note, file=out, flush=True)
    result, err, _ = asyncio.run(run_demo_async(duration_s, scenario, road, log_dir, status_stream=out,
                                                labels=labels, calibration=cal.start, foxglove=foxglove,
                                                imu=imu))
    saved = cal.finish(result.learned, cfg, str(result.log_path))
    rate = result.can_frames / result.duration_s if result.duration_s > 0 else 0.0
    print(
        f"\ndemo finished after {result.duration_s:.1f} s\n"
        f"  log:        {result.log_path} ({result.log_path.stat().st_size / 1e6:.2f} MB)\n"
        f"  CAN:        {result.can_frames} frames ({rate:.0f} frames/s), {result.lost_frames} lost\n"
        f"  NMEA:       {result.nmea_lines} lines, {result.bad_sentences} bad\n"
        f"  estimates:  {result.estimates}\n"
        f"  maneuvers:  {result.maneuver_count}"
        + (f" (the last {len(result.maneuvers)})" if result.maneuver_count > len(result.maneuvers) else "")
        + "".join(f"\n    {maneuver_line(m)}" for m in result.maneuvers)
        + "".join(f"\n  test set:   {test_set_line(r)}" for r in result.test_sets) + "\n"
        f"  slip error against the simulator's truth (speed > 5 m/s, {err.samples} wheel windows): "
        f"RMS {err.rms_points:.3f} points, median {err.median_abs_points:.3f}, max {err.max_abs_points:.3f}\n"
        + (f"  {saved}\n" if saved else "") +
        f"next:\n"
        f"  slipdaq replay {result.log_path} -o replayed.mcap\n"
        f"  slipdaq export {result.log_path} --csv estimates.csv --fast-csv fast.csv --maneuvers-csv maneuvers.csv\n"
        f"  slipdaq report {result.log_path} -o report",
        file=out, flush=True,
    )
    return 0
