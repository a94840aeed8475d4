"""The house's import rule (docs/ARCHITECTURE.md): every import goes down the layers, and no file imports itself back.

Layers, bottom up: core (stereo_recon.core) < calib, measure < reconstruction (stereo_recon.*) < synthetic < app.
An AST walk over every project file (imports inside functions count too); no dependency beyond the standard library.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("stereo_recon", "calib", "measure")

# Which layers each layer may import (its own included).
ALLOWED = {
    "core": {"core"},
    "calib": {"core", "calib"},
    "measure": {"core", "measure"},
    "reconstruction": {"core", "calib", "reconstruction"},
    "synthetic": {"core", "calib", "measure", "reconstruction", "synthetic"},
    "app": {"core", "calib", "measure", "reconstruction", "synthetic", "app"},
}


def layer(module: str) -> str:
    """The layer of a project module (dotted name)."""
    parts = module.split(".")
    if parts[0] in ("calib", "measure"):
        return parts[0]
    if len(parts) == 1 or parts[1] == "core":   # the bare package holds only __version__
        return "core"
    if parts[1] in ("app", "synthetic"):
        return parts[1]
    return "reconstruction"


def module_name(path: Path, root: Path) -> str:
    """Dotted module name of a .py file under ``root`` (a package's __init__ is the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_imports(tree: ast.AST, modules: set[str]) -> list[tuple[int, str]]:
    """(line, imported project module) for every import in a file, resolved to the longest known module name."""
    out = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            # ``from pkg import mod`` imports pkg.mod when that is a module, else a name of pkg
            names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in modules else node.module for a in node.names]
        for name in names:
            if name.split(".")[0] not in PACKAGES:
                continue
            while name not in modules and "." in name:
                name = name.rsplit(".", 1)[0]
            out.append((node.lineno, name))
    return out


def import_graph(root: Path = REPO) -> dict[str, dict[str, int]]:
    """{module: {imported module: line}} over the project's packages under ``root``."""
    files = {module_name(p, root): p for pkg in PACKAGES for p in (root / pkg).rglob("*.py")}
    graph: dict[str, dict[str, int]] = {}
    for mod, path in files.items():
        edges: dict[str, int] = {}
        for line, target in project_imports(ast.parse(path.read_text(encoding="utf-8")), set(files)):
            if target != mod:
                edges.setdefault(target, line)
        graph[mod] = edges
    return graph


def upward_imports(graph: dict[str, dict[str, int]]) -> list[str]:
    """Every import that goes up a layer (or sideways between calib and measure), as 'module:line -> target'."""
    return [f"{m}:{line} ({layer(m)}) imports {t} ({layer(t)})" for m, edges in sorted(graph.items())
            for t, line in sorted(edges.items()) if layer(t) not in ALLOWED[layer(m)]]


def cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan): each is an import cycle."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_goes_up_a_layer():
    bad = upward_imports(import_graph())
    assert not bad, "imports against the layers (docs/ARCHITECTURE.md):\n" + "\n".join(bad)


def test_no_file_import_cycle():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_check_catches_a_planted_violation(tmp_path):
    # A copy of the rule's view of a tiny tree: core importing the app, and two measure files importing each other.
    for rel, text in {"stereo_recon/__init__.py": "", "stereo_recon/core/__init__.py": "",
                      "stereo_recon/core/errors.py": "from stereo_recon.app import cli\n",
                      "stereo_recon/app/__init__.py": "", "stereo_recon/app/cli.py": "import stereo_recon.core.errors\n",
                      "calib/__init__.py": "", "measure/__init__.py": "",
                      "measure/a.py": "def f():\n    from measure import b\n", "measure/b.py": "from measure.a import f\n"}.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    graph = import_graph(tmp_path)
    assert upward_imports(graph) == ["stereo_recon.core.errors:1 (core) imports stereo_recon.app.cli (app)"]
    assert sorted(cycles(graph)) == [["measure.a", "measure.b"], ["stereo_recon.app.cli", "stereo_recon.core.errors"]]
