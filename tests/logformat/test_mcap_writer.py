"""logformat.mcap_writer writes the file mcap.Writer writes, byte for byte, whatever the calls: chunks closed by size
(compressed on its worker thread) and by flush, metadata between them, messages out of log-time order, channels
registered late, empty chunks."""

from __future__ import annotations

import io
import random

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from slipdaq.logformat.mcap_writer import McapWriter

CALL = st.one_of(
    st.tuples(st.just("message"), st.integers(0, 5), st.integers(0, 2**40), st.binary(max_size=300),
              st.integers(0, 2**32 - 1)),
    st.tuples(st.just("flush")),
    st.tuples(st.just("metadata"), st.text(max_size=5), st.dictionaries(st.text(max_size=5), st.text(max_size=20),
                                                                        max_size=3)),
    st.tuples(st.just("channel"), st.text(max_size=8)),
)


def _write(writer: Writer | McapWriter, calls: list[tuple], chunk_size: int) -> None:
    writer.start(profile="slipdaq", library="slipdaq test")
    sid = writer.register_schema("s", "jsonschema", b'{"type": "object"}')
    channels = [writer.register_channel(f"/t{i}", "json", sid) for i in range(3)]
    writer.add_metadata("slipdaq", {"version": "x"})
    for call in calls:
        if call[0] == "message":
            _, k, t, data, seq = call
            writer.add_message(channels[k % len(channels)], log_time=t, data=data, publish_time=t, sequence=seq)
        elif call[0] == "flush":
            writer.flush()
        elif call[0] == "metadata":
            writer.add_metadata(call[1], call[2])
        else:
            channels.append(writer.register_channel(call[1], "json", sid))
    writer.finish()


def _both(calls: list[tuple], chunk_size: int) -> tuple[bytes, bytes]:
    theirs, ours = io.BytesIO(), io.BytesIO()
    _write(Writer(theirs, chunk_size=chunk_size, compression=CompressionType.ZSTD), calls, chunk_size)
    _write(McapWriter(ours, chunk_size=chunk_size), calls, chunk_size)
    return theirs.getvalue(), ours.getvalue()


@settings(max_examples=60, deadline=None)
@given(st.lists(CALL, max_size=60), st.sampled_from([1, 200, 1000, 1 << 20]))
def test_the_file_is_mcap_writers(calls: list[tuple], chunk_size: int) -> None:
    theirs, ours = _both(calls, chunk_size)
    assert ours == theirs


def test_many_chunks_by_size_read_back() -> None:
    rng = random.Random(1)
    calls = [("message", rng.randrange(3), 10**9 + i * 1000 - rng.randrange(3000), rng.randbytes(rng.randrange(400)),
              i) for i in range(20000)]
    calls[5000:5000] = [("flush",), ("metadata", "m", {"a": "b"})]
    theirs, ours = _both(calls, 64 * 1024)
    assert ours == theirs
    summary = make_reader(io.BytesIO(ours)).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 50
    messages = [m.data for _s, _c, m in make_reader(io.BytesIO(ours)).iter_messages(log_time_order=False)]
    assert messages == [c[3] for c in calls if c[0] == "message"]


def test_a_with_block_finishes_the_file() -> None:
    """A writer used in a `with` block: the file is whole when the block ends (the mcap library reads its summary)."""
    stream = io.BytesIO()
    with McapWriter(stream, chunk_size=200) as writer:
        writer.start(profile="slipdaq", library="slipdaq test")
        sid = writer.register_schema("s", "jsonschema", b'{"type": "object"}')
        ch = writer.register_channel("/t", "json", sid)
        for i in range(50):
            writer.add_message(ch, log_time=i, data=b"{}", publish_time=i, sequence=i)
    stream.seek(0)
    summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 50
