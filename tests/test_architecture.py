"""docs/architecture.md against the tree: the packages it names, the import layers, the sizes of rooms."""

from __future__ import annotations

import ast
import re
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "slipdaq"
PAGE = (ROOT / "docs" / "architecture.md").read_text()
MAX_TOP_MODULES = 6
MAX_MODULE_LINES = 500
MAX_CLASS_LINES = 250


def _packages() -> set[str]:
    return {p.name for p in SRC.iterdir() if p.is_dir() and p.name != "__pycache__" and not p.name.startswith(".")}


def _named_packages() -> set[str]:
    table = PAGE[PAGE.index("## Packages and what each owns"):PAGE.index("## Who imports whom")]
    return set(re.findall(r"^\| `(\w+)/` \|", table, re.M))


def _layers() -> list[set[str]]:
    block = PAGE[PAGE.index("<!-- layers -->"):]
    body = block[block.index("```") + 3:]
    return [set(line.split()) for line in body[:body.index("```")].strip().splitlines()]


def _unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "slipdaq"


def _imports() -> dict[str, set[str]]:
    """Package (or top module) -> the packages and top modules of slipdaq it imports."""
    graph: dict[str, set[str]] = defaultdict(set)
    for path in SRC.rglob("*.py"):
        rel = path.relative_to(SRC.parent).with_suffix("").parts
        here = rel[1] if len(rel) > 1 else "slipdaq"
        here = here if here != "__init__" else "slipdaq"
        for node in ast.walk(ast.parse(path.read_text())):
            names: list[str] = []
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "slipdaq":
                names = [node.module] if node.module != "slipdaq" else [f"slipdaq.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names if a.name.split(".")[0] == "slipdaq"]
            for name in names:
                there = _unit(name)
                there = there if (SRC / there).is_dir() or (SRC / f"{there}.py").exists() else "slipdaq"
                if there not in (here, "slipdaq", "__main__"):
                    graph[here].add(there)
    return graph


def test_every_package_is_named_and_every_named_package_exists() -> None:
    assert _named_packages() == _packages()


def test_the_top_floor_holds_few_modules() -> None:
    modules = sorted(p.name for p in SRC.glob("*.py") if p.name != "__init__.py")
    assert len(modules) <= MAX_TOP_MODULES, modules


def test_imports_point_down_the_layers() -> None:
    layers = _layers()
    level = {name.removesuffix(".py"): i for i, names in enumerate(layers) for name in names}
    units = _packages() | {p.stem for p in SRC.glob("*.py") if p.stem not in ("__init__", "__main__")}
    assert units - {"data"} <= set(level), f"not in the layers: {sorted(units - {'data'} - set(level))}"
    upward = [(a, b) for a, bs in _imports().items() for b in bs if a != "__main__" and level[b] <= level[a]]
    assert not upward, f"imports that do not point down: {sorted(upward)}"


def test_no_module_or_class_over_its_size_unless_the_page_says_why() -> None:
    sizes = PAGE[PAGE.index("## Sizes"):]
    over: list[str] = []
    for path in SRC.rglob("*.py"):
        text = path.read_text()
        if text.count("\n") > MAX_MODULE_LINES:
            over.append(f"{path.relative_to(SRC)}: {text.count(chr(10))} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef) and (node.end_lineno or 0) - node.lineno + 1 > MAX_CLASS_LINES:
                if f"`{node.name}`" not in sizes:
                    over.append(f"{path.relative_to(SRC)}: class {node.name}")
    assert not over, over


@pytest.mark.parametrize("module", ["pipeline", "sinks", "estimator", "maneuver"])
def test_the_layers_have_teeth(module: str) -> None:
    """The check above would see an import that points up: every one of these imports something below it."""
    assert _imports()[module]
