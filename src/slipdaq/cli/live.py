"""The live verbs: run (the daemon), simulate (the vehicle and tire model in real time), demo (both)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from slipdaq.cli.common import (
    EXIT_FAIL,
    EXIT_OK,
    _add_calibration,
    _add_config,
    _add_foxglove,
    _add_label,
    _config,
    _labels_meta,
    _run_calibration,
    _save_calibration,
)
from slipdaq.sim import SCENARIOS


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """This group's verbs on the command line."""
    p = sub.add_parser("run", help="the live daemon: read CAN and GPS, estimate, log to MCAP, show status",
                       description="Read WPT frames from the configured CAN bus and NMEA from the GPS serial port, "
                       "estimate slip, Re, Fx and Cx online, log everything to a new MCAP file in the log dir and "
                       "show a live status view (one status line every few seconds when stdout is not a terminal). "
                       "SIGINT/SIGTERM finish the log cleanly. The log gets a name no file or segment has: a file is "
                       "never written over.")
    _add_config(p)
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: run until signalled)")
    p.add_argument("--log-dir", metavar="D", help="write the MCAP log here (default: log.dir of the config)")
    _add_label(p)
    _add_calibration(p, "the log directory")
    _add_foxglove(p)

    p = sub.add_parser("simulate", help="a vehicle and tire model sending WPT frames and NMEA in real time",
                       description="Send simulated WPT frames on the configured python-can bus and NMEA (RMC, GGA, "
                       "VTG at 10 Hz) to a serial port, in real time. Without --gps-port a pseudo-terminal is made "
                       "and its path printed (and linked at --gps-link).")
    _add_config(p)
    p.add_argument("--scenario", choices=SCENARIOS, default="cycle")
    p.add_argument("--road", choices=("paved", "sand"), default="paved")
    p.add_argument("--gps-port", metavar="P", help="serial device to write NMEA to (default: a new pseudo-terminal)")
    p.add_argument("--gps-link", metavar="L", help="with a pseudo-terminal: make L a symlink to it")
    p.add_argument("--imu-port", metavar="P", help='with [imu] source = "serial": serial device to write the MTi\'s '
                   "MTData2 messages to (100 Hz; default: a new pseudo-terminal)")
    p.add_argument("--imu-link", metavar="L", help="with the MTi on a pseudo-terminal: make L a symlink to it")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: run until signalled)")
    p.add_argument("--wpt-rate-hz", type=float, default=100.0, help="WPT frames per second per wheel (default 100)")
    p.add_argument("--gps-rate-hz", type=float, default=10.0, help="GPS epochs per second (default 10)")
    p.add_argument("--gps-latency-s", type=float, default=0.0, help="GPS output latency, fix to sentence (default 0)")
    p.add_argument("--gps-noise-mps", type=float, default=0.02, help="GPS speed noise, standard deviation (default 0.02)")
    p.add_argument("--seed", type=int, default=1)

    p = sub.add_parser("demo", help="simulator and daemon together: no hardware, no root",
                       description="Run the simulator and the daemon in one process on python-can's virtual bus and a "
                       "pseudo-terminal, with the live view, writing an MCAP log under ./logs; at the end, the "
                       "estimated slip is compared with the simulator's truth.")
    p.add_argument("--duration", type=float, default=30.0, metavar="S", help="seconds to run (default 30)")
    p.add_argument("--scenario", choices=SCENARIOS, default="cycle")
    p.add_argument("--road", choices=("paved", "sand"), default="paved")
    p.add_argument("--log-dir", metavar="D", default="logs", help="where the MCAP log goes (default ./logs)")
    p.add_argument("--imu", choices=("can", "serial"), default="can",
                   help="serial: an Xsens MTi's MTData2 messages (100 Hz) on a second pseudo-terminal, [imu] source = "
                   '"serial", in every scenario; can (default): the IMU on CAN in the sensor scenarios')
    _add_label(p)
    _add_calibration(p, "the log directory")
    _add_foxglove(p)


def cmd_run(args: argparse.Namespace) -> int:
    from slipdaq.live.daemon import new_log_path, open_bus, run_daemon

    cfg = _config(args.config)
    if args.foxglove is not None:
        cfg = cfg.with_overrides(live={"foxglove": args.foxglove})
    log_dir = Path(args.log_dir) if args.log_dir else cfg.resolve(cfg.log.dir)
    cal = _run_calibration(args, cfg, log_dir)
    with open_bus(cfg) as bus:
        import asyncio

        result = asyncio.run(run_daemon(cfg, bus, new_log_path(log_dir), duration_s=args.duration,
                                        metadata=_labels_meta(args) or None, calibration=cal.start))
    print(f"log written: {result.log_path} ({result.can_frames} CAN frames, {result.nmea_lines} NMEA lines, "
          f"{result.estimates} estimates, {result.lost_frames} lost frames, {result.bad_sentences} bad sentences)")
    _save_calibration(cal, result.learned, cfg, str(result.log_path))
    segments = getattr(result, "log_segments", None) or []
    if len(segments) > 1:
        print(f"log segments: {' '.join(str(p) for p in segments)}")
    log_error = getattr(result, "log_error", None)
    if log_error:
        print(f"slipdaq: the log is incomplete: {log_error}", file=sys.stderr)
        return EXIT_FAIL
    return EXIT_OK


def cmd_simulate(args: argparse.Namespace) -> int:
    from slipdaq.live.simulate import SimOptions, run_simulate

    cfg = _config(args.config)
    return run_simulate(cfg, SimOptions.from_args(args))


def cmd_demo(args: argparse.Namespace) -> int:
    from slipdaq.live.demo import run_demo
    from slipdaq.report.labels import parse_labels

    return run_demo(duration_s=args.duration, scenario=args.scenario, road=args.road, log_dir=Path(args.log_dir),
                    labels=parse_labels(args.label),
                    calibration_path=Path(args.calibration) if args.calibration else None,
                    no_calibration=args.no_calibration, foxglove=args.foxglove, imu=args.imu)


COMMANDS = {"run": cmd_run, "simulate": cmd_simulate, "demo": cmd_demo}
