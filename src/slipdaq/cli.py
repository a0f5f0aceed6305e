"""slipdaq command line: verbs only (parse arguments, build the parts, run). `slipdaq VERB --help` explains each."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import slipdaq
from slipdaq.calibration import Calibration, Learned, RunCalibration
from slipdaq.config import Config, ConfigError, load_config
from slipdaq.decode.can_signals import SignalDecoder
from slipdaq.decode.can_wheels import DbcError, WheelDecoder
from slipdaq.outputs import OutputError, atomic_output
from slipdaq.sim import SCENARIOS
from slipdaq.sources.read_errors import InputError

EXIT_OK, EXIT_FAIL, EXIT_USAGE = 0, 1, 2


OUTPUT_RULES = (" An output path that is one of the inputs is refused (exit 2). Outputs are written under a temporary "
                "name and renamed into place when complete: a failure leaves no partial output and an existing file "
                "as it was. An input that cannot be read: one line naming the file and where, exit 1.")

BATCH_HELP = """\
Each log is one task on Dask: re-run two-pass from its raw records (as `replay --two-pass`; the logged
estimates for a log without raw records), summarized and plotted (as `report`). Default: a local cluster
of --workers processes on this machine, nothing to start; --scheduler: an existing Dask cluster (start
`dask scheduler` on one host and `dask worker tcp://HOST:8786` on each machine; every worker must read
the logs at the same paths, e.g. a shared file system; this process writes DIR). Needs the fleet extra:
pip install -e ".[fleet]".

Output in DIR:
  estimates/NAME-KEY.parquet  one file per log: its estimates (the CSV's columns), `log` and `label_KEY`
  cache/NAME-KEY.pickle       the log's summary and plots, for re-runs
  report/                     index.html (plots, comparison across logs by labels), summary.csv and
                              summary.json (one row per log, maneuver and wheel), the PNGs
NAME is the log's file stem; KEY hashes the log's size and mtime, its stored config, DBC, calibration
and labels, and slipdaq's version. A re-run skips a log whose files with its current KEY exist (the
report is written again from the cache); a new output of a NAME removes the older one.

