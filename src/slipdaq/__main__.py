"""`python -m slipdaq` and the `slipdaq` command: the CLI, its modules imported with the garbage collector paused
(they make about 200,000 objects that live as long as the process: collections while they are made free nothing and
cost a fifth of the start-up)."""

import gc
import sys


def main() -> int:
    gc.disable()
    try:
        from slipdaq.cli import main as cli_main
    finally:
        gc.enable()
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
