"""MkDocs hook: the references the code declares, rendered into the pages at build time, never written twice.

A page holds a marker, `<!-- slipdaq:NAME -->`, and the build puts in its place:
    config-reference  every config key: section, type, default, range, description (the pydantic models, config/)
    commands          every verb and flag with its help (the argument parser, cli/)
    topics            every topic of the log: encoding, schema, fields (logformat/registry.py, schemas.py)
    csv-columns       every CSV column of `export` (export/csv_file.py, records/columns.py)

The sources are this checkout's (src/ first on the path), so the site describes the code beside it.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import types
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

SRC = Path(__file__).resolve().parents[2] / "src"
if str(SRC) not in sys.path:
    sys.path.insert(0, str(SRC))

MARKER = re.compile(r"<!-- slipdaq:([a-z-]+) -->")


def cell(text: object) -> str:
    """Text for a Markdown table cell: one line, `|` and emphasis characters escaped."""
    s = " ".join(str(text).split())
    return s.replace("\\", "\\\\").replace("|", "\\|").replace("*", "\\*").replace("<", "&lt;")


# --- configuration ---------------------------------------------------------------------------------------------

def _type_name(t: Any) -> str:
    origin = typing.get_origin(t)
    args = typing.get_args(t)
    if origin is typing.Literal:
        return " \\| ".join(json.dumps(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        names = [_type_name(a) for a in args if a is not type(None)]
        return " \\| ".join(names) + (" (optional)" if type(None) in args else "")
    if origin is list:
        return f"list of {_type_name(args[0])}"
    return {float: "number", int: "integer", str: "text", bool: "true \\| false"}.get(t, getattr(t, "__name__", str(t)))


def _default(v: Any) -> str:
    if v is None:
        return "unset"
    if isinstance(v, bool):
        return "`true`" if v else "`false`"
    return f"`{json.dumps(v)}`"


_BOUNDS = {"gt": ">", "ge": "≥", "lt": "<", "le": "≤", "min_length": "length ≥"}


def _range(field: Any) -> str:
    out = []
    for m in field.metadata:
        for name, sign in _BOUNDS.items():
            value = getattr(m, name, None)
            if value is not None:
                out.append(f"{sign} {value}")
    return ", ".join(out)


def _model_doc(model: type) -> str:
    doc = model.__dict__.get("__doc__") or ""
    return " ".join(doc.split())


def config_keys() -> Iterator[tuple[str, type, list[tuple[str, Any]]]]:
    """(section name, its model, [(dotted key, field)]) for every section of the config, in declaration order."""
    from pydantic import BaseModel

    from slipdaq.config import Config

    for name, field in Config.model_fields.items():
        if field.exclude:
            continue
        model = field.annotation
        section = name
        if typing.get_origin(model) is dict:  # [wheels.W]: one table per wheel
            model = typing.get_args(model)[1]
            section = "wheels.W"
        assert isinstance(model, type) and issubclass(model, BaseModel)
        yield section, model, [(f"{section}.{k}", f) for k, f in model.model_fields.items()]
        for k, f in model.model_fields.items():  # [[section.k]]: a list of tables (test.procedure)
            item = typing.get_args(f.annotation)[0] if typing.get_origin(f.annotation) is list else None
            if isinstance(item, type) and issubclass(item, BaseModel):
                yield f"[{section}.{k}]", item, [(f"{section}.{k}.{n}", g) for n, g in item.model_fields.items()]


def render_config() -> str:
    from slipdaq import WHEELS
    from slipdaq.config import Config

    lines = []
    for section, model, keys in config_keys():
        lines.append(f"### `[{section}]`\n")
        doc = _model_doc(model) or (Config.model_fields[section.strip("[").split(".")[0]].description or "")
        if section == "wheels.W":
            doc += f" W is one of {', '.join(WHEELS)}."
        if doc:
            lines.append(doc.strip() + "\n")
        lines.append("| key | type | default | range | description |\n|---|---|---|---|---|")
        for key, f in keys:
            default = "required" if f.is_required() else _default(f.default)
            lines.append(f"| `{key}` | {_type_name(f.annotation)} | {default} | {cell(_range(f))} | "
                         f"{cell(f.description or '')} |")
        lines.append("")
    return "\n".join(lines)


# --- commands --------------------------------------------------------------------------------------------------

def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def verbs() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """("run", its parser), ..., ("calibration show", ...): every verb and sub-verb of the command line."""
    from slipdaq.cli import build_parser

    def walk(prefix: str, parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser]]:
        for name, sub in _subparsers(parser).items():
            path = f"{prefix} {name}".strip()
            yield path, sub
            yield from walk(path, sub)

    yield from walk("", build_parser())


def flags(parser: argparse.ArgumentParser) -> Iterator[argparse.Action]:
    for action in parser._actions:
        if not isinstance(action, argparse._SubParsersAction) and action.help is not argparse.SUPPRESS:
            yield action


def _flag_rows(parser: argparse.ArgumentParser) -> list[str]:
    formatter = parser._get_formatter()
    rows = ["| option | value | help |\n|---|---|---|"]
    for a in flags(parser):
        name = ", ".join(f"`{o}`" for o in a.option_strings) or f"`{a.metavar or a.dest}`"
        if a.nargs == 0:
            value = ""
        elif a.choices:
            value = " \\| ".join(f"`{c}`" for c in a.choices)
        else:
            value = f"`{a.metavar or a.dest.upper()}`" if a.option_strings else ""
        if a.nargs in ("+", "*"):
            value += " ..."
        text = formatter._expand_help(a) if a.help else ""
        if a.required and a.option_strings:
            text = "required. " + text
        if a.default not in (None, False, argparse.SUPPRESS) and "default" not in text:
            text += f" (default: {a.default})"
        rows.append(f"| {name} | {value} | {cell(text)} |")
    return rows


def render_commands() -> str:
    from slipdaq.cli import build_parser

    top = build_parser()
    lines = [f"`slipdaq [-h] [--version] [-v] VERB ...`: {cell(top.description or '')}\n", *_flag_rows(top),
             "", cell(top.epilog or ""), ""]
    for path, parser in verbs():
        lines.append(f"### `slipdaq {path}`\n")
        usage = parser.format_usage().removeprefix("usage: ").strip()
        lines.append("```text\n" + usage + "\n```\n")
        description = parser.description or ""
        if isinstance(parser.formatter_class, type) and issubclass(parser.formatter_class,
                                                                   argparse.RawDescriptionHelpFormatter):
            lines.append("```text\n" + description + "\n```\n")
        elif description:
            lines.append(description.replace("*", "\\*") + "\n")
        lines += _flag_rows(parser)
        lines.append("")
    return "\n".join(lines)


# --- the log's topics ------------------------------------------------------------------------------------------

def _json_type(prop: dict[str, Any]) -> str:
    if "enum" in prop:
        return " \\| ".join(f"`{v}`" for v in prop["enum"])
    if "oneOf" in prop:
        return " \\| ".join(f"{o['const']} {o['title']}" for o in prop["oneOf"])
    t = prop.get("type", "object")
    t = " or ".join(t) if isinstance(t, list) else t
    if t == "array" and "items" in prop:
        return f"array of {_json_type(prop['items'])}"
    return t


def schema_fields(schema: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, dict[str, Any], bool]]:
    """(dotted field name, its schema, required) of a JSON Schema, nested objects' fields after their own."""
    required = set(schema.get("required", ()))
    for name, prop in schema.get("properties", {}).items():
        yield prefix + name, prop, name in required
        if prop.get("type") == "object" and "properties" in prop:
            yield from schema_fields(prop, f"{prefix}{name}.")


