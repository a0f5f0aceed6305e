"""A two-pass run's second pass plays back what its first pass's wheel and NMEA decoders made (offline.decoder_tape):
every sink call the same as with decoders of its own (estimates, fixes, wheel samples, diagnostics with the decoders'
counters, raw records), a tape past its budget plays nothing, and a second pass over other records is refused. A
DecodingPipeline (offline.first_pass_feed) makes the same decoder calls as a pass that estimates, and a tape fed them
run by run plays them to both passes, the same calls as decoding."""

from __future__ import annotations

import dataclasses
import os
import sys
from typing import Any

import numpy as np
import pytest

from slipdaq.config import Config, load_config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.offline.decoder_tape import DecoderTape, TapedNmeaDecoder, TapedWheelDecoder, TapeMismatch
from slipdaq.offline.first_pass_feed import DecodingPipeline, FeedSender
from slipdaq.offline.items import batched, read_ahead
from slipdaq.offline.run import FirstPass, first_pass, process
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
    """40 s of the cycle drive, its frames jittered and its lines late (neither on the other's time grid: the
    diagnostics snapshots fall due at frames and at lines), with NMEA lines the decoder drops or counts (a bad
    checksum, a comment, an unused sentence, noise before a sentence) and frames cut into batches of 100."""
    records: list[Any] = []
    frames: list[Any] = []
    settings = SimSettings(seed=7, gps_latency_s=0.047, can_jitter_s=0.0003)  # frames and lines off a common grid
    for k, ev in enumerate(e for e in generate(cfg, "cycle", "paved", settings, duration_s=40.0)
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
    rec = TapedWheelDecoder(cfg, tape, play=None)
    seen = [(rec.decode_batch(b), rec.frames, rec.bad_frames) for b in records]
    play = TapedWheelDecoder(cfg, tape, play=iter(tape.wheels))
    for b, (samples, frames, bad) in zip(records, seen, strict=True):
        assert play.decode_batch(b) is samples
        assert (play.frames, play.bad_frames) == (frames, bad)
    assert np.sum(list(seen[-1][1].values())) > 0


def _entries(tape: DecoderTape) -> tuple[list[Any], list[Any]]:
    """The tape's entries in a form == compares."""
    wheels = [(n, t, *(getattr(s, f.name).tobytes() for f in dataclasses.fields(s)), c.tobytes(), bad)
              for n, t, s, c, bad in tape.wheels]
    return wheels, list(tape.lines)


def test_a_decoding_pipeline_makes_the_decoder_calls_of_a_pass_that_estimates(cfg: Config) -> None:
    """The same items in the same runs: the same calls, cut where the diagnostics snapshots fall, with the same
    outputs and counters, as the first pass's (which estimates and takes the snapshots)."""
    records = _records(cfg)
    tape = DecoderTape()
    with open(os.devnull, "w") as quiet:
        first_pass(cfg, records, None, "test", stream=quiet, tape=tape)
    decoding = DecodingPipeline(cfg, [], maneuvers=False, fast_slip=False)
    made = DecoderTape(sys.maxsize)
    made.attach(decoding)
    for run in read_ahead(batched(records)):
        decoding.process_all(run)
    assert decoding.estimator.status() == DecodingPipeline(cfg, []).estimator.status()  # nothing estimated
    assert len(tape.wheels) > 40 and len(tape.lines) > 400  # cut at each second's snapshot, at least
    assert _entries(made) == _entries(tape)


def _fed_passes(cfg: Config, records: list[Any], tape: DecoderTape) -> tuple[FirstPass, _Calls, Pipeline]:
    """The first pass fed by a FeedSender (its runs' entries into tape as the pass takes them), the second with
    tape."""
    fed = 0

    def send(message: tuple[Any, ...]) -> None:
        nonlocal fed
        if message[0] is not None:
            tape.feed(*message[1:])
            fed += 1

    with open(os.devnull, "w") as quiet:
        first = first_pass(cfg, FeedSender(cfg, send, None).runs(records), None, "test", stream=quiet, tape=tape)
        calls = _Calls()
        p = process(cfg, records, [calls], stream=quiet, maneuvers=False, tape=tape, **first.second_pass())
    assert fed > 2  # run by run
    return first, calls, p


@pytest.mark.parametrize("budget", [None, 100_000])
def test_a_fed_tape_plays_to_both_passes_what_decoding_gives(cfg: Config, budget: int | None) -> None:
    """The first pass learns the same and the second's sink calls are the same as decoding's; a tape past its budget
    still plays what it is fed to the first pass, and the second pass decodes."""
    records = _records(cfg)
    with open(os.devnull, "w") as quiet:
        own_first = first_pass(cfg, records, None, "test", stream=quiet)
    own, _ = _second(cfg, records, None)
    tape = DecoderTape(budget, fed=True)
    first, calls, p = _fed_passes(cfg, records, tape)
    assert first.gps_speeds == own_first.gps_speeds and first.learned == own_first.learned
    assert calls.calls == own.calls
    assert tape.complete is (budget is None)
    assert type(p.wheels) is (TapedWheelDecoder if budget is None else WheelDecoder)


def test_a_fed_first_pass_over_other_records_is_refused(cfg: Config) -> None:
    """The entries fed are checked against the first pass's calls: a pass over records with one CAN batch left out
    (the feed made from them all) raises TapeMismatch."""
    records = _records(cfg)
    tape = DecoderTape(fed=True)
    sender = FeedSender(cfg, lambda m: tape.feed(*m[1:]) if m[0] is not None else None, None)
    k = next(i for i, r in enumerate(records) if isinstance(r, CanFrameBatch))
    with open(os.devnull, "w") as quiet, pytest.raises(TapeMismatch):
        first_pass(cfg, (r for i, r in enumerate(sender.runs(records)) if i != k), None, "test", stream=quiet,
                   tape=tape)
