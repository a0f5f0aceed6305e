#!/usr/bin/env python3
"""Starts slipdaq commands as their own processes without paying for the imports each time (HIL tests only).

Inside the emulated VM one Python process needs one to two minutes to import slipdaq's dependencies (numpy,
pydantic, cantools, python-can, mcap, rich: hundreds of files over the VM's 9p file system, every instruction
emulated). This process imports them once, then forks one child per request: the child is a separate process that
runs the real entry point — `slipdaq.cli.main(argv)` exactly as `python -m slipdaq ...` does, or a script such as
tools/replay/replay_bus.py as `__main__` — with its stdout and stderr on the pipe given with the request. It can
wait until a file matching a glob exists first (`go`), e.g. the daemon's MCAP log, so that a traffic source starts
once the daemon is reading.

Protocol, on the Unix socket passed as fd argv[1]: the client sends one JSON request per message (kind, argv, cwd,
go, delay, nice: the child's scheduling priority) with one file descriptor attached (SCM_RIGHTS; the child's stdout
and stderr); the zygote answers `{"pid": N}`. On its own
stdout it prints `zygote: ready` once, then `exited PID RC` for each child it reaps.
"""

from __future__ import annotations

import contextlib
import gc
import glob
import importlib
import json
import os
import runpy
import select
import signal
import socket
import sys
import time
import traceback

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no BLAS worker threads in a process that forks
os.environ.setdefault("OMP_NUM_THREADS", "1")

PRELOAD = (
    "numpy", "can", "can.interfaces.socketcan", "serial", "slipdaq.cli", "slipdaq.live.daemon", "slipdaq.live.simulate",
    "slipdaq.sim.realtime", "slipdaq.sim.emit", "slipdaq.logformat.reader", "slipdaq.offline.run", "rich.live",
)


def _child(request: dict[str, object], out_fd: int, control: socket.socket) -> None:
    """In the forked child: never returns."""
    rc = 1
    try:
        control.close()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGCHLD):
            signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(out_fd, 1)
        os.dup2(out_fd, 2)
        os.close(out_fd)
        os.close(null)
        sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
        os.chdir(str(request.get("cwd") or "."))
        nice = int(request.get("nice", 0))  # type: ignore[call-overload]
        if nice:  # absolute; threads started later inherit it
            with contextlib.suppress(PermissionError):
                os.setpriority(os.PRIO_PROCESS, 0, nice)
        go = request.get("go")
        if go:
            while not glob.glob(str(go)):
                time.sleep(0.05)
            time.sleep(float(request.get("delay", 0.0)))  # type: ignore[arg-type]
        print("zygote-child: go", flush=True)
        argv = [str(a) for a in request["argv"]]  # type: ignore[attr-defined]
        try:
            if request["kind"] == "slipdaq":
                from slipdaq.cli import main

                rc = main(argv)
            else:
                sys.argv = argv
                runpy.run_path(argv[0], run_name="__main__")
                rc = 0
        except SystemExit as e:
            rc = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    except BaseException:
        traceback.print_exc()
        rc = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(rc if isinstance(rc, int) else 1)


def main() -> int:
    control = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET, fileno=int(sys.argv[1]))
    for name in PRELOAD:
        importlib.import_module(name)
    importlib.import_module("slipdaq.compiled").prepare()  # numba's kernels, once: the children inherit them
    gc.freeze()  # the imported modules are permanent: children's collections need not scan them (full ones take
    # hundreds of ms in the emulated VM; a fork server freezes what it preloaded)
    print("zygote: ready", flush=True)
    while True:
        ready, _, _ = select.select([control], [], [], 0.2)
        while True:  # reap
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            print(f"exited {pid} {os.waitstatus_to_exitcode(status)}", flush=True)
        if not ready:
            continue
        data, fds, _flags, _addr = socket.recv_fds(control, 65536, 1)
        if not data:  # the client closed the socket: children keep running, the zygote ends
            return 0
        request = json.loads(data)
        sys.stdout.flush()
        pid = os.fork()
        if pid == 0:
            _child(request, fds[0], control)
        os.close(fds[0])
        control.sendall(json.dumps({"pid": pid}).encode())


if __name__ == "__main__":
    sys.exit(main())
