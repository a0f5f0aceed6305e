"""`python -m slipdaq` and the `slipdaq` command: the CLI, its modules imported with the garbage collector paused and
then frozen out of its reach (gc.freeze): they make about 200,000 objects that live as long as the process, and
collections that walk them free nothing (a fifth of the start-up)."""

import gc
import sys


def main() -> int:
    gc.disable()
    try:
        from slipdaq.cli import main as cli_main

        gc.freeze()
    finally:
        gc.enable()
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
