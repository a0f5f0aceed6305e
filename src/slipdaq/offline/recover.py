"""Rewriting logs that were never finished, or damaged, (or a rotated run's segments) as one finished file: what
logformat.salvage.scan read past the damage, written with summary, indexes and statistics, several inputs joined in
order; and the report of what could not be read (each damaged byte range: its log time, its messages by topic as
the message index or statistics count them).

Messages are written in the order of the file, which is log-time order: slipdaq's writer never writes a message
with an earlier log time than the one before it (and a rotated run's segments follow each other in time).
"""

from __future__ import annotations

import datetime as dt
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from slipdaq.logformat.damage import lost_text, range_text, time_text
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

    @property
    def lossy(self) -> bool:
        """Something that held messages could not be read: the output was written with losses (exit status 3)."""
        return any(r.lossy for r in self.inputs)

    def lines(self) -> list[str]:
        """The report: per input how far it was read and each damaged range; what was written; what was lost."""
        out = [line for r in self.inputs for line in input_lines(r)]
        counts = ", ".join(f"{t} {n}" for t, n in sorted(self.topics.items()))
        out.append(f"recovered {self.messages} messages -> {self.output} ({counts})")
        if self.lossy:
            ranges = sum(1 for r in self.inputs for d in r.damaged if d.loses_data)
            lost = [n for r in self.inputs if (n := _lost_by_statistics(r)[0]) is not None]
            known = f"{sum(lost)} messages by the statistics" if len(lost) == len(self.inputs) else \
                "the number of messages unknown where the file has no statistics"
            orphans = sum(r.orphans for r in self.inputs)
            orph = f", {orphans} messages on channels whose definition is lost" if orphans else ""
            out.append(f"written with losses: {ranges} damaged ranges ({known}{orph}); exit status 3")
        return out


def _time(ns: int) -> str:
    return f"{dt.datetime.fromtimestamp(ns / 1e9, dt.UTC):%Y-%m-%d %H:%M:%S.%f} UTC"


def _lost_by_statistics(r: ScanResult) -> tuple[int | None, dict[str, int]]:
    """Messages the file's statistics count and the scan did not read: in all, and by topic."""
    if r.expected is None:
        return None, {}
    by_topic = {t: n - r.topics.get(t, 0) for t, n in r.expected.items() if n > r.topics.get(t, 0)}
    return sum(by_topic.values()), by_topic


def input_lines(r: ScanResult) -> list[str]:
    """How far one input was read, each damaged range (what it held, when), and the losses by its statistics."""
    last = "" if r.last_log_time_ns is None else f", last message {_time(r.last_log_time_ns)}"
    state = "finished" if r.has_summary else "not finished"
    why = f"; {r.stopped_because}" if r.stopped_because else ""
    lines = [f"{r.path}: {state}, {r.messages} messages read ({r.read_bytes} of {r.size_bytes} bytes{why}){last}"]
    for d in r.damaged:
        when = f"; {time_text(d)}" if d.loses_data else ""
        lines.append(f"  {'torn' if d.tail else 'damaged'}: {range_text(d)}{when}; {lost_text(d)}")
    if r.summary_damaged:
        lines.append(f"  {r.summary_damaged}: written anew")
    lost, by_topic = _lost_by_statistics(r)
    if lost:
        topics = ", ".join(f"{t} {n}" for t, n in sorted(by_topic.items()))
        lines.append(f"  lost by the file's statistics: {lost} of {sum((r.expected or {}).values())} messages "
                     f"({topics})")
    return lines


def recover(inputs: Sequence[str | Path], output: str | Path, metadata_name: str = "slipdaq") -> RecoverReport:
    """Everything readable of `inputs` (in order) into one finished MCAP file `output`: every message of every
    chunk that checks out, past damaged ones (RecoverReport.lossy then; each input's ScanResult.damaged says what).

    Channels are matched by topic; the first input's metadata is kept (with `recovered_from` added to the slipdaq
    record), and a later input's longer list of CAN channels (can_channels) too. Inputs of different runs (a
    different config) are refused, and so is an output that is one of the inputs (OutputError); the output is in
    place only once it is complete (outputs.atomic_output). Inputs with damage of which no message could be read:
    RecoverError, and no output."""
    if not inputs:
        raise RecoverError("no input")
    out = Path(output)
    first_meta: dict[str, str] | None = None
    for p in inputs:  # check them all before writing anything
        metas = {m.name: m.metadata for m in scan_metadata(p, skip_damage=True)}
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
            for kind, item in scan(p, res, skip_damage=True):
                if kind == "schema":
                    s: Schema = item
                    key = (s.name, s.encoding, bytes(s.data))
                    if key not in schema_ids:
                        schema_ids[key] = writer.register_schema(s.name, s.encoding, s.data)
                    local_schema[s.id] = schema_ids[key]
                elif kind == "channel":
                    c: Channel = item
                    ckey = (c.topic, c.message_encoding)
                    if ckey not in channel_ids:
                        channel_ids[ckey] = writer.register_channel(
                            c.topic, c.message_encoding, local_schema.get(c.schema_id, 0), dict(c.metadata))
                    local_channel[c.id] = channel_ids[ckey]
                elif kind == "metadata":
                    m: Metadata = item
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
                    channel, msg = item
                    writer.add_message(local_channel[channel.id], log_time=msg.log_time, data=msg.data,
                                       publish_time=msg.publish_time, sequence=msg.sequence)
                    topics[channel.topic] = topics.get(channel.topic, 0) + 1
                    total += 1
            results.append(res)
        if not total and any(r.lossy for r in results):
            raise RecoverError(f"nothing could be recovered: {'; '.join(_damage_summary(r) for r in results)}")
        writer.finish()
    return RecoverReport(results, out, total, topics)


def _damage_summary(r: ScanResult) -> str:
    ranges = ", ".join(f"{range_text(d)}" for d in r.damaged)
    return f"{r.path}: {r.messages} messages readable" + (f"; damaged at {ranges}" if ranges else "")
