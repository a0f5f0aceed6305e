"""slipdaq command line: verbs only (parse arguments, build the parts, run). `slipdaq VERB --help` explains each.
One module per verb group: live (run, simulate, demo), logs (import, replay, export, recover, calibration), study
(report, batch); common holds what they share."""

from __future__ import annotations

import argparse
import logging
import sys

import slipdaq
from slipdaq.cli import live, logs, study
from slipdaq.cli.common import EXIT_FAIL, EXIT_USAGE, ConfigError, DbcError, InputError, OutputError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slipdaq",
        description="Live wheel-slip acquisition: WPT pulse counts from CAN and NMEA GPS in, windowed slip, "
        "effective rolling radius Re, longitudinal force Fx and tire stiffness Cx out, all logged to MCAP.",
        epilog="Start with `slipdaq demo` (no hardware needed). Exit status: 0 ok, 1 failure, 2 bad config or usage, "
        "3 (recover) the output was written with losses.",
    )
    parser.add_argument("--version", action="version", version=f"slipdaq {slipdaq.__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log warnings and details to stderr")
    sub = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for group in (live, logs, study):
        group.add_parsers(sub)
    return parser


COMMANDS = live.COMMANDS | logs.COMMANDS | study.COMMANDS


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