Progress: one line per finished log on stderr (with a progress bar on a terminal). A log that fails is
reported with its error and the others go on. Exit status: 0 every log succeeded, 1 one or more failed
(each listed at the end), 2 bad usage."""


def _add_config(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="F", help="TOML config (default: ./slipdaq.toml, else the packaged example)")


def _label(text: str) -> str:
    from slipdaq.report.labels import LabelError, parse_label

    try:
        parse_label(text)
    except LabelError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return text


def _positive(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number of at least 1")
    return n


def _add_label(p: argparse.ArgumentParser) -> None:
    p.add_argument("--label", action="append", type=_label, metavar="KEY=VALUE",
                   help="a free-form label stored in the log's metadata (e.g. road=sand, maneuver=brake); repeatable")


def _add_calibration(p: argparse.ArgumentParser, default: str, replay: bool = False) -> None:
    g = p.add_mutually_exclusive_group()
    start = ("start from the calibration stored in the log (the one the run started from, so that the estimates are "
             "the run's), or from PATH with --calibration; save what it learns to PATH, else to calibration.path of "
             "the config, else calibration.toml in the output's directory") if replay else \
        (f"start from the calibration in PATH and save what the run learns to it (default: calibration.path of the "
         f"config, else calibration.toml in {default})")
    g.add_argument("--calibration", metavar="PATH", help=start + "; a file of another vehicle or tire set "
                   "(vehicle.name, tire.size, tire.set) is neither used nor written over")
    g.add_argument("--no-calibration", action="store_true", help="start cold and save nothing")


def _run_calibration(args: argparse.Namespace, cfg: Config, log_dir: Path, *, replay: bool = False,
                     logged: Calibration | None = None) -> RunCalibration:
    """--calibration / --no-calibration / the default file; prints what it starts from. A replay without either
    flag starts from `logged`, the calibration the logged run started from, and saves to the default file."""
    from slipdaq.calibration import default_path, for_replay, for_run

    if replay and not args.no_calibration and not args.calibration:
        cal = for_replay(logged, default_path(log_dir, cfg), cfg)
    else:
        path = None if args.no_calibration else Path(args.calibration) if args.calibration \
            else default_path(log_dir, cfg)
        cal = for_run(path, cfg)
    if cal.note:
        print(cal.note)
    return cal


def _save_calibration(cal: RunCalibration, learned: Learned, cfg: Config, learned_from: str) -> None:
    saved = cal.finish(learned, cfg, learned_from)
    if saved:
        print(saved)


def _add_allow_empty(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--allow-empty", action="store_true", help=f"accept {what} (default: exit 1, no output)")


def _require(found: int, message: str, args: argparse.Namespace) -> None:
    """An input that gave nothing to work with fails (exit 1, the output is not kept) unless --allow-empty."""
    if not found and not args.allow_empty:
        raise InputError(f"{message} (--allow-empty accepts it)")


def _config_files(cfg: Config) -> list[Path]:
    """The files a config was read from (its TOML and DBC; none for the config stored in a log): inputs too."""
    if cfg.source_path is None or cfg.dbc_text is not None:
        return []
    return [cfg.source_path, *cfg.dbc_paths()]


def _labels_meta(args: argparse.Namespace) -> dict[str, str]:
    from slipdaq.report.labels import labels_metadata, parse_labels

    return labels_metadata(parse_labels(args.label))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slipdaq",
        description="Live wheel-slip acquisition: WPT pulse counts from CAN and NMEA GPS in, windowed slip, "
        "effective rolling radius Re, longitudinal force Fx and tire stiffness Cx out, all logged to MCAP.",
        epilog="Start with `slipdaq demo` (no hardware needed). Exit status: 0 ok, 1 failure, 2 bad config or usage.",
    )
    parser.add_argument("--version", action="version", version=f"slipdaq {slipdaq.__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log warnings and details to stderr")
    sub = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

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

    p = sub.add_parser("simulate", help="a vehicle and tire model sending WPT frames and NMEA in real time",
                       description="Send simulated WPT frames on the configured python-can bus and NMEA (RMC, GGA, "
                       "VTG at 10 Hz) to a serial port, in real time. Without --gps-port a pseudo-terminal is made "
                       "and its path printed (and linked at --gps-link).")
    _add_config(p)
    p.add_argument("--scenario", choices=SCENARIOS, default="cycle")
    p.add_argument("--road", choices=("paved", "sand"), default="paved")
    p.add_argument("--gps-port", metavar="P", help="serial device to write NMEA to (default: a new pseudo-terminal)")
    p.add_argument("--gps-link", metavar="L", help="with a pseudo-terminal: make L a symlink to it")
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
    _add_label(p)
    _add_calibration(p, "the log directory")

    p = sub.add_parser("import", help="CAN log (or MF4 files) + NMEA log -> a slipdaq MCAP log",
                       description="Turn a CAN log python-can reads (candump -L .log, .asc, .blf, .trc, .mf4), or the "
                       "MF4 files of a session (--mf4), and an NMEA log with lines `(EPOCH_SECONDS) $SENTENCE` in the "
                       "same clock (bare sentences accepted) into a slipdaq log, estimates included, like a live one. "
                       "Every frame is kept as it was (ID, IDE, DLC, data, bus channel, direction, FD flags). With "
                       "[gps] source = \"can\" in the config the reference speed comes from the CAN frames and --nmea "
                       "is not needed." + OUTPUT_RULES)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--can", metavar="LOG", help="CAN log file (any format python-can reads, .mf4 included)")
    src.add_argument("--mf4", nargs="+", metavar="FILE",
                     help="ASAM MDF4 bus logs (CANedge, Vector: both CAN bus-logging layouts) read with asammdf; "
                     "the files of one session are joined in time order. Needs `pip install slipdaq[mdf]`")
    p.add_argument("--nmea", metavar="LOG", help="NMEA log file; not needed when the config takes the reference "
                   "speed from CAN ([gps] source = \"can\": a CANmod.gps or a CANedge's GNSS in the same file)")
    _add_config(p)
    p.add_argument("-o", "--output", required=True, metavar="RAW.mcap")
    _add_allow_empty(p, "a CAN log without frames, or an NMEA log without lines or without one fix")
    _add_label(p)
    _add_calibration(p, "the output's directory")

    p = sub.add_parser("replay", help="re-run the estimator over a log's raw CAN and NMEA",
                       description="Re-run decode and estimator over the raw CAN and NMEA channels of a slipdaq log, "
                       "in the order they were recorded, with the config stored in the log (or --config)."
                       + OUTPUT_RULES)
    p.add_argument("log", metavar="RAW.mcap")
    _add_config(p)
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap")
    _add_allow_empty(p, "a log without raw CAN or GPS records")
    _add_calibration(p, "", replay=True)
    p.add_argument("--two-pass", action="store_true",
                   help="post-processing at the limit of the data: a first pass learns the calibration over the whole "
                   "log (GPS latency, r0, Cx), the second recomputes every estimate with it, and with the GPS speed "
                   "smoothed over the whole run (non-causal) in place of the speed as it came, so the first "
                   "acceleration is as good as the last. Without it, replay gives the live run's estimates, bit for bit")

    p = sub.add_parser("export", help="estimates of a log -> CSV, MF4, Parquet",
                       description="--csv: one row per estimate: time_s, speed_mps, accel_mps2, force_n, then for "
                       "each wheel W in FL FR RL RR: slip_W, re_W_m, r0_W_m, cx_W_n (then the extra columns of the "
                       "README). --fast-csv: one row per instant of the high-rate slip (estimator.fast_rate_hz, "
                       "/slip/fast): time_s, speed_mps, slip_FL, slip_FR, slip_RL, slip_RR (slip a fraction; empty "
                       "below the minimum speed). Empty cell = undefined. --mf4: ASAM MDF 4.10 (asammdf): group "
                       "'estimates' with one channel per --csv column (same names, units, a comment each; NaN = "
                       "empty cell, texts through a value-to-text conversion), group 'wheel speeds' (/slip/fast: "
                       "wheel_speed_W_mps, fast_speed_mps, fast_slip_W), group 'GPS' (/gps/fix: gps_speed_mps, "
                       "gps_valid); the log's labels and config in the header comment. --parquet: one row per "
                       "estimate, the --csv columns (null = empty cell), then `log` (the log's name without "
                       ".mcap) and label_KEY per label. Values equal the CSV's bit for bit. Any of them at once, "
                       "each its own file: all are written or none." + OUTPUT_RULES)
    p.add_argument("log", metavar="LOG.mcap")
    p.add_argument("--csv", metavar="OUT.csv", help="the windowed estimates")
    p.add_argument("--fast-csv", metavar="OUT.csv", help="the high-rate slip")
    p.add_argument("--maneuvers-csv", metavar="OUT.csv", help="one row per maneuver (/maneuver): index, kind, "
                   "times, speeds, target, valid and why not ('; '-joined), the brake figures, time to speed, then "
                   "per wheel W mean_slip_W, max_abs_slip_W, cx_line_n_W, mu_peak_W, slip_at_mu_peak_W")
    p.add_argument("--mf4", metavar="OUT.mf4", help="the estimates, the high-rate wheel speeds and the GPS speed as "
                   "MF4 (needs asammdf: pip install 'slipdaq[mdf]')")
    p.add_argument("--parquet", metavar="OUT.parquet", help="the estimates as Parquet, with the log's name and labels "
                   "(needs pyarrow: pip install 'slipdaq[fleet]')")
    _add_allow_empty(p, "a log without estimates (the CSV is then its header only, the MF4 and Parquet without rows)")

    p = sub.add_parser("report", help="plots and tables of the slip study from one or more logs",
                       description="For each log and each maneuver phase in it (accelerate, cruise, brake): per "
                       "wheel, slip against time, speed, force Fx, effective radius Re and stiffness Cx against slip "
                       "as PNG, with the linear region's fitted line and the end of linearity marked; a summary "
                       "table (peak linear Fx and its slip, mean Re, peak and fitted Cx, r0, GPS latency, lost "
                       "frames, bad sentences); several logs compared side by side, grouped by their labels. "
                       "Writes DIR/index.html (opens offline), DIR/summary.json and DIR/summary.csv." + OUTPUT_RULES)
    p.add_argument("logs", nargs="+", metavar="LOG.mcap")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="directory for the report (created)")
    p.add_argument("--group-by", action="append", metavar="KEY",
                   help="compare logs grouped by this label (repeatable; default: every label but maneuver)")
    p.add_argument("--live", action="store_true",
                   help="use the estimates as logged (default: each log is post-processed two-pass, as "
                   "`replay --two-pass` does, from its raw records, in memory; the logs are not changed)")

    p = sub.add_parser("batch", help="many logs on Dask: Parquet dataset, fleet summary table, comparison report",
                       description=BATCH_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", nargs="+", metavar="LOG.mcap")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory (created)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="run on the Dask cluster of this scheduler, e.g. "
                       "tcp://HOST:8786 (default: a local cluster on this machine, no server to start)")
    where.add_argument("--workers", type=_positive, metavar="N",
                       help="worker processes of the local cluster, one thread each (default: this machine's cores)")
    p.add_argument("--group-by", action="append", metavar="KEY",
                   help="compare logs grouped by this label (repeatable; default: every label but maneuver)")

    p = sub.add_parser("calibration", help="show or reset a calibration file",
                       description="The calibration file keeps what runs learned about one vehicle and tire set (r0 "
                       "per wheel, GPS latency, fitted Cx per tire, the host clock's offset from UTC), each with when "
                       "and from which log; `run`, `import`, `replay` and `demo` start from it and save to it.")
    csub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    for name, text in (("show", "print what the calibration holds"),
                       ("reset", "clear the calibration (every value, or those of --wheel W: its tire changed)")):
        c = csub.add_parser(name, help=text, description=text + ". PATH: default calibration.path of the config, "
                            "else calibration.toml in log.dir of the config.")
        c.add_argument("path", nargs="?", metavar="PATH")
        _add_config(c)
        if name == "reset":
            c.add_argument("--wheel", action="append", choices=("FL", "FR", "RL", "RR"),
                           help="clear only this wheel's r0 and Cx (repeatable)")

    p = sub.add_parser("recover", help="a log that was not finished (killed, power loss), or a rotated run's "
                       "segments -> one finished log",
                       description="Read everything that is whole in the input logs, up to the last complete chunk "
                       "of each (a daemon killed with SIGKILL or a power loss leaves a log without its summary, "
                       "perhaps with a torn tail), and write it as one finished MCAP file with summary and indexes. "
                       "Several inputs (the segments of a rotated run, in order) are joined into one log, which "
                       "then replays like the live run. The inputs are not changed." + OUTPUT_RULES)
    p.add_argument("logs", nargs="+", metavar="IN.mcap", help="the log, or the segments of one run in order")
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap")
    return parser


def _config(path: str | None) -> Config:
    """Load and check the config, its DBC included (one clear ConfigError naming file and key)."""
    cfg = load_config(path)
    try:
        WheelDecoder(cfg)
        SignalDecoder(cfg)
    except DbcError as e:
        raise ConfigError(f"{cfg.source_path}: can.dbc ({', '.join(map(str, cfg.dbc_paths()))}): {e}") from None
    return cfg


def cmd_run(args: argparse.Namespace) -> int:
    from slipdaq.daemon import new_log_path, open_bus, run_daemon

    cfg = _config(args.config)
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
    from slipdaq.simulate import SimOptions, run_simulate

    cfg = _config(args.config)
    return run_simulate(cfg, SimOptions.from_args(args))


def cmd_demo(args: argparse.Namespace) -> int:
    from slipdaq.demo import run_demo
    from slipdaq.report.labels import parse_labels

    return run_demo(duration_s=args.duration, scenario=args.scenario, road=args.road, log_dir=Path(args.log_dir),
                    labels=parse_labels(args.label),
                    calibration_path=Path(args.calibration) if args.calibration else None,
                    no_calibration=args.no_calibration)


def cmd_import(args: argparse.Namespace) -> int:
    from slipdaq.offline import process_to_log
    from slipdaq.sources.files import iter_can_logs, iter_nmea_log, merge_by_time

    cfg = _config(args.config)
    can_logs = args.mf4 if args.mf4 else [args.can]
    if args.mf4:
        _require_mdf()
    if args.nmea is None and cfg.gps.source != "can":
        raise OutputError("import: give --nmea LOG, or a config whose reference speed comes from CAN "
                          "([gps] source = \"can\")")
    streams = [iter_can_logs(can_logs)] + ([iter_nmea_log(args.nmea)] if args.nmea else [])
    records = merge_by_time(*streams)
    meta = {"import_can": " ".join(map(str, can_logs)), "import_nmea": str(args.nmea or "")} | _labels_meta(args)
    cal = _run_calibration(args, cfg, Path(args.output).resolve().parent)
    inputs = [*can_logs, *([args.nmea] if args.nmea else []), *_config_files(cfg)]
    with atomic_output(args.output, inputs=inputs) as tmp:
        p = process_to_log(cfg, records, tmp, "import", metadata=meta, description="import", calibration=cal.start)
        d = p.diagnostics()
        _require(d.can_frames, f"{' '.join(map(str, can_logs))}: no CAN frames in it", args)
        if args.nmea:
            _require(d.nmea_lines + d.ubx_frames, f"{args.nmea}: no NMEA lines in it", args)
            why = ", ".join(f"{reason} {n}" for reason, n in d.dropped_sentences.items() if n)
            _require(p.fixes, f"{args.nmea}: no usable NMEA: 0 fixes from {d.nmea_lines} lines "
                     f"({d.bad_sentences} bad sentences{'; dropped: ' + why if why else ''})", args)
        else:
            _require(p.fixes, f"{' '.join(map(str, can_logs))}: no reference speed in it: no frame of "
                     f"{cfg.gps.message}.{cfg.gps.signal} ([gps] message and signal; their DBC in can.dbc)", args)
    ubx = f" ({d.ubx_frames} UBX frames)" if d.ubx_frames else ""
    gps = f"{d.nmea_lines} NMEA lines{ubx}" if args.nmea else f"{p.fixes} reference-speed frames"
    print(f"imported {d.can_frames} CAN frames and {gps} -> {args.output} "
          f"({d.estimates} estimates, {sum(d.lost_frames.values())} lost frames, {d.bad_sentences} bad sentences)")
    _save_calibration(cal, p.estimator.learned(), cfg, str(args.output))
    return EXIT_OK


def _require_mdf() -> None:
    """asammdf, for python-can's MF4 reader (the `mdf` extra)."""
    try:
        import asammdf  # noqa: F401
    except ImportError:
        raise OutputError("--mf4 needs asammdf: pip install 'slipdaq[mdf]'") from None


