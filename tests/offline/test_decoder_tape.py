"""A two-pass run's second pass plays back what its first pass's wheel and NMEA decoders made (offline.decoder_tape):
every sink call the same as with decoders of its own (estimates, fixes, wheel samples, diagnostics with the decoders'
counters, raw records), a tape past its budget plays nothing, and a second pass over other records is refused."""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np
import pytest

from slipdaq.config import Config, load_config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.offline.decoder_tape import DecoderTape, TapedNmeaDecoder, TapedWheelDecoder, TapeMismatch
from slipdaq.offline.run import first_pass, process
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrameBatch, Estimate, GpsFix, NmeaLine, RawRecord, WheelSampleBatch
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import Sink
from support.paths import CONFIG


class _Calls(Sink):
    """Every call, its records in a form == compares."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.calls.append(("estimate", estimate.as_row(), log_time_s))

    def on_fix(self, fix: GpsFix) -> None:
        self.calls.append(("fix", fix))

    def on_raw(self, record: RawRecord) -> None:
        self.calls.append(("raw", record))

    def on_can_batch(self, batch: CanFrameBatch) -> None:
        self.calls.append(("frames", len(batch), batch.timestamp_s.tobytes()))

    def on_wheel_batch(self, samples: WheelSampleBatch) -> None:
        self.calls.append(("samples", *(getattr(samples, f.name).tobytes() for f in dataclasses.fields(samples))))

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self.calls.append(("diagnostics", diagnostics, log_time_s))


def _records(cfg: Config) -> list[Any]:
    """40 s of the cycle drive, with NMEA lines the decoder drops or counts (a bad checksum, a comment, an unused
    sentence, noise before a sentence) and frames cut into batches of 100."""
    records: list[Any] = []
    frames: list[Any] = []
    for k, ev in enumerate(e for e in generate(cfg, "cycle", "paved", SimSettings(seed=7), duration_s=40.0)
                           if e.record is not None):
        r = ev.record
        if isinstance(r, NmeaLine):
            if frames:
                records.append(CanFrameBatch.from_frames(frames))
                frames = []
            records.append(r)
            if k % 97 == 0:
                records += [dataclasses.replace(r, line=r.line[:-2] + "00"), dataclasses.replace(r, line="# note"),
                            dataclasses.replace(r, line="$GPGSV,1,1,00*79"), dataclasses.replace(r, line="x" + r.line)]
        else:
            frames.append(r)
            if len(frames) == 100:
                records.append(CanFrameBatch.from_frames(frames))
                frames = []
    return records


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config(CONFIG)


def _second(cfg: Config, records: list[Any], tape: DecoderTape | None) -> tuple[_Calls, Pipeline]:
    with open(os.devnull, "w") as quiet:
        first = first_pass(cfg, records, None, "test", stream=quiet, tape=tape)
        calls = _Calls()
        p = process(cfg, records, [calls], stream=quiet, maneuvers=False, tape=tape, **first.second_pass())
    return calls, p


def test_the_second_pass_played_back_is_the_one_decoded(cfg: Config) -> None:
    records = _records(cfg)
    own, p_own = _second(cfg, records, None)
    tape = DecoderTape()
    played, p = _second(cfg, records, tape)
    assert tape.complete and tape.wheels and tape.lines
    assert type(p.wheels) is TapedWheelDecoder and type(p.nmea) is TapedNmeaDecoder
    assert played.calls == own.calls
    kinds = {c[0] for c in own.calls}
    assert {"estimate", "fix", "samples", "diagnostics"} <= kinds
    d = [c[1] for c in own.calls if c[0] == "diagnostics"]
    assert d[-1]["bad_sentences"] > d[0]["bad_sentences"] and d[-1]["nmea_lines"] > d[0]["nmea_lines"]
    assert sum(d[-1]["dropped_sentences"].values()) > 0
    counts = {k for k, v in vars(NmeaDecoder()).items() if type(v) is int and not k.startswith("_")}
    assert counts == set(NmeaDecoder.COUNTERS)  # every running count is recorded on the tape
    for name in (*NmeaDecoder.COUNTERS, "dropped"):
        assert getattr(p.nmea, name) == getattr(p_own.nmea, name), name
    for name in ("frames", "lost_frames", "count_wraps", "counter_resets", "bad_frames"):
        assert getattr(p.wheels, name) == getattr(p_own.wheels, name), name


def test_a_tape_past_its_budget_plays_nothing(cfg: Config) -> None:
    records = _records(cfg)
    own, _ = _second(cfg, records, None)
    tape = DecoderTape(budget_bytes=100_000)
    calls, p = _second(cfg, records, tape)
    assert not tape.complete and not tape.wheels and not tape.lines
    assert type(p.wheels) is WheelDecoder and type(p.nmea) is NmeaDecoder
    assert calls.calls == own.calls


@pytest.mark.parametrize("change", ["frames", "line"])
def test_a_second_pass_over_other_records_is_refused(cfg: Config, change: str) -> None:
    records = _records(cfg)
    tape = DecoderTape()
    with open(os.devnull, "w") as quiet:
        first = first_pass(cfg, records, None, "test", stream=quiet, tape=tape)
        k = next(i for i, r in enumerate(records) if isinstance(r, CanFrameBatch if change == "frames" else NmeaLine))
        other = records[:k] + records[k + 1:]
        with pytest.raises(TapeMismatch):
            process(cfg, other, [], stream=quiet, maneuvers=False, tape=tape, **first.second_pass())


def test_a_played_wheel_decoder_gives_the_recorded_counters_between_calls(cfg: Config) -> None:
    records = [r for r in _records(cfg) if isinstance(r, CanFrameBatch)][:20]
    tape = DecoderTape()
    rec = TapedWheelDecoder(cfg, tape, play=False)
    seen = [(rec.decode_batch(b), rec.frames, rec.bad_frames) for b in records]
    tape._recorded = True
    play = TapedWheelDecoder(cfg, tape, play=True)
    for b, (samples, frames, bad) in zip(records, seen, strict=True):
        assert play.decode_batch(b) is samples
        assert (play.frames, play.bad_frames) == (frames, bad)
    assert np.sum(list(seen[-1][1].values())) > 0
