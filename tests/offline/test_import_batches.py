"""offline.frame_runs: a log's frames read in slices of any size reach the pipeline in the batches a reader of single
frames gives them through offline.batched (each naming only its own frames' channels, in order of appearance), so
that the log written is the same."""

from __future__ import annotations

import random

import numpy as np
import pytest

from slipdaq.offline.run import BATCH_FRAMES, batched, frame_runs
from slipdaq.records import FLAG_FD, CanFrame, CanFrameBatch, NmeaLine


def fields(b: CanFrameBatch) -> tuple:
    return (b.timestamp_s.tolist(), b.arbitration_id.tolist(), b.flags.tolist(), b.dlc.tolist(), b.data.tolist(),
            b.channel.tolist(), b.channels)


@pytest.mark.parametrize("seed", range(6))
def test_the_batches_of_single_frames(seed: int) -> None:
    rng = random.Random(seed)
    records: list[CanFrame | NmeaLine] = []
    for i in range(rng.randint(1, 3000)):
        if rng.random() < 0.002:
            records.append(NmeaLine(i, "$GPRMC"))
            continue
        fd = rng.random() < 0.01
        payload = rng.randbytes(rng.choice((8, 24) if fd else (0, 3, 8)))
        channel = rng.choice(["can0", "can0", "can1", "x"]) if i > 500 else "can0"
        records.append(CanFrame.from_flags(float(i), rng.randrange(2048), payload, FLAG_FD if fd else 0, 0, channel))
    expected = [CanFrameBatch.from_frames(r) if isinstance(r, list) else r for r in batched(records)]
    assert any(isinstance(r, CanFrameBatch) and len(r) == BATCH_FRAMES for r in expected) or len(records) < 1500
    sliced: list[CanFrameBatch | NmeaLine] = []  # runs of frames in slices of random sizes, as a reader gives them
    run: list[CanFrame] = []
    for r in [*records, None]:
        if isinstance(r, CanFrame):
            run.append(r)
            continue
        whole = CanFrameBatch.from_frames(run) if run else None
        i = 0
        while whole is not None and i < len(whole):
            k = min(len(whole), i + rng.randint(1, 700))
            sliced.append(whole.slice(i, k))
            i = k
        run = []
        if r is not None:
            sliced.append(r)
    got = list(frame_runs(sliced))
    assert len(got) == len(expected)
    for g, e in zip(got, expected):
        assert type(g) is type(e)
        if isinstance(e, CanFrameBatch):
            assert isinstance(g, CanFrameBatch) and fields(g) == fields(e)
            assert g.data.dtype == np.uint8
        else:
            assert g == e
