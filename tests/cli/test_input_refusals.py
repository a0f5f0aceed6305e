"""Inputs that give nothing to work with, and outputs that would be inputs, refused before anything is done."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from support.paths import CONFIG


def _invalidate(line: str) -> str:
    """An NMEA sentence with its fix marked invalid (RMC status V, GGA quality 0), checksum recomputed."""
    m = re.match(r"(\(\S+\) )?\$(?P<body>[^*]*)\*[0-9A-F]{2}", line)
    if not m:
        return line
    fields = m.group("body").split(",")
    if fields[0].endswith("RMC"):
        fields[2] = "V"
    elif fields[0].endswith("GGA"):
        fields[6] = "0"
    elif fields[0].endswith("VTG"):
        fields[-1] = "N"
    body = ",".join(fields)
    cs = 0
    for ch in body.encode():
        cs ^= ch
    return f"{m.group(1) or ''}${body}*{cs:02X}"


def test_an_nmea_log_without_a_valid_fix_is_refused_unless_allowed(tmp_path: Path) -> None:
    cfg = load_config(CONFIG)
    write_drive_logs(generate(cfg, "cycle", "paved", SimSettings(seed=3), duration_s=3.0),
                     tmp_path / "d.log", tmp_path / "d.nmea")
    lines = (tmp_path / "d.nmea").read_text().splitlines()
    (tmp_path / "bad.nmea").write_text("\n".join(_invalidate(x) for x in lines) + "\n")
    args = ["import", "--can", str(tmp_path / "d.log"), "--nmea", str(tmp_path / "bad.nmea"), "--config", str(CONFIG),
            "--no-calibration", "-o", str(tmp_path / "out.mcap")]
    assert main(args) == 1 and not (tmp_path / "out.mcap").exists()
    assert main([*args, "--allow-empty"]) == 0 and (tmp_path / "out.mcap").exists()
    args[4] = str(tmp_path / "d.nmea")  # the same drive with its fixes valid
    (tmp_path / "out.mcap").unlink()
    assert main(args) == 0


def test_report_into_its_own_input_is_refused_before_reading(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`report LOG -o LOG`: refused (exit 2) before the log is read: a log that cannot be read says so only when the
    output is another path (exit 1)."""
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    assert main(["report", str(bad), "-o", str(bad)]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert bad.read_bytes() == b"not an mcap file"
    assert main(["report", str(bad), "-o", str(tmp_path / "rep")]) == 1
    index = tmp_path / "rep2" / "index.html"
    index.parent.mkdir()
    index.write_bytes(b"not an mcap file either")
    assert main(["report", str(index), "-o", str(index.parent)]) == 2


def test_a_symlinked_or_hard_linked_output_is_replaced_not_written_through(tmp_path: Path) -> None:
    cfg = load_config(CONFIG)
    write_drive_logs(generate(cfg, "cycle", "paved", SimSettings(seed=3), duration_s=3.0),
                     tmp_path / "d.log", tmp_path / "d.nmea")
    assert main(["import", "--can", str(tmp_path / "d.log"), "--nmea", str(tmp_path / "d.nmea"), "--config",
                 str(CONFIG), "--no-calibration", "-o", str(tmp_path / "d.mcap")]) == 0
    target = tmp_path / "kept.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    hard = tmp_path / "hard.csv"
    other = tmp_path / "other-name.csv"
    other.write_text("old\n")
    hard.hardlink_to(other)
    assert main(["export", str(tmp_path / "d.mcap"), "--csv", str(link), "--fast-csv", str(hard)]) == 0
    # through a symlink: its target is replaced (the link stays and now shows the new file)
    assert link.is_symlink() and target.read_text().startswith("time_s,")
    # a name with other hard links: a new file under that name, the other names keep the old content
    assert hard.read_text().startswith("time_s,") and other.read_text() == "old\n"
