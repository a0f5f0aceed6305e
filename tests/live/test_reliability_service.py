"""Running as a service: the systemd unit runs `slipdaq run` unprivileged, restarts on failure, is
hardened and valid for systemd itself. (That the daemon opens no network port: test_reliability_log.py, on a
running `slipdaq run`.)"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from support.paths import ROOT

PACKAGING = ROOT / "packaging"


def _unit(path: Path) -> dict[str, list[str]]:
    """key -> values (a key may repeat), sections flattened as 'Section.Key'."""
    out: dict[str, list[str]] = {}
    section = ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        out.setdefault(f"{section}.{key.strip()}", []).append(value.strip())
    return out


def test_service_unit_runs_unprivileged_restarts_and_is_hardened() -> None:
    u = _unit(PACKAGING / "slipdaq.service")
    one = {k: v[-1] for k, v in u.items()}
    assert "slipdaq run" in one["Service.ExecStart"] and "--log-dir /var/log/slipdaq" in one["Service.ExecStart"]
    assert one["Service.User"] == "slipdaq" and "dialout" in one["Service.SupplementaryGroups"]
    assert one["Service.Restart"] == "on-failure" and one["Service.RestartPreventExitStatus"] == "2"
    assert one["Service.KillSignal"] == "SIGTERM"
    for key, value in {"NoNewPrivileges": "yes", "ProtectSystem": "strict", "PrivateTmp": "yes",
                       "ProtectHome": "yes", "IPAddressDeny": "any", "CapabilityBoundingSet": ""}.items():
        assert one[f"Service.{key}"] == value, key
    assert "/var/log/slipdaq" in one["Service.ReadWritePaths"] and one["Service.LogsDirectory"] == "slipdaq"
    families = one["Service.RestrictAddressFamilies"].split()
    assert "AF_CAN" in families and not {"AF_INET", "AF_INET6", "AF_PACKET"} & set(families)
    assert {"char-ttyUSB rw", "char-ttyACM rw"} <= set(u["Service.DeviceAllow"])
    sysusers = (PACKAGING / "slipdaq.sysusers").read_text()
    assert "u slipdaq" in sysusers and "m slipdaq dialout" in sysusers
    net = _unit(PACKAGING / "80-can0.network")
    assert net["Match.Name"] == ["can0"] and net["CAN.BitRate"] and net["CAN.RestartSec"]


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze")
@pytest.mark.parametrize("name", ["slipdaq.service", "slipdaq-can@.service"])
def test_units_verify_with_systemd(tmp_path: Path, name: str) -> None:
    """systemd-analyze verify finds nothing (the ExecStart paths pointed at this machine's), and the service's
    exposure (systemd-analyze security) is rated OK."""
    text = (PACKAGING / name).read_text().replace("/opt/slipdaq/.venv/bin/slipdaq", str(Path(sys.executable).parent / "slipdaq"))
    ip = shutil.which("ip")
    if ip:
        text = text.replace("/usr/sbin/ip", ip)
    unit = tmp_path / name.replace("@.", "@can0.")
    unit.write_text(text)
    r = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and not r.stderr.strip(), r.stderr
    if name == "slipdaq.service":
        r = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(unit)], capture_output=True,
                           text=True, timeout=60)
        if r.returncode == 0 or "exposure level" in r.stdout:
            level = float(r.stdout.rsplit("exposure level for", 1)[1].split(":", 1)[1].split()[0])
            assert level <= 2.5, r.stdout[-400:]
