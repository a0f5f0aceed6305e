"""The log verbs: import (CAN, MF4, NMEA and MTi files into a log), replay, export, recover, calibration."""

from __future__ import annotations

import argparse
from pathlib import Path

from slipdaq.cli.common import (
    EXIT_LOSSES,
    EXIT_OK,
    OUTPUT_RULES,
    OutputError,
    _add_allow_empty,
    _add_calibration,
    _add_config,
    _add_label,
    _config,
    _config_files,
    _imports_frozen,
    _labels_meta,
    _require,
    _require_mdf,
    _run_calibration,
    _save_calibration,
    _unfinished_note,
    load_config,
)
from slipdaq.outputs import atomic_output


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """This group's verbs on the command line."""
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
    p.add_argument("--imu-xbus", metavar="FILE", help="an Xsens MTi's serial capture (Xbus MTData2, the bytes as "
                   "sent), its packets stamped from the MTi's UTCTime; the config's [imu] source = \"serial\" takes "
                   "their acceleration (axis, sign)")
    gps = p.add_mutually_exclusive_group()
    gps.add_argument("--nmea", metavar="LOG", help="NMEA log file; not needed when the config takes the reference "
                     "speed from CAN ([gps] source = \"can\": a CANmod.gps or a CANedge's GNSS in the same file)")
    gps.add_argument("--gps-raw", metavar="FILE", help="a receiver's raw byte capture instead (NMEA and UBX mixed as "
                     "u-center or `cat /dev/ttyACM0` records it, no host stamps): each message placed by its own GNSS "
                     "time (RMC date and time, NAV-PVT UTC), the CAN log's clock taken as UTC")
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
                       "each wheel W in FL FR RL RR: slip_W, re_W_m, r0_W_m, cx_W_n (then the extra columns: "
                       "the docs, The log). --fast-csv: one row per instant of the high-rate slip (estimator.fast_rate_hz, "
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
    p.add_argument("--sets-csv", metavar="OUT.csv", help="one row per test set ([[test.procedure]]): its last "
                   "/test_set record, the same names as columns (runs '; '-joined, excluded as '3: reason; ...')")
    p.add_argument("--imu-csv", metavar="OUT.csv", help="time_s, accel_mps2: the forward acceleration the estimator "
                   "took from the IMU ([imu] on CAN, or an Xsens MTi on serial), one row per sample")
    p.add_argument("--mf4", metavar="OUT.mf4", help="the estimates, the high-rate wheel speeds and the GPS speed as "
                   "MF4 (needs asammdf: pip install 'slipdaq[mdf]')")
    p.add_argument("--parquet", metavar="OUT.parquet", help="the estimates as Parquet, with the log's name and labels "
                   "(needs pyarrow: pip install 'slipdaq[fleet]')")
    p.add_argument("--tir", metavar="DIR", help="one Magic Formula tire property file per tire, DIR/FL.tir ... RR.tir "
                   "(MF-Tyre 6.1: the pure longitudinal force fitted to the log's accelerate and brake maneuvers, "
                   "valid over the slip they covered; a tire without mu-slip points gets none)")
    _add_allow_empty(p, "a log without estimates (the CSV is then its header only, the MF4 and Parquet without rows)")

    p = sub.add_parser("recover", help="a log that was not finished (killed, power loss) or is damaged, or a rotated "
                       "run's segments -> one finished log",
                       description="Read everything that is whole in the input logs (a daemon killed with SIGKILL or a "
                       "power loss leaves a log without its summary, perhaps with a torn tail; a flash card may flip "
                       "bits anywhere): every message of every chunk that checks out, past a damaged chunk (skipped) "
                       "or damaged bytes (reading goes on at the next record that parses), up to a torn tail, and "
                       "write it as one finished MCAP file with summary and indexes. Several inputs (the segments of "
                       "a rotated run, in order) are joined into one log, which then replays like the live run. The "
                       "inputs are not changed. Prints, per damaged byte range, its log time and the messages lost by "
                       "topic (as its message index or the file's statistics count them). Exit status: 0 nothing "
                       "lost, 3 the output was written with losses, 1 nothing could be recovered." + OUTPUT_RULES)
    p.add_argument("logs", nargs="+", metavar="IN.mcap", help="the log, or the segments of one run in order")
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap")

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