def _unfinished_note(path: str, scanned: object) -> None:
    """One line on stderr when a log was read without its summary (the daemon was killed or lost power)."""
    if getattr(scanned, "has_summary", True):
        return
    why = getattr(scanned, "stopped_because", "") or "no summary"
    print(f"slipdaq: note: {path} was not finished (killed or power loss?): read up to its last complete chunk "
          f"({getattr(scanned, 'read_bytes', 0)} of {getattr(scanned, 'size_bytes', 0)} bytes; {why}); "
          f"`slipdaq recover {path} -o FIXED.mcap` writes a finished copy", file=sys.stderr)


def cmd_replay(args: argparse.Namespace) -> int:
    from slipdaq.logformat.reader import config_from_log, iter_raw_batches, raw_record_count, read_metadata
    from slipdaq.logformat.salvage import ScanResult
    from slipdaq.offline import first_pass, process_to_log, start_calibration
    from slipdaq.report.labels import LABEL_PREFIX
    from slipdaq.sources.read_errors import guarded

    cfg = _config(args.config) if args.config else config_from_log(args.log)
    total = raw_record_count(args.log)
    meta = read_metadata(args.log)
    labels = {k: v for k, v in meta.items() if k.startswith(LABEL_PREFIX)}  # kept
    # without --calibration: the calibration the run started from (so the estimates are the run's)
    cal = _run_calibration(args, cfg, Path(args.output).resolve().parent, replay=True,
                           logged=start_calibration(meta, args.log))
    scanned = ScanResult(Path(args.log))
    first = None
    if args.two_pass:
        first = first_pass(cfg, guarded(args.log, iter_raw_batches(args.log)), cal.start, str(args.log), total=total)
    with atomic_output(args.output, inputs=[args.log, *_config_files(cfg)]) as tmp:
        p = process_to_log(cfg, guarded(args.log, iter_raw_batches(args.log, scanned)), tmp, "replay",
                           metadata={"replay_of": str(args.log), "two_pass": "true" if first else ""} | labels,
                           total=total, **(first.second_pass() if first else {"calibration": cal.start}))
        records = p.can_frames + p.nmea.lines + p.ubx.frames
        _require(records, f"{args.log}: no raw CAN or GPS records in it to replay", args)
    _unfinished_note(args.log, scanned)
    print(f"replayed {records} records -> {args.output} ({p.estimates} estimates{', two-pass' if first else ''})")
    _save_calibration(cal, first.learned if first else p.estimator.learned(), cfg, str(args.log))
    return EXIT_OK


