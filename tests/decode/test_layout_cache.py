"""The wheel decoder's layouts kept in the cache directory (decode/layout_cache.py): a decoder built from the cache
decodes as one built from the DBC; a DBC that cantools decodes is not cached; another DBC is another key; a file
that does not read back is made again; a replay, and a batch's client, whose layout is cached import neither cantools
nor python-can."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.compiled import ahead
from slipdaq.config import load_config
from slipdaq.decode import can_wheels
from slipdaq.decode.can_wheels import LAYOUT_CACHE_NAME, WheelDecoder
from slipdaq.records import CanFrame, CanFrameBatch
from support.paths import CONFIG, ROOT, write_config


@pytest.fixture(autouse=True)
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A cache directory of the test's own, with the kernels compiled ahead of time copied in where the usual one has
    them (a command then loads them, not builds them)."""
    d = tmp_path / "cache"
    d.mkdir()
    for built in ahead.cache_dir().glob("slipdaq_kernels_*.so"):
        shutil.copy2(built, d)
    monkeypatch.setenv("SLIPDAQ_CACHE_DIR", str(d))
    return d


def _layouts(cache: Path) -> list[Path]:
    return sorted(cache.glob(f"{LAYOUT_CACHE_NAME}-*.pickle"))


def _wpt_frames(n: int = 3000, seed: int = 3) -> CanFrameBatch:
    """The four WPT messages (counts wrapping at 2^32, Seq with gaps), a wrong DLC now and then, other IDs."""
    rng = np.random.default_rng(seed)
    count = {784: 2**32 - 500, 785: 7, 786: 2**31, 787: 123}
    seq = dict.fromkeys(count, 0)
    frames, t = [], 100.0
    for k in range(n):
        t += 0.00025
        fid = 784 + k % 4
        count[fid] = (count[fid] + int(rng.integers(0, 3))) % 2**32
        seq[fid] = (seq[fid] + (2 if rng.random() < 0.01 else 1)) % 256
        data = count[fid].to_bytes(4, "little") + bytes([seq[fid], 0, 0, 0])
        if rng.random() < 0.005:
            data = data[:3]
        frames.append(CanFrame(t, fid if rng.random() > 0.02 else 0x123, data))
    return CanFrameBatch.from_frames(frames)