def cmd_import(args: argparse.Namespace) -> int:
    from slipdaq.offline.run import frame_runs, process_to_log
    from slipdaq.sources.files import iter_can_logs, iter_gps_capture, iter_nmea_log, merge_by_time
    from slipdaq.sources.xbus_file import iter_xbus_capture

    cfg = _config(args.config)
    can_logs = args.mf4 if args.mf4 else [args.can]
    if args.mf4:
        _require_mdf()
    gps_file = args.nmea or args.gps_raw
    if gps_file is None and cfg.gps.source != "can":
        raise OutputError("import: give --nmea LOG or --gps-raw FILE, or a config whose reference speed comes from "
                          "CAN ([gps] source = \"can\")")
    if args.imu_xbus and cfg.imu.source != "serial":
        raise OutputError("import --imu-xbus: the config's IMU must be the MTi ([imu] source = \"serial\", axis, sign)")
    gps_stream = [iter_nmea_log(args.nmea)] if args.nmea else [iter_gps_capture(args.gps_raw)] if args.gps_raw else []
    streams = [iter_can_logs(can_logs)] + gps_stream \
        + ([iter_xbus_capture(args.imu_xbus)] if args.imu_xbus else [])
    records = frame_runs(merge_by_time(*streams))
    meta = {"import_can": " ".join(map(str, can_logs)), "import_nmea": str(args.nmea or ""),
            **({"import_gps_raw": str(args.gps_raw)} if args.gps_raw else {}),
            "import_imu_xbus": str(args.imu_xbus or "")} | _labels_meta(args)
    cal = _run_calibration(args, cfg, Path(args.output).resolve().parent)
    inputs = [*can_logs, *([gps_file] if gps_file else []), *([args.imu_xbus] if args.imu_xbus else []),
              *_config_files(cfg)]
    with atomic_output(args.output, inputs=inputs) as tmp, _imports_frozen():
        p = process_to_log(cfg, records, tmp, "import", metadata=meta, description="import", calibration=cal.start)
        d = p.diagnostics()
        _require(d.can_frames, f"{' '.join(map(str, can_logs))}: no CAN frames in it", args)
        if gps_file:
            _require(d.nmea_lines + d.ubx_frames, f"{gps_file}: no NMEA lines in it", args)
            why = ", ".join(f"{reason} {n}" for reason, n in d.dropped_sentences.items() if n)
            _require(p.fixes, f"{gps_file}: no usable NMEA: 0 fixes from {d.nmea_lines} lines "
                     f"({d.bad_sentences} bad sentences{'; dropped: ' + why if why else ''})", args)
            _require(p.valid_fixes, f"{gps_file}: no valid fix: {p.fixes} fixes, all marked invalid (no satellite fix)",
                     args)
        else:
            _require(p.fixes, f"{' '.join(map(str, can_logs))}: no reference speed in it: no frame of "
                     f"{cfg.gps.message}.{cfg.gps.signal} ([gps] message and signal; their DBC in can.dbc)", args)
    ubx = f" ({d.ubx_frames} UBX frames)" if d.ubx_frames else ""
    gps = f"{d.nmea_lines} NMEA lines{ubx}" if gps_file else f"{p.fixes} reference-speed frames"
    print(f"imported {d.can_frames} CAN frames and {gps} -> {args.output} "
          f"({d.estimates} estimates, {sum(d.lost_frames.values())} lost frames, {d.bad_sentences} bad sentences)")
    _save_calibration(cal, p.estimator.learned(), cfg, str(args.output))
    return EXIT_OK


