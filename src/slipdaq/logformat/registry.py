"""Which topics a log has and how each is written: message encoding and schema, by registration (in the order the
writer registers their channels). A new record stream registers its topic here and every log carries it."""

from __future__ import annotations

import json
from dataclasses import dataclass

from slipdaq.logformat import cdr
from slipdaq.logformat.schemas import BATCH_SCHEMAS, SCHEMAS


@dataclass(frozen=True, slots=True)
class TopicFormat:
    topic: str
    message_encoding: str
    """'cdr' (batches, logformat.cdr) or 'json' (logformat.json_codec)."""
    schema_name: str
    schema_encoding: str
    """'ros2msg' or 'jsonschema'."""
    schema_data: bytes


TOPIC_FORMATS: dict[str, TopicFormat] = {}


def register(fmt: TopicFormat) -> None:
    if fmt.topic in TOPIC_FORMATS:
        raise ValueError(f"topic {fmt.topic} is registered twice")
    TOPIC_FORMATS[fmt.topic] = fmt


for _topic, (_name, _text) in BATCH_SCHEMAS.items():
    register(TopicFormat(_topic, cdr.ENCODING, _name, cdr.SCHEMA_ENCODING, _text.encode()))
for _topic, _schema in SCHEMAS.items():
    register(TopicFormat(_topic, "json", _schema["title"], "jsonschema", json.dumps(_schema).encode()))
