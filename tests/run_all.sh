#!/usr/bin/env bash
# The whole test suite, from a clean clone: installs the project and its test tools into ./.venv when
# missing, runs the host tests, then the hardware-in-the-loop suite in a VM with SocketCAN vcan.
# SLIPDAQ_SKIP_HIL=1 skips the VM part (it needs root to install qemu the first time).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
py=${SLIPDAQ_PYTHON:-$root/.venv/bin/python}
if [ ! -x "$py" ]; then
    echo "tests: creating $root/.venv"
    python3 -m venv "$root/.venv"
    py=$root/.venv/bin/python
fi
echo "tests: installing slipdaq and its test dependencies into $(dirname "$(dirname "$py")")"
"$py" -m pip install -q --disable-pip-version-check -e "$root[test]" 2>&1 | grep -v "^WARNING: Location" || true
"$py" -c "import slipdaq, can, cantools, mcap, matplotlib, plotly, playwright, pytest, hypothesis, mkdocs" # fail early and clearly if the install failed
# The report page's browser test (tests/report/test_report_page.py) drives the OS's Chromium through Playwright: installed
# with apt when missing, as root (as tests/hil/run_vm.sh installs qemu); where it cannot be, that test skips (one line).
chromium=${SLIPDAQ_CHROMIUM:-/usr/bin/chromium}
if [ ! -x "$chromium" ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        echo "tests: installing chromium (apt) for the report page's browser test"
        log=$(mktemp)
        if ! { apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends chromium; } \
            >"$log" 2>&1; then
            tail -n 20 "$log" >&2
            echo "tests: chromium could not be installed: the report page's browser test will skip"
        fi
        rm -f "$log"
    else
        echo "tests: no $chromium and not root (or no apt): the report page's browser test will skip"
    fi
fi
echo "tests: lint (ruff) and type check (mypy), configured in pyproject.toml"
"$py" -m ruff check --quiet "$root"
"$py" -m mypy
echo "tests: docs site (mkdocs build --strict: a warning fails it)"
site=$(mktemp -d)
if ! NO_MKDOCS_2_WARNING=1 "$py" -m mkdocs build --strict --config-file "$root/mkdocs.yml" --site-dir "$site" \
    >"$site.log" 2>&1; then
    grep -v "^INFO" "$site.log" >&2
    exit 1
fi
rm -rf "$site" "$site.log"
echo "tests: host suite"
"$py" -m pytest -q -p no:cacheprovider tests --ignore=tests/hil
if [ "${SLIPDAQ_SKIP_HIL:-0}" = 1 ]; then
    echo "tests: HIL suite skipped (SLIPDAQ_SKIP_HIL=1)"
elif [ -f tests/hil/run_vm.sh ]; then
    echo "tests: hardware-in-the-loop suite (VM with vcan)"
    SLIPDAQ_PYTHON=$py bash tests/hil/run_vm.sh
fi
