"""Config faults: each is one line naming the file, the key and what is expected; exit status 2; no
traceback. (Bad values of each key: tests/test_tire_config.py; here what is around them: unreadable files, a
directory, the DBC.)"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from slipdaq.cli import main
from support.paths import CONFIG, ROOT, write_config

DBC = (ROOT / "config" / "wpt.dbc").read_text()


def _run(capsys, *argv: str) -> tuple[int, str]:  # type: ignore[no-untyped-def]
    capsys.readouterr()
    rc = main(list(argv))
    return rc, capsys.readouterr().err


def _one_line(err: str, *words: str) -> None:
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)


def test_a_directory_given_as_config(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    rc, err = _run(capsys, "run", "--config", str(tmp_path), "--duration", "1")
    assert rc == 2
    _one_line(err, str(tmp_path), "cannot read config")


def test_dbc_that_is_a_directory(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "dbcdir").mkdir()
    cfg = write_config(tmp_path, '[can]\ndbc = "dbcdir"\n')
    rc, err = _run(capsys, "run", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), "can.dbc", "dbcdir")


def test_dbc_missing_file(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    cfg = write_config(tmp_path, '[can]\ndbc = "nowhere.dbc"\n')
    rc, err = _run(capsys, "simulate", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), "can.dbc", "nowhere.dbc")


def test_dbc_that_does_not_parse(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    cfg = write_config(tmp_path, "", dbc='VERSION ""\nBO_ this is not a DBC\n\x00\x01')
    rc, err = _run(capsys, "run", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), "can.dbc", "cannot parse DBC")


@pytest.mark.parametrize("old, new, words", [
    ("WPT_FL", "WPT_XX", ["WPT_FL", "not found"]),  # a missing message
    ("SG_ Seq : 56|8@1+ (1,0) [0|255] \"\" SLIPDAQ\n\nBO_ 787", "\nBO_ 787", ["WPT_RL", "Seq"]),  # a missing signal
])
def test_dbc_missing_message_or_signal(tmp_path: Path, capsys, old: str, new: str, words: list[str]) -> None:  # type: ignore[no-untyped-def]
    assert old in DBC
    cfg = write_config(tmp_path, "", dbc=DBC.replace(old, new, 1))
    rc, err = _run(capsys, "run", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), "can.dbc", *words)


@pytest.mark.parametrize("text, key, words", [
    ('[vehicle]\nmass_kg = "heavy"\n', "vehicle.mass_kg", "number"),
    ("[log]\nchunk_size_bytes = -1\n", "log.chunk_size_bytes", "greater than 0"),
    ("[gps]\nbaudrate = 11.5\n", "gps.baudrate", "integer"),
    ("[log]\nrotate = 1\n", "log.rotate", "unknown key"),
    ("vehicle = 3\n", "vehicle", ""),
])
def test_wrong_type_and_unknown_key_via_the_cli(tmp_path: Path, capsys, text: str, key: str, words: str) -> None:  # type: ignore[no-untyped-def]
    cfg = write_config(tmp_path, text)
    rc, err = _run(capsys, "run", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), key, words)


# Strict types: a value of another type is refused, never converted ("1000" is not 1000, 1 is not true).
@pytest.mark.parametrize("text, key, words", [
    ('[wpt]\npulses_per_rev = "1000"\n', "wpt.pulses_per_rev", "integer"),
    ('[vehicle]\nmass_kg = "1300"\n', "vehicle.mass_kg", "number"),
    ("[estimator]\ncalibrate_r0 = 1\n", "estimator.calibrate_r0", "boolean"),
    ('[estimator]\nwindow_s = "0.5"\n', "estimator.window_s", "number"),
    ('[gps]\nlatency_s = "0.1"\n', "gps.latency_s", "'auto'"),
    ("[gps]\nbaudrate = 115200.0\n", "gps.baudrate", "integer"),
    ('[log]\nrotate_size_bytes = "5000000"\n', "log.rotate_size_bytes", "integer"),
    ('[wheels.FL]\nmessage = "M"\nsignal = "S"\npulses_per_rev = "100"\n', "wheels.FL.pulses_per_rev", "integer"),
    ("[tire]\nsize = 195\n", "tire.size", "string"),
])
def test_a_value_of_another_type_is_refused_not_converted(tmp_path: Path, capsys, text: str, key: str,  # type: ignore[no-untyped-def]
                                                          words: str) -> None:
    cfg = write_config(tmp_path, text)
    rc, err = _run(capsys, "run", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), f": {key}: ", words)
    assert "literal" not in err and ".float" not in err  # the TOML key, not pydantic's union tags


def test_an_integer_is_a_number(tmp_path: Path) -> None:
    from slipdaq.config import load_config

    cfg = load_config(write_config(tmp_path, "[vehicle]\nmass_kg = 1500\n[gps]\nlatency_s = 0\n"))
    assert cfg.vehicle.mass_kg == 1500.0 and cfg.latency_fixed_s == 0.0


def test_config_that_is_not_utf8(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    cfg = tmp_path / "latin1.toml"
    cfg.write_bytes('[vehicle]\n# Fahrzeug für die Messung\nmass_kg = 1300.0\n'.encode("latin-1"))
    rc, err = _run(capsys, "run", "--config", str(cfg), "--duration", "1")
    assert rc == 2
    _one_line(err, str(cfg), "UTF-8")


def test_bad_config_as_a_process_exit_2_one_line(tmp_path: Path) -> None:
    cfg = write_config(tmp_path, '[can]\ndbc = "dbcdir"\n')
    (tmp_path / "dbcdir").mkdir()
    r = subprocess.run([sys.executable, "-m", "slipdaq", "run", "--config", str(cfg)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    _one_line(r.stderr, str(cfg), "can.dbc")
    assert CONFIG.exists()
