"""The docs site: built strict once (mkdocs, the `docs` extra), every declared config key, verb, flag, topic, field and
CSV column is in the built pages, and no page cites an issue or a commit (the pages are a reference; history is in
the commit messages and CHANGELOG.md)."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import typing
from html.parser import HTMLParser
from pathlib import Path

import pytest
from pydantic import BaseModel

from slipdaq.cli import build_parser
from slipdaq.config import Config
from slipdaq.export import csv_file
from slipdaq.logformat.registry import TOPIC_FORMATS
from support.paths import ROOT


class _Text(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.parts: list[str] = []

    def handle_data(self, data: str) -> None:
        self.parts.append(data)


def page_text(site: Path, page: str) -> str:
    parser = _Text()
    parser.feed((site / page / "index.html").read_text(encoding="utf-8"))
    return " ".join(parser.parts)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("mkdocs", reason="the docs toolchain is not installed: pip install -e '.[docs]'")
    pytest.importorskip("material", reason="mkdocs-material is not installed: pip install -e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    env = os.environ | {"NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT / "src")}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
                          "--site-dir", str(out)], capture_output=True, text=True, env=env, cwd=ROOT)
    warnings = [line for line in run.stderr.splitlines() if line.startswith(("WARNING", "ERROR"))]
    assert run.returncode == 0 and not warnings, run.stderr[-3000:]
    return out


def config_keys() -> list[str]:
    """Every key of the config as `section.key` (`wheels.W.key` for the per-wheel tables), from the models."""
    keys = []
    for name, field in Config.model_fields.items():
        if field.exclude:
            continue
        model, section = field.annotation, name
        if typing.get_origin(model) is dict:
            model, section = typing.get_args(model)[1], f"{name}.W"
        assert isinstance(model, type) and issubclass(model, BaseModel)
        keys += [f"{section}.{key}" for key in model.model_fields]
    return keys


@pytest.mark.slow  # builds the site (about 10 s)
def test_every_config_key_is_in_the_configuration_page(site: Path) -> None:
    text = page_text(site, "configuration")
    keys = config_keys()
    assert len(keys) > 60
    assert [k for k in keys if k not in text] == []
    assert "[vehicle]" in text and "1300.0" in text and "≤ 1" in text  # a section, a default, a range


def verbs(parser: argparse.ArgumentParser, prefix: str = "") -> list[tuple[str, argparse.ArgumentParser]]:
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.append((f"{prefix}{name}", sub))
                found += verbs(sub, f"{prefix}{name} ")
    return found


@pytest.mark.slow  # builds the site (about 10 s)
def test_every_verb_and_flag_is_in_the_commands_page(site: Path) -> None:
    text = page_text(site, "commands")
    every = verbs(build_parser())
    assert {"run", "demo", "import", "replay", "export", "recover", "report", "batch", "calibration show"} \
        <= {v for v, _ in every}
    missing = [f"slipdaq {v}" for v, _ in every if f"slipdaq {v}" not in text]
    for verb, parser in every:
        section = text[text.index(f"slipdaq {verb} "):]
        missing += [f"{verb} {o}" for a in parser._actions for o in a.option_strings if o not in section]
        missing += [f"{verb} {a.help}" for a in parser._actions
                    if a.help and a.option_strings and " ".join(a.help.split())[:40] not in section]
    assert missing == []


@pytest.mark.slow  # builds the site (about 10 s)
def test_every_topic_and_field_is_in_the_log_page(site: Path) -> None:
    text = page_text(site, "log")
    import json

    missing = [t for t in TOPIC_FORMATS if t not in text]
    for fmt in TOPIC_FORMATS.values():
        if fmt.schema_encoding == "jsonschema":
            fields = json.loads(fmt.schema_data)["properties"]
        else:
            fields = {m.group(1) for m in re.finditer(r"^\S+\s+(\w+)", fmt.schema_data.decode(), re.M)}
        missing += [f"{fmt.topic} {f}" for f in fields if f not in text]
        missing += [] if fmt.schema_name in text else [fmt.schema_name]
    assert "slip_RR" in text and "live_dropped_messages" in text
    assert missing == []


@pytest.mark.slow  # builds the site (about 10 s)
def test_every_csv_column_is_in_the_log_page(site: Path) -> None:
    text = page_text(site, "log")
    every = csv_file.ALL_COLUMNS + csv_file.FAST_COLUMNS + csv_file.MANEUVER_CSV_COLUMNS + csv_file.IMU_CSV_COLUMNS
    assert len(every) > 100
    assert [c for c in every if c not in text] == []
    for flag in ("export --csv", "export --fast-csv", "export --maneuvers-csv", "export --imu-csv"):
        assert flag in text


@pytest.mark.slow  # builds the site (about 10 s)
def test_the_site_has_every_page_of_the_nav(site: Path) -> None:
    for page in ("tutorial", "inputs", "live-view", "maneuvers", "report", "batch", "service", "method", "accuracy",
                 "performance", "reliability", "architecture", "real-data"):
        assert (site / page / "index.html").is_file(), page
    assert (site / "index.html").is_file()


ISSUE = re.compile(r"\bissues? \d+|\(issue\b|(?<![\w&/])#\d+\b", re.IGNORECASE)
HEX_WORD = re.compile(r"(?<![\w-])[0-9a-f]{7,40}(?![\w-])")
CODE_SPAN = re.compile(r"`[^`]+`")


def references(text: str) -> list[str]:
    """The issue numbers and commit hashes a page cites: `issue 12`, `(issue`, `#12` (outside inline code: a
    maneuver's name `brake #2` is output), a word of 7 to 40 hex digits with a digit and a letter in it, or one
    that git resolves to an object (outside file paths in inline code: `tests/data/...`)."""
    found = [m.group(0) for m in ISSUE.finditer(CODE_SPAN.sub("", text))]
    no_paths = CODE_SPAN.sub(lambda m: "" if "/" in m.group(0) or "." in m.group(0) else m.group(0), text)
    for m in HEX_WORD.finditer(no_paths):
        word = m.group(0)
        hashlike = re.search(r"\d", word) and re.search(r"[a-f]", word)
        if hashlike or subprocess.run(["git", "-C", str(ROOT), "cat-file", "-e", f"{word}^{{commit}}"],
                                      capture_output=True).returncode == 0:
            found.append(word)
    return found


def test_the_reference_check_finds_issues_and_commits() -> None:
    assert references("as issue 14 asked (issue 7), see #12") == ["issue 14", "(issue", "#12"]
    assert references("the base c3685c0 against 5578e03ab") == ["c3685c0", "5578e03ab"]
    assert references("brake `60-0 km/h #2`, 3129988 bytes, 0x1D0, `tests/data/slipdaq-6641212`, deadbeef") == []


@pytest.mark.parametrize("page", sorted(p.relative_to(ROOT).as_posix()
                                        for p in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]))
def test_no_page_cites_an_issue_or_a_commit(page: str) -> None:
    assert references((ROOT / page).read_text(encoding="utf-8")) == []


def test_a_benchmark_writes_no_commit_into_a_page() -> None:
    """The benchmarks' tables go into the pages without the commits they were measured at (`--base REV` stays)."""
    from benchmarks.doc_block import without_revisions

    text = "base 56f1e07 against d9059f7 + working tree; 1.12x of 171396 frames/s; --base REV; cafe"
    assert without_revisions(text) == "base REV against REV + working tree; 1.12x of 171396 frames/s; --base REV; cafe"
    assert not any(HEX_WORD.finditer(without_revisions(text).replace("171396", "")))
