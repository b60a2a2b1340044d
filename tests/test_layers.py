"""The import rule of docs/design.md: no module imports from a layer below it in the layer table.

The table is read from docs/design.md itself, so the document and the code cannot drift apart:
every module of resti_lib must be listed, every import (module level or inside a function) must go
to the module's own layer or a layer above it in the table, the module-level imports have no
cycle, and only the run layer imports the mini-world generator.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from resti_lib import paths

PKG = paths.ROOT / "resti_lib"


def _layers() -> list[tuple[str, list[str]]]:
    text = (paths.ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    section = text.split("## Layers", 1)[1].split("\n## ", 1)[0]
    out = []
    for line in section.splitlines():
        m = re.match(r"^\|\s*([a-z]+)\s*\|([^|]*)\|", line)
        if m and m.group(1) != "layer":
            out.append((m.group(1), re.findall(r"`([^`]+)`", m.group(2))))
    return out


def _modules() -> dict[str, Path]:
    mods = {}
    for f in sorted(PKG.rglob("*.py")):
        parts = f.relative_to(paths.ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        mods[name] = f
    return mods


def _layer_of(name: str, layers) -> int | None:
    short = name[len("resti_lib."):] if name != "resti_lib" else "resti_lib"
    for i, (_, pats) in enumerate(layers):
        for p in pats:
            if short == p or (p.endswith(".*") and (short == p[:-2] or short.startswith(p[:-1]))):
                return i
    return None


def _imports(name: str, f: Path, mods: dict, *, module_level_only: bool = False) -> set[str]:
    tree = ast.parse(f.read_text(encoding="utf-8"))
    nodes = tree.body if module_level_only else list(ast.walk(tree))
    pkg = name if f.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            targets = [target] + [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in mods]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            continue
        for t in targets:
            if not t.startswith("resti_lib"):
                continue
            while t not in mods and "." in t:
                t = t.rsplit(".", 1)[0]
            if t != name:
                out.add(t)
    return out


def test_every_module_is_in_the_layer_table():
    layers = _layers()
    assert [n for n, _ in layers][:3] == ["base", "io", "geometry"]
    missing = sorted(m for m in _modules() if _layer_of(m, layers) is None)
    assert missing == [], "add these modules to the layer table of docs/design.md"


def test_no_import_goes_down_the_table():
    layers, mods = _layers(), _modules()
    bad = []
    for name, f in mods.items():
        mine = _layer_of(name, layers)
        for dep in _imports(name, f, mods):
            theirs = _layer_of(dep, layers)
            if theirs is not None and mine is not None and theirs > mine:
                bad.append(f"{name} ({layers[mine][0]}) imports {dep} ({layers[theirs][0]})")
    assert bad == []


def test_module_level_imports_have_no_cycle():
    mods = _modules()
    graph = {n: _imports(n, f, mods, module_level_only=True) for n, f in mods.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(n, stack):
        state[n] = 1
        for d in sorted(graph.get(n, ())):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d, stack + [d])
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n, [n])
    assert cycles == []


@pytest.mark.parametrize("forbidden, allowed", [("resti_lib.synth", ("run", "synth"))])
def test_the_audit_path_never_imports_the_generator(forbidden, allowed):
    layers, mods = _layers(), _modules()
    bad = [n for n, f in mods.items() if layers[_layer_of(n, layers)][0] not in allowed
           and any(d == forbidden or d.startswith(forbidden + ".") for d in _imports(n, f, mods))]
    assert bad == []


def test_measure_imports_no_task():
    mods = _modules()
    bad = [(n, d) for n, f in mods.items() if n.startswith("resti_lib.measure")
           for d in _imports(n, f, mods) if d.startswith("resti_lib.tasks")]
    assert bad == []
    text = "".join(f.read_text() for n, f in mods.items() if n.startswith("resti_lib.measure"))
    assert "pkgutil" not in text and "import_module" not in text