def test_a_decoder_from_the_cache_decodes_as_one_from_the_dbc(cache: Path) -> None:
    cfg = load_config(CONFIG)
    parsed = WheelDecoder(cfg)
    assert len(_layouts(cache)) == 1
    cached = WheelDecoder(cfg)
    assert all(isinstance(e.message, can_wheels._Named) for e in cached._entries)
    assert not any(isinstance(e.message, can_wheels._Named) for e in parsed._entries)
    assert cached.fast_messages == parsed.fast_messages == [f"WPT_{w}" for w in WHEELS]
    batch = _wpt_frames()
    for start in range(0, len(batch), 700):  # the decoders' state carried from batch to batch
        a, b = parsed.decode_batch(batch.slice(start, start + 700)), cached.decode_batch(batch.slice(start, start + 700))
        assert len(a) > 0
        for name in ("frame", "wheel", "timestamp_s", "revolutions", "count", "raw", "seq", "lost_frames", "flags"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert (parsed.frames, parsed.lost_frames, parsed.count_wraps, parsed.bad_frames) == \
        (cached.frames, cached.lost_frames, cached.count_wraps, cached.bad_frames)


def test_a_dbc_cantools_decodes_is_not_kept(tmp_path: Path, cache: Path) -> None:
    """A wheel speed signal in km/h goes through cantools frame by frame: the decoder needs the DBC's message."""
    dbc = (ROOT / "config" / "wpt.dbc").read_text() + '''
BO_ 801 WHEEL_SPEED_RR: 8 ABS
 SG_ SPEED_RR : 0|16@1+ (0.01,0) [0|655] "km/h" SLIPDAQ
'''
    cfg = load_config(write_config(tmp_path, '[wheels.RR]\nkind = "speed"\nmessage = "WHEEL_SPEED_RR"\n'
                                             'signal = "SPEED_RR"\n[can]\ndbc = "wpt.dbc"\n', dbc))
    decoder = WheelDecoder(cfg)
    assert _layouts(cache) == [] and "WHEEL_SPEED_RR" not in decoder.fast_messages
    samples = decoder.decode_batch(CanFrameBatch.from_frames([CanFrame(1.0, 801, (3600).to_bytes(2, "little") * 4),
                                                              CanFrame(1.1, 801, (3600).to_bytes(2, "little") * 4)]))
    assert len(samples) == 2


def test_another_dbc_is_another_key_and_a_broken_file_is_made_again(tmp_path: Path, cache: Path) -> None:
    cfg = load_config(CONFIG)
    WheelDecoder(cfg)
    WheelDecoder(cfg, dbc_text=cfg.load_dbc_text() + "\n")  # the same layout, another text
    files = _layouts(cache)
    assert len(files) == 2
    for f in files:
        f.write_bytes(f.read_bytes()[:20])  # cut short
    decoder = WheelDecoder(cfg)
    assert not any(isinstance(e.message, can_wheels._Named) for e in decoder._entries)  # from the DBC again
    assert WheelDecoder(cfg)._entries[0].message == can_wheels._Named("WPT_FL", 784)  # and kept whole again


PROBE = """
import runpy, sys
sys.argv = ["slipdaq", *sys.argv[1:]]
try:
    runpy.run_module("slipdaq", run_name="__main__")
except SystemExit as e:
    print("exit", e.code, "cantools" in sys.modules, "can" in sys.modules)
"""


def test_a_replay_whose_layout_is_cached_imports_neither_cantools_nor_python_can(tmp_path: Path) -> None:
    """The first replay parses the DBC (cantools, python-can with it); the next finds the layout and imports
    neither; both write the same messages."""
    from mcap.reader import make_reader

    from slipdaq.sim.emit import SimSettings, generate
    from slipdaq.sim.logs import write_drive_logs

    cfg = load_config(CONFIG)
    write_drive_logs(generate(cfg, "cycle", "paved", SimSettings(), 3.0), tmp_path / "d.log", tmp_path / "d.nmea")
    subprocess.run([sys.executable, "-m", "slipdaq", "import", "--can", str(tmp_path / "d.log"), "--nmea",
                    str(tmp_path / "d.nmea"), "--config", str(CONFIG), "-o", str(tmp_path / "d.mcap"),
                    "--no-calibration"], check=True, capture_output=True)
    for layout in _layouts(tmp_path / "cache"):
        layout.unlink()  # the import's own decoder kept it: start without

    def replay(out: str) -> str:
        done = subprocess.run([sys.executable, "-c", PROBE, "replay", str(tmp_path / "d.mcap"), "-o",
                               str(tmp_path / out), "--no-calibration"], capture_output=True, text=True, check=True)
        return done.stdout.splitlines()[-1]

    assert replay("a.mcap") == "exit 0 True True"
    assert replay("b.mcap") == "exit 0 False False"

    def messages(name: str) -> list[tuple[str, int, bytes]]:
        with open(tmp_path / name, "rb") as f:
            return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]

    assert messages("a.mcap") == messages("b.mcap")
    if importlib.util.find_spec("distributed") is None or importlib.util.find_spec("pyarrow") is None:
        return  # `batch` needs the fleet extra
    done = subprocess.run([sys.executable, "-c", PROBE, "batch", str(tmp_path / "d.mcap"), "-o", str(tmp_path / "b"),
                           "--workers", "1"], capture_output=True, text=True, check=True)
    assert done.stdout.splitlines()[-1] == "exit 0 False False"  # the client; its worker forked from it
    assert (tmp_path / "b" / "report" / "index.html").is_file()