_ROS2_FIELD = re.compile(r"^\s*([\w/\[\]<=]+)\s+(\w+)\s*$")


def ros2_fields(text: str) -> Iterator[tuple[str, str]]:
    """(type, name) of each field line of a ros2msg schema text (its own and its nested messages')."""
    for line in text.splitlines():
        m = _ROS2_FIELD.match(line.split("#")[0])
        if m and not line.startswith("MSG:") and not line.startswith("="):
            yield m.group(1), m.group(2)


def render_topics() -> str:
    from slipdaq.logformat.registry import TOPIC_FORMATS

    lines = ["| topic | message encoding | schema |\n|---|---|---|"]
    lines += [f"| [`{t}`](#{_anchor(t)}) | {f.message_encoding} | `{f.schema_name}` ({f.schema_encoding}) |"
              for t, f in TOPIC_FORMATS.items()]
    lines.append("")
    for topic, fmt in TOPIC_FORMATS.items():
        lines.append(f"### `{topic}` {{#{_anchor(topic)}}}\n")
        if fmt.schema_encoding == "ros2msg":
            lines.append(f"CDR messages, schema `{fmt.schema_name}` (ros2msg):\n")
            lines.append("```text\n" + fmt.schema_data.decode().strip() + "\n```\n")
            continue
        schema = json.loads(fmt.schema_data)
        lines.append(f"JSON messages, schema `{fmt.schema_name}` (JSON Schema)"
                     + (f": {cell(schema['description'])}" if schema.get("description") else "") + "\n")
        lines.append("| field | type | always there | description |\n|---|---|---|---|")
        for name, prop, required in schema_fields(schema):
            lines.append(f"| `{name}` | {_json_type(prop)} | {'yes' if required else 'no'} | "
                         f"{cell(prop.get('description', ''))} |")
        lines.append("")
    return "\n".join(lines)


