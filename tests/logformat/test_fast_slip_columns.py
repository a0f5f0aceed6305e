"""The high-rate slip rows as columns (records.fast_rows): a batch's rows, dicts and log messages are those of the
FastSlip records it holds, field for field and byte for byte (NaN, infinities, undefined values, sums that
overflow); a run's rows held as columns read back as the same dicts, however the batches were cut."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st
from test_epoch_json import exact, fast_slip_messages_one_by_one

from slipdaq import WHEELS
from slipdaq.logformat.json_codec import fast_slip_messages, std_dumps
from slipdaq.records import FastSlip, FastWheel
from slipdaq.records.fast_rows import FastRows, FastSlipBatch

FLOAT = st.floats(allow_nan=True, allow_infinity=True)
BIG = st.floats(min_value=1e307, max_value=1.7e308)  # finite values whose sum overflows
VALUE = st.one_of(FLOAT, BIG)
WHEEL = st.builds(FastWheel, st.one_of(st.none(), VALUE), st.one_of(st.none(), VALUE))
ROW = st.builds(FastSlip, st.floats(-1e10, 1e10), VALUE, VALUE, st.sampled_from(["imu", "gps"]),
                st.tuples(*[WHEEL] * len(WHEELS)).map(lambda ws: dict(zip(WHEELS, ws))))
ROWS = st.lists(ROW, min_size=1, max_size=12)


def _exact(rows: list[dict[str, object]]) -> list[object]:
    return [exact(std_dumps(r)) for r in rows]


@given(ROWS)
def test_batch_holds_the_rows_field_for_field(rows: list[FastSlip]) -> None:
    batch = FastSlipBatch.of_rows(rows, WHEELS)
    assert len(batch) == len(rows)
    assert _exact(batch.dicts()) == _exact([r.as_row() for r in rows])
    assert _exact([r.as_row() for r in batch]) == _exact([r.as_row() for r in rows])
    assert _exact([batch[-1].as_row()]) == _exact([rows[-1].as_row()])
    columns = batch.columns()
    assert list(columns) == list(rows[0].as_row())
    assert all(_exact([{"v": x} for x in columns[k]]) == _exact([{"v": r.as_row()[k]} for r in rows]) for k in columns)


@given(ROWS)
def test_batch_messages_are_the_rows_messages(rows: list[FastSlip]) -> None:
    """The /slip/fast message and the /slip/fast/row payloads from the columns: the bytes the records give, written
    one by one."""
    assert fast_slip_messages(FastSlipBatch.of_rows(rows, WHEELS)) == fast_slip_messages_one_by_one(rows)


@given(ROWS, st.lists(st.integers(0, 12), max_size=6), st.integers(1, 3))
def test_run_of_batches_reads_back_as_the_rows(rows: list[FastSlip], cuts: list[int], join_every: int) -> None:
    held = FastRows()
    held.JOIN_EVERY = join_every  # batches joined as they come, every join_every
    edges = sorted({0, len(rows), *(min(c, len(rows)) for c in cuts)})
    for a, b in zip(edges, edges[1:]):
        held.add(FastSlipBatch.of_rows(rows[a:b], WHEELS))
        held.add(FastSlipBatch.of_rows([], WHEELS))
    want = _exact([r.as_row() for r in rows])
    assert len(held) == len(rows)
    assert _exact(list(held)) == want
    assert _exact([held[i] for i in range(-len(rows), len(rows))]) == want + want
    assert _exact(held[1::2]) == want[1::2]
    assert _exact(held.columns().dicts()) == want
    halves = [FastSlipBatch.of_rows(rows[:1], WHEELS), FastSlipBatch.of_rows(rows[1:], WHEELS)]
    assert _exact(FastSlipBatch.concat(halves).dicts()) == want
