"""Free-form run labels (`--label KEY=VALUE` on run, import and demo), stored in a log's `slipdaq` metadata.

A label KEY=VALUE is stored as the metadata entry `label.KEY` = VALUE, so labels never collide with the keys
slipdaq writes itself (mode, config_toml, dbc, ...). A demo log without a `road`/`maneuver` label is labelled
from its `demo_road`/`demo_scenario` entries.
"""

from __future__ import annotations

import re

LABEL_PREFIX = "label."
_KEY = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
_DEMO_KEYS = {"road": "demo_road", "maneuver": "demo_scenario"}


class LabelError(ValueError):
    """A label that is not KEY=VALUE (message fit for one line)."""


def parse_label(text: str) -> tuple[str, str]:
    """'road=sand' -> ('road', 'sand'). KEY: letters, digits, '_', '.', '-'; VALUE: any text (may be empty)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not _KEY.match(key):
        raise LabelError(f"label {text!r}: expected KEY=VALUE with KEY of letters, digits, '_', '.', '-'")
    return key, value.strip()


def parse_labels(texts: list[str] | None) -> dict[str, str]:
    """Several KEY=VALUE texts -> {KEY: VALUE}; a key given twice is an error."""
    out: dict[str, str] = {}
    for text in texts or []:
        key, value = parse_label(text)
        if key in out:
            raise LabelError(f"label {key!r} given twice")
        out[key] = value
    return out


def labels_metadata(labels: dict[str, str]) -> dict[str, str]:
    """{KEY: VALUE} -> the metadata entries {'label.KEY': VALUE}."""
    return {LABEL_PREFIX + k: v for k, v in labels.items()}


def labels_of(metadata: dict[str, str]) -> dict[str, str]:
    """The labels stored in a log's metadata (plus road and maneuver of a demo log), sorted by key."""
    labels = {k[len(LABEL_PREFIX):]: v for k, v in metadata.items() if k.startswith(LABEL_PREFIX)}
    for key, demo_key in _DEMO_KEYS.items():
        if key not in labels and metadata.get(demo_key):
            labels[key] = metadata[demo_key]
    return dict(sorted(labels.items()))


def format_labels(labels: dict[str, str]) -> str:
    """'road=sand, maneuver=brake' ('' when there are none)."""
    return ", ".join(f"{k}={v}" for k, v in labels.items())
