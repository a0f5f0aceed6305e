"""Tire size -> free radius (hand-computed), and config validation: one clear error naming file and key."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from slipdaq.config import ConfigError, load_config, packaged_config_path
from slipdaq.config.tire_size import TireSizeError, free_radius_m, parse_tire_size
from support.paths import CONFIG, ROOT, write_config


@pytest.mark.parametrize(
    "size, radius_m",
    [
        ("195/60 R15", (2 * 0.60 * 195 + 15 * 25.4) / 2 / 1000),  # 0.3075
        ("225/65 R17", (2 * 0.65 * 225 + 17 * 25.4) / 2 / 1000),  # 0.36215
        ("205/55R16", (2 * 0.55 * 205 + 16 * 25.4) / 2 / 1000),  # 0.31595
        ("P215/70 ZR 14", (2 * 0.70 * 215 + 14 * 25.4) / 2 / 1000),
        ("195/60 R15 88H", (2 * 0.60 * 195 + 15 * 25.4) / 2 / 1000),
    ],
)
def test_free_radius_from_size(size: str, radius_m: float) -> None:
    assert free_radius_m(size) == pytest.approx(radius_m, abs=1e-12)


def test_free_radius_example_values() -> None:
    assert free_radius_m("195/60 R15") == pytest.approx(0.3075)
    assert parse_tire_size("225/65 R17") == (225.0, 65.0, 17.0)


@pytest.mark.parametrize("bad", ["195-60-15", "R15", "195/60", "abc", ""])
def test_bad_tire_size(bad: str) -> None:
    with pytest.raises(TireSizeError):
        parse_tire_size(bad)


def test_example_config_loads_and_matches_package() -> None:
    c = load_config(CONFIG)
    assert c.vehicle.mass_kg == 1300.0 and c.vehicle.driven_axle == "front"
    assert c.tire.radius_m == pytest.approx(0.3075)
    assert c.wpt.pulses_per_rev == 1000 and c.gps.latency_s == "auto" and c.estimator.window_s == 0.5
    assert c.resolve(c.can.dbc) == ROOT / "config" / "wpt.dbc"
    assert packaged_config_path().read_text() == CONFIG.read_text()


def test_free_radius_overrides_size(tmp_path: Path) -> None:
    c = load_config(write_config(tmp_path, '[tire]\nsize = "195/60 R15"\nfree_radius_m = 0.3045\n'))
    assert c.tire.radius_m == 0.3045


def test_effective_config_round_trips(cfg) -> None:  # type: ignore[no-untyped-def]
    from slipdaq.config import parse_config

    again = parse_config(cfg.to_toml())
    assert again.model_dump() == cfg.model_dump()


@pytest.mark.parametrize(
    "text, key, words",
    [
        ("[vehicle]\nmass_kg = -5\n", "vehicle.mass_kg", "greater than 0"),
        ("[vehicle]\nmass = 1300\n", "vehicle.mass", "unknown key"),
        ("[vehicle]\ndriven_axle = \"middle\"\n", "vehicle.driven_axle", "front"),
        ("[tire]\nsize = \"big\"\n", "tire.size", "W/A Rd"),
        ("[gps]\nlatency_s = \"soon\"\n", "gps.latency_s", "auto"),
        ("[gps]\nlatency_s = -0.1\n", "gps.latency_s", "0 to 5"),
        ("[wpt]\npulses_per_rev = \"many\"\n", "wpt.pulses_per_rev", "integer"),
        ("[estimator]\nwindow_s = 0\n", "estimator.window_s", "greater than 0"),
        # slip divides by the GPS speed: at 0 a car at a standstill has none
        ("[estimator]\nmin_speed_mps = 0\n", "estimator.min_speed_mps", "greater than 0"),
        ("[bogus]\nx = 1\n", "bogus", "unknown key"),
        ("[vehicle\n", "", "not valid TOML"),
    ],
)
def test_bad_config_names_file_and_key(tmp_path: Path, text: str, key: str, words: str) -> None:
    path = write_config(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_config(path)
    msg = str(e.value)
    assert str(path) in msg and key in msg and words in msg
    assert "\n" not in msg


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "slipdaq", *args], cwd=cwd, capture_output=True, text=True, timeout=60)


def test_cli_bad_config_exit_2_no_traceback(tmp_path: Path) -> None:
    path = write_config(tmp_path, "[vehicle]\nmass_kg = -1\n")
    r = _cli("run", "--config", str(path), "--duration", "1", cwd=tmp_path)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert r.stderr.count("\n") == 1 and "vehicle.mass_kg" in r.stderr and str(path) in r.stderr


def test_cli_missing_dbc_message_exit_2(tmp_path: Path) -> None:
    dbc = (ROOT / "config" / "wpt.dbc").read_text().replace("WPT_RR", "WPT_XX")
    path = write_config(tmp_path, "", dbc=dbc)
    r = _cli("replay", "nothing.mcap", "--config", str(path), "-o", "x.mcap", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "can.dbc" in r.stderr and "WPT_RR" in r.stderr and str(path) in r.stderr


def test_cli_missing_config_file_exit_2(tmp_path: Path) -> None:
    r = _cli("run", "--config", str(tmp_path / "nope.toml"), cwd=tmp_path)
    assert r.returncode == 2 and "nope.toml" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("verb", ["run", "simulate", "demo", "import", "replay", "export"])
def test_every_verb_has_help(verb: str, tmp_path: Path) -> None:
    r = _cli(verb, "--help", cwd=tmp_path)
    assert r.returncode == 0 and "usage: slipdaq " + verb in r.stdout and len(r.stdout) > 200