def _anchor(topic: str) -> str:
    return "topic" + topic.replace("/", "-")


# --- CSV columns -----------------------------------------------------------------------------------------------

def csv_files() -> list[tuple[str, tuple[str, ...], dict[str, tuple[str, str, str]]]]:
    """(the export flag, its columns in order, {column: (kind, description, class)}) of every CSV `export` writes."""
    from slipdaq import WHEELS
    from slipdaq.export import csv_file
    from slipdaq.maneuver.record import MANEUVER_COLUMNS
    from slipdaq.maneuver.test_set import TEST_SET_COLUMNS, TEST_SET_CSV_COLUMNS
    from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS

    def described(groups: Any) -> dict[str, tuple[str, str, str]]:
        out = {}
        for g in groups:
            for w in WHEELS if g.per_wheel else ("",):
                for c in g.columns:
                    kind = " \\| ".join(f"`{v}`" for v in c.values) if c.kind == "enum" else \
                        c.kind.replace("?", " or empty")
                    out[c.key(w) if g.per_wheel else c.name] = (kind, c.describe(w), g.csv)
        return out

    estimates = described(ESTIMATE_COLUMNS)
    return [
        ("--csv", csv_file.ALL_COLUMNS, estimates),
        ("--fast-csv", csv_file.FAST_COLUMNS, described(FAST_SLIP_COLUMNS)),
        ("--maneuvers-csv", csv_file.MANEUVER_CSV_COLUMNS, described(MANEUVER_COLUMNS)),
        ("--sets-csv", TEST_SET_CSV_COLUMNS, described(TEST_SET_COLUMNS)),
        ("--imu-csv", csv_file.IMU_CSV_COLUMNS, {"time_s": ("number", "the sample's time, seconds in the log's clock",
                                                            "contract"),
                                                 "accel_mps2": ("number", "the forward acceleration the estimator "
                                                                "took from the IMU", "contract")}),
    ]


def render_csv() -> str:
    lines = []
    for flag, columns, described in csv_files():
        lines.append(f"### `export {flag}`\n")
        lines.append("| # | column | kind | description |\n|---|---|---|---|")
        for i, name in enumerate(columns, 1):
            kind, text, klass = described.get(name, ("", "", ""))
            after = " (appended after the contract's columns)" if klass == "extra" else ""
            lines.append(f"| {i} | `{name}` | {kind} | {cell(text + after)} |")
        lines.append("")
    return "\n".join(lines)


RENDERERS: dict[str, Callable[[], str]] = {
    "config-reference": render_config,
    "commands": render_commands,
    "topics": render_topics,
    "csv-columns": render_csv,
}


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """mkdocs hook: each marker replaced by its generated reference; an unknown marker stops the build."""

    def replace(m: re.Match[str]) -> str:
        name = m.group(1)
        if name not in RENDERERS:
            raise ValueError(f"{page.file.src_path}: unknown marker <!-- slipdaq:{name} -->")
        return RENDERERS[name]()

    return MARKER.sub(replace, markdown)
