#!/usr/bin/env bash
# Runs inside the virtme-ng VM as root (started by run_vm.sh): brings up vcan0 and
# runs the HIL tests with $SLIPDAQ_PYTHON. Extra arguments go to pytest.
set -euo pipefail
exec 2>&1  # one output stream: vng writes guest stdout and stderr separately
export PYTHONDONTWRITEBYTECODE=1  # write no __pycache__ into the host tree
cd "$(dirname "${BASH_SOURCE[0]}")/../.."

modprobe vcan
ip link add dev vcan0 type vcan
ip link set vcan0 txqueuelen 10000
ip link set up vcan0
echo "hil(guest): $(uname -r), vcan0 up"

exec "${SLIPDAQ_PYTHON:?}" -m pytest -q -p no:cacheprovider tests/hil "$@"
