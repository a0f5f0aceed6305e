"""What the verbs share: exit statuses, the output rules' text, the options every verb group adds (config, labels,
calibration, --allow-empty, --foxglove) and the checks behind them."""

from __future__ import annotations

import argparse
import gc
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from slipdaq.config import Config, ConfigError, load_config, parse_host_port
from slipdaq.config.calibration import Calibration, Learned, RunCalibration
from slipdaq.decode.can_signals import SignalDecoder
from slipdaq.decode.can_wheels import DbcError, WheelDecoder
from slipdaq.outputs import OutputError
from slipdaq.sources.read_errors import InputError

EXIT_OK, EXIT_FAIL, EXIT_USAGE, EXIT_LOSSES = 0, 1, 2, 3


OUTPUT_RULES = (" An output path that is one of the inputs is refused (exit 2). Outputs are written under a temporary "
                "name and renamed into place when complete: a failure leaves no partial output and an existing file "
                "as it was. An input that cannot be read: one line naming the file and where, exit 1.")

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


def _add_foxglove(p: argparse.ArgumentParser) -> None:
    def address(text: str) -> str:
        try:
            parse_host_port(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return text

    p.add_argument("--foxglove", type=address, metavar="[HOST:]PORT", help="serve the run live to Foxglove over "
                   "WebSocket (host default 127.0.0.1; port 0: any free port, printed); overrides live.foxglove")


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
    from slipdaq.config.calibration import default_path, for_replay, for_run

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


def _config(path: str | None) -> Config:
    """Load and check the config, its DBC included (one clear ConfigError naming file and key)."""
    cfg = load_config(path)
    try:
        WheelDecoder(cfg)
        SignalDecoder(cfg)
    except DbcError as e:
        raise ConfigError(f"{cfg.source_path}: can.dbc ({', '.join(map(str, cfg.dbc_paths()))}): {e}") from None
    return cfg


def _require_mdf() -> None:
    """asammdf, for python-can's MF4 reader (the `mdf` extra)."""
    try:
        import asammdf  # noqa: F401
    except ImportError:
        raise OutputError("--mf4 needs asammdf: pip install 'slipdaq[mdf]'") from None


def _require_png() -> None:
    """matplotlib, for the static figures of --png (the `png` extra); imported here only to check it is there."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise OutputError("--png needs matplotlib: pip install 'slipdaq[png]'") from None


def _unfinished_note(path: str, scanned: object) -> None:
    """One line on stderr when a log was read without its summary (the daemon was killed or lost power)."""
    if getattr(scanned, "has_summary", True):
        return
    why = getattr(scanned, "stopped_because", "") or "no summary"
    print(f"slipdaq: note: {path} was not finished (killed or power loss?): read up to its last complete chunk "
          f"({getattr(scanned, 'read_bytes', 0)} of {getattr(scanned, 'size_bytes', 0)} bytes; {why}); "
          f"`slipdaq recover {path} -o FIXED.mcap` writes a finished copy", file=sys.stderr)


@contextmanager
def _imports_frozen() -> Iterator[None]:
    """An offline run with numba's kernels loaded first (the collector paused: its start makes many long-lived
    objects) and every object made so far (the imports': python-can's asammdf with sympy and pandas, cantools, numba:
    about 200,000) out of the garbage collector's reach (gc.freeze) until it ends: otherwise each full collection
    walks them all again (a quarter of an import's CPU time)."""
    from slipdaq import compiled

    enabled = gc.isenabled()
    gc.disable()
    try:
        compiled.prepare()
        gc.freeze()
    finally:
        if enabled:
            gc.enable()
    try:
        yield
    finally:
        gc.unfreeze()