def cmd_calibration(args: argparse.Namespace) -> int:
    from slipdaq.calibration import CalibrationError, default_path, load_calibration, reset, save_calibration, show

    cfg = load_config(args.config)
    path = Path(args.path) if args.path else default_path(cfg.resolve(cfg.log.dir), cfg)
    cal = load_calibration(path)
    if cal is None:
        raise CalibrationError(f"{path}: no calibration there (a run saves one at its end)")
    if args.action == "show":
        print(show(cal, str(path)))
        return EXIT_OK
    new = reset(cal, args.wheel)
    save_calibration(path, new)
    what = f"r0 and Cx of {', '.join(args.wheel)}" if args.wheel else "every value"
    print(f"{path}: cleared {what}")
    print(show(new, str(path)))
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    import contextlib

    from slipdaq.export import FORMATS, LogStreams, check_outputs

    outputs = {name: getattr(args, name) for name in FORMATS if getattr(args, name)}
    check_outputs(outputs, args.log)
    log = LogStreams(args.log)
    done = []
    with contextlib.ExitStack() as outs:  # each output renamed into place only when every one is complete
        for name, out in outputs.items():
            fmt = FORMATS[name]
            n = fmt.write(log, outs.enter_context(atomic_output(out, inputs=[args.log])))
            _require(n, f"{args.log}: no {fmt.what} in it to export{fmt.empty_note}", args)
            done.append(f"{n} {fmt.what} -> {out}")
    print("\n".join(done))
    _unfinished_note(args.log, log.scanned)
    return EXIT_OK


