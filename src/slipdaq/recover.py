"""Rewriting logs that were never finished (or a rotated run's segments) as one finished file: what
logformat.salvage.scan read, written with summary, indexes and statistics, several inputs joined in order.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from slipdaq.logformat.errors import LogError
from slipdaq.logformat.salvage import ScanResult, scan, scan_metadata
from slipdaq.outputs import atomic_output


class RecoverError(LogError):
    """The inputs cannot be recovered or joined (not MCAP, different runs)."""


@dataclass
class RecoverReport:
    inputs: list[ScanResult]
    output: Path
    messages: int
    topics: dict[str, int]


def recover(inputs: Sequence[str | Path], output: str | Path, metadata_name: str = "slipdaq") -> RecoverReport:
    """Everything readable of `inputs` (in order) into one finished MCAP file `output`.

    Channels are matched by topic; the first input's metadata is kept (with `recovered_from` added to the slipdaq
    record), and a later input's longer list of CAN channels (can_channels) too. Inputs of different runs (a
    different config) are refused, and so is an output that is one of the inputs (OutputError); the output is in
    place only once it is complete (outputs.atomic_output)."""
    if not inputs:
        raise RecoverError("no input")
    out = Path(output)
    first_meta: dict[str, str] | None = None
    for p in inputs:  # check them all before writing anything
        metas = {m.name: m.metadata for m in scan_metadata(p)}
        meta = metas.get(metadata_name)
        if meta is None:
            raise RecoverError(f"{p}: no '{metadata_name}' metadata: not a slipdaq log (or torn before it)")
        if first_meta is None:
            first_meta = meta
        elif meta.get("config_toml") != first_meta.get("config_toml") or meta.get("dbc") != first_meta.get("dbc"):
            raise RecoverError(f"{p}: recorded with another config than {inputs[0]}: not segments of one run")
    results: list[ScanResult] = []
    topics: dict[str, int] = {}
    total = 0
    with atomic_output(output, inputs=inputs) as tmp, open(tmp, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile=metadata_name, library="slipdaq recover")
        schema_ids: dict[tuple[str, str, bytes], int] = {}
        channels: str | None = None  # the can_channels of the last slipdaq record written
        channel_ids: dict[tuple[str, str], int] = {}
        for n, p in enumerate(inputs):
            res = ScanResult(Path(p))
            local_schema: dict[int, int] = {}
            local_channel: dict[int, int] = {}
            for kind, item in scan(p, res):
                if kind == "schema":
                    s: Schema = item  # type: ignore[assignment]  # scan() yields (kind, record); kind names the record's type
                    key = (s.name, s.encoding, bytes(s.data))
                    if key not in schema_ids:
                        schema_ids[key] = writer.register_schema(s.name, s.encoding, s.data)
                    local_schema[s.id] = schema_ids[key]
                elif kind == "channel":
                    c: Channel = item  # type: ignore[assignment]  # scan() yields (kind, record); kind names the record's type
                    ckey = (c.topic, c.message_encoding)
                    if ckey not in channel_ids:
                        channel_ids[ckey] = writer.register_channel(
                            c.topic, c.message_encoding, local_schema.get(c.schema_id, 0), dict(c.metadata))
                    local_channel[c.id] = channel_ids[ckey]
                elif kind == "metadata":
                    m: Metadata = item  # type: ignore[assignment]  # scan() yields (kind, record); kind names the record's type
                    data = dict(m.metadata)
                    if m.name == metadata_name:
                        if n and data.get("can_channels") == channels:
                            continue
                        if n:  # a later segment's longer list of CAN channels: the first's record with it
                            data = dict(first_meta or {}) | {"can_channels": data.get("can_channels", "")}
                        channels = data.get("can_channels")
                        data["recovered_from"] = json.dumps([str(Path(i).name) for i in inputs])
                    elif n:
                        continue
                    writer.add_metadata(m.name, data)
                elif kind == "message":
                    channel: Channel
                    msg: Message
                    channel, msg = item  # type: ignore[misc]  # a 'message' item is (Channel, Message)
                    writer.add_message(local_channel[channel.id], log_time=msg.log_time, data=msg.data,
                                       publish_time=msg.publish_time, sequence=msg.sequence)
                    topics[channel.topic] = topics.get(channel.topic, 0) + 1
                    total += 1
            results.append(res)
        writer.finish()
    return RecoverReport(results, out, total, topics)