def cmd_replay(args: argparse.Namespace) -> int:
    from slipdaq.logformat.reader import config_from_log, iter_raw_messages, raw_record_count, read_metadata
    from slipdaq.logformat.salvage import ScanResult
    from slipdaq.offline.run import log_decoder, process_to_log, replay_two_pass, start_calibration
    from slipdaq.report.labels import LABEL_PREFIX

    cfg = _config(args.config) if args.config else config_from_log(args.log)
    total = raw_record_count(args.log)
    meta = read_metadata(args.log)
    labels = {k: v for k, v in meta.items() if k.startswith(LABEL_PREFIX)}  # kept
    # without --calibration: the calibration the run started from (so the estimates are the run's)
    cal = _run_calibration(args, cfg, Path(args.output).resolve().parent, replay=True,
                           logged=start_calibration(meta, args.log))
    scanned = ScanResult(Path(args.log))
    first = None
    written = {"replay_of": str(args.log), "two_pass": "true" if args.two_pass else ""} | labels
    with atomic_output(args.output, inputs=[args.log, *_config_files(cfg)]) as tmp, _imports_frozen():
        if args.two_pass:
            p, first = replay_two_pass(cfg, args.log, tmp, cal.start, metadata=written, total=total, scanned=scanned)
        else:
            p = process_to_log(cfg, iter_raw_messages(args.log, scanned), tmp, "replay", metadata=written, total=total,
                               decode=log_decoder(args.log), calibration=cal.start)
        records = p.can_frames + p.nmea.lines + p.ubx.frames
        _require(records, f"{args.log}: no raw CAN or GPS records in it to replay", args)
    _unfinished_note(args.log, scanned)
    print(f"replayed {records} records -> {args.output} ({p.estimates} estimates{', two-pass' if first else ''})")
    _save_calibration(cal, first.learned if first else p.estimator.learned(), cfg, str(args.log))
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    import contextlib

    from slipdaq.export.run import FORMATS, LogStreams, check_outputs

    outputs = {name: getattr(args, name) for name in FORMATS if getattr(args, name)}
    check_outputs(outputs, args.log, tir_dir=args.tir)
    log = LogStreams(args.log)
    done = []
    with contextlib.ExitStack() as outs:  # each output renamed into place only when every one is complete
        for name, out in outputs.items():
            fmt = FORMATS[name]
            n = fmt.write(log, outs.enter_context(atomic_output(out, inputs=[args.log])))
            _require(n, f"{args.log}: no {fmt.what} in it to export{fmt.empty_note}", args)
            done.append(f"{n} {fmt.what} -> {out}")
        if args.tir:
            from slipdaq.outputs import atomic_tree

            done += _export_tires(args, outs.enter_context(atomic_tree(args.tir, inputs=[args.log])))
    print("\n".join(done))
    if outputs:
        _unfinished_note(args.log, log.scanned)
    return EXIT_OK


def _export_tires(args: argparse.Namespace, build: Path) -> list[str]:
    """export --tir: the log summarized as the report does (its logged estimates), one .tir per tire in build."""
    from slipdaq.report.build import read_log
    from slipdaq.report.labels import labels_of
    from slipdaq.report.summary import summarize_log
    from slipdaq.report.tires import tire_results, write_tires

    d = read_log(args.log)
    summary = summarize_log(d.rows, d.metadata, d.diagnostics, path=str(d.path), name=d.path.name,
                            labels=labels_of(d.metadata), fast=d.fast, sensors=d.sensors)
    groups = tire_results([summary])
    written = write_tires(build, groups, flat=True).get(summary.group, {})
    _require(len(written), f"{args.log}: no tire to export (no accelerate or brake maneuver with high-rate slip "
             "points: a log recorded with estimator.fast_rate_hz = 0 has none)", args)
    lines = [f"{len(written)} tire files -> {Path(args.tir) / rel}" if i == 0 else f"  {Path(args.tir) / rel}"
             for i, rel in enumerate(written.values())]
    lines += [f"  no {r.wheel}.tir: {r.reason}" for g in groups for r in g.results if r.file is None]
    lines += [f"  {r.wheel}.tir: peak not passed: valid only over slip {r.file.slip_min:g} to {r.file.slip_max:g}"
              for g in groups for r in g.results if r.file is not None and r.fit is not None and not r.fit.peak_passed]
    return lines


def cmd_recover(args: argparse.Namespace) -> int:
    from slipdaq.offline.recover import recover

    report = recover(args.logs, args.output)
    print("\n".join(report.lines()))
    return EXIT_LOSSES if report.lossy else EXIT_OK


def cmd_calibration(args: argparse.Namespace) -> int:
    from slipdaq.config.calibration import CalibrationError, default_path, load_calibration, reset, save_calibration, show

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


COMMANDS = {"import": cmd_import, "replay": cmd_replay, "export": cmd_export, "recover": cmd_recover,
            "calibration": cmd_calibration}