def cmd_recover(args: argparse.Namespace) -> int:
    import datetime as dt

    from slipdaq.recover import recover

    report = recover(args.logs, args.output)
    for r in report.inputs:
        last = "" if r.last_log_time_ns is None else \
            f", last message {dt.datetime.fromtimestamp(r.last_log_time_ns / 1e9, dt.UTC):%Y-%m-%d %H:%M:%S.%f} UTC"
        state = "finished" if r.has_summary else "not finished"
        why = f"; {r.stopped_because}" if r.stopped_because else ""
        print(f"{r.path}: {state}, {r.messages} messages read ({r.read_bytes} of {r.size_bytes} bytes{why}){last}")
    counts = ", ".join(f"{t} {n}" for t, n in sorted(report.topics.items()))
    print(f"recovered {report.messages} messages -> {report.output} ({counts})")
    return EXIT_OK


def cmd_report(args: argparse.Namespace) -> int:
    from slipdaq.report.build import make_report

    make_report(args.logs, args.output, group_by=args.group_by, progress=sys.stdout, two_pass=not args.live)
    return EXIT_OK


def cmd_batch(args: argparse.Namespace) -> int:
    from slipdaq.fleet import FleetError, failure, run_batch

    try:
        res = run_batch(args.logs, args.output, scheduler=args.scheduler, workers=args.workers, group_by=args.group_by)
    except FleetError as e:
        print(f"slipdaq: batch: {e}", file=sys.stderr)
        return EXIT_FAIL
    report = f"; report {res.report}" if res.report else "; no report (no log succeeded)"
    print(f"batch: {len(res.done)} processed, {len(res.skipped)} up to date, {len(res.failed)} failed -> "
          f"{res.out_dir / 'estimates'}{report}")
    for r in res.failed:
        print(f"slipdaq: batch: failed: {failure(r)}", file=sys.stderr)
    return EXIT_FAIL if res.failed else EXIT_OK


COMMANDS = {
    "run": cmd_run, "simulate": cmd_simulate, "demo": cmd_demo, "import": cmd_import,
    "replay": cmd_replay, "export": cmd_export, "report": cmd_report, "recover": cmd_recover,
    "calibration": cmd_calibration, "batch": cmd_batch,
}


def main(argv: list[str] | None = None) -> int:
    from slipdaq.report.labels import LabelError

    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.ERROR, format="%(levelname)s %(name)s: %(message)s")
    try:
        return COMMANDS[args.verb](args)
    except ConfigError as e:
        print(f"slipdaq: config error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except (LabelError, OutputError) as e:
        print(f"slipdaq: {e}", file=sys.stderr)
        return EXIT_USAGE
    except DbcError as e:  # a DBC stored in a log
        print(f"slipdaq: DBC error: {e}", file=sys.stderr)
        return EXIT_FAIL
    except (InputError, OSError) as e:  # LogError, ImportError_: an input that cannot be read
        print(f"slipdaq: {e}", file=sys.stderr)
        return EXIT_FAIL
    except KeyboardInterrupt:
        return 130
