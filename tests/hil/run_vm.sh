#!/usr/bin/env bash
# Run the hardware-in-the-loop tests (tests/hil) inside a small QEMU VM booted with
# virtme-ng, because this machine's kernel has no SocketCAN. The VM sees the host's
# files read-only; the project root is passed read-write. Installs what is missing
# (qemu, a Debian kernel, busybox for vng's initramfs, virtme-ng) and exits with the
# guest's pytest status. Extra arguments go to pytest. Python: $SLIPDAQ_PYTHON,
# default <root>/.venv/bin/python. Limit on the VM run: $SLIPDAQ_HIL_TIMEOUT (s).
# The VM runs at nice $SLIPDAQ_HIL_NICE (default -10, root only; 0: as this shell): an
# emulated machine that other work on the host preempts stalls as a whole, for tens to
# hundreds of ms, and no process in it, the daemon under test included, keeps real time.
# Other SLIPDAQ_HIL_* variables (rates, durations, SLIPDAQ_HIL_ARTIFACTS: a directory
# under the project root to copy the logs to) are passed on to the tests; see README.md.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
PY="${SLIPDAQ_PYTHON:-$ROOT/.venv/bin/python}"
TIMEOUT="${SLIPDAQ_HIL_TIMEOUT:-1800}"
NICE="${SLIPDAQ_HIL_NICE:--10}"
export DEBIAN_FRONTEND=noninteractive
t0=$SECONDS

quiet() {  # run a command silently; show its output only if it fails
    local log rc=0; log="$(mktemp)"
    "$@" >"$log" 2>&1 || rc=$?
    [ "$rc" -eq 0 ] || cat "$log" >&2
    rm -f "$log"; return "$rc"
}

[ -x "$PY" ] || { echo "hil: no Python interpreter at $PY (set SLIPDAQ_PYTHON)" >&2; exit 2; }

# qemu, a kernel with modules (vcan), and a static busybox for vng's initramfs.
if ! command -v qemu-system-x86_64 >/dev/null || ! compgen -G '/boot/vmlinuz-*' >/dev/null \
   || ! command -v busybox >/dev/null; then
    echo "hil: installing qemu-system-x86, linux-image-amd64, busybox-static (apt)..."
    quiet apt-get update
    quiet apt-get install -y --no-install-recommends \
        qemu-system-x86 linux-image-amd64 busybox-static
fi

# vng calls virtme-run through PATH, so the interpreter's bin dir must be on it.
BIN="$(dirname "$PY")"
export PATH="$BIN:$PATH"
if ! command -v vng >/dev/null; then
    echo "hil: installing virtme-ng with $PY -m pip (the project's [hil] extra)..."
    quiet "$PY" -m pip install --disable-pip-version-check -e "$ROOT[hil]"
fi

KERNEL="$(ls -1 /boot/vmlinuz-* | sort -V | tail -n 1)"
echo "hil: setup took $((SECONDS - t0)) s; booting VM with kernel $KERNEL (no KVM, 2 CPUs, 2G, nice $NICE)..."

# Build the guest command with every argument quoted for the guest's shell.
# SLIPDAQ_HIL_* variables (rates, durations, an artifacts dir) are passed on to the tests in the guest.
CMD="SLIPDAQ_PYTHON=$(printf '%q' "$PY")"
while IFS='=' read -r name value; do
    CMD+=" $name=$(printf '%q' "$value")"
done < <(env | grep -E '^SLIPDAQ_HIL_[A-Z0-9_]+=' | grep -v -E '^SLIPDAQ_HIL_(TIMEOUT|NICE)=' || true)
CMD+=" bash $(printf '%q' "$ROOT/tests/hil/guest.sh")"
for a in "$@"; do CMD+=" $(printf '%q' "$a")"; done

# qemu re-opens /proc/self/fd/1 and 2 as files (truncating a redirected log), so
# give it a pipe: `| cat` keeps earlier lines of a `run_vm.sh >log 2>&1` intact.
PRIO=()
if [ "$NICE" != 0 ]; then
    if [ "$(id -u)" = 0 ]; then PRIO=(nice -n "$NICE"); else echo "hil: not root: the VM runs at this shell's priority"; fi
fi
t1=$SECONDS
set +e
${PRIO[@]+"${PRIO[@]}"} timeout --kill-after=30 "$TIMEOUT" vng --run "$KERNEL" --user root --disable-kvm \
    --cpus 2 --memory 2G --rwdir "$ROOT" --cwd "$ROOT" --exec "$CMD" </dev/null 2>&1 | cat
rc=${PIPESTATUS[0]}
set -e
[ "$rc" -eq 124 ] && echo "hil: VM run timed out after $TIMEOUT s" >&2
echo "hil: VM exited with status $rc; VM run $((SECONDS - t1)) s, total $((SECONDS - t0)) s"
exit "$rc"
