"""The package's import structure: entry points are leaves, no two modules need each other, and
every module sits in one layer of docs/architecture.md and imports nothing from a layer above.

Imports are read with ``ast`` from every .py under mitsvbrdf/, at module level and inside
functions alike (a function-local import hides a cycle, it does not remove it). Only imports
between mitsvbrdf modules count; ``from . import x`` is an import of the module ``x`` when
``x`` is a module, else of the package.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "mitsvbrdf"

#: Command-line front ends: they may import anything, and nothing but each other imports them.
ENTRY_POINTS = {"mitsvbrdf.cli", "mitsvbrdf.demo", "mitsvbrdf.capture.cli", "mitsvbrdf.__main__",
                "mitsvbrdf.nets.__main__"}

#: The layers of docs/architecture.md, lowest first. A module may import from its own layer and the
#: ones below. A name stands for a module or a whole subpackage; the longest matching name decides.
#: "" is the package itself (``mitsvbrdf``, the public API), which re-exports up to the method layer.
LAYERS = {
    "foundation": ["errors", "checks", "imageio", "backend", "scene_xml"],
    "physics": ["brdf", "rig", "svbrdf", "patterns", "sensor"],
    "renderers": ["render", "relight"],
    "method": ["importance", "separation", "nets", "losses", "resolution", "acquisition", "training", "data", ""],
    "applications": ["evaluation", "metrics", "viewing", "export", "data.preview", "data.encoding", "capture", "cli", "demo",
                     "__main__", "nets.__main__"],
}
#: The Mitsuba plugins (package mitsvbrdf_plugins, folder plugins/) belong to the renderers.
PLUGINS = Path(__file__).resolve().parent.parent / "plugins"


def layer_of(module: str) -> int | None:
    """Index in LAYERS of a dotted module name of the package (None: in no layer)."""
    rel = module.partition(".")[2]
    best, found = -1, None
    for k, names in enumerate(LAYERS.values()):
        for name in names:
            if (rel == name or (name and rel.startswith(name + "."))) and len(name) > best:
                best, found = len(name), k
    return found


def module_files(package: Path = PACKAGE) -> dict[str, Path]:
    """{dotted module name: file} for every module of ``package`` (a package is its __init__)."""
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _is_package(name: str, files: dict[str, Path]) -> bool:
    return files[name].name == "__init__.py"


def _resolve(name: str, files: dict[str, Path]) -> str | None:
    """The package module a dotted name lives in (its longest prefix that is a module)."""
    parts = name.split(".")
    while parts:
        if ".".join(parts) in files:
            return ".".join(parts)
        parts.pop()
    return None


def _type_checking_only(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    while node in parents:
        node = parents[node]
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            return True
    return False


def imports_of(module: str, files: dict[str, Path]) -> set[str]:
    """The package modules that ``module`` imports anywhere in its file."""
    tree = ast.parse(files[module].read_text())
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    package = module if _is_package(module, files) else module.rpartition(".")[0]
    out = set()
    for node in ast.walk(tree):
        if not isinstance(node, (ast.Import, ast.ImportFrom)) or _type_checking_only(node, parents):
            continue
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            # `from base import x`: the module base.x when it is one, else base itself
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
        for t in targets:
            r = _resolve(t, files)
            if r is not None and r != module:
                out.add(r)
    return out


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """{module: the package modules it imports} for every module of ``package``."""
    files = module_files(package)
    return {m: imports_of(m, files) for m in files}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_reader_sees_relative_absolute_and_function_level_imports(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from .a import f\n",
        "a.py": "import os\n\ndef f():\n    from .sub import b\n    from . import c\n",
        "c.py": "from pkg.sub.b import g\n",
        "sub/__init__.py": "",
        "sub/b.py": "from .. import a\nfrom ..c import x\nfrom . import g\n",
        "sub/d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..a import f\n",
    }
    for name, text in files.items():
        (pkg / name).write_text(text)
    graph = import_graph(pkg)
    assert graph["pkg"] == {"pkg.a"}
    assert graph["pkg.a"] == {"pkg.sub.b", "pkg.c"}       # inside a function; `from . import c` is the module
    assert graph["pkg.c"] == {"pkg.sub.b"}
    assert graph["pkg.sub.b"] == {"pkg.a", "pkg.c", "pkg.sub"}  # `g` is no module: the package
    assert graph["pkg.sub.d"] == set()                     # annotations only
    assert cycles(graph) == [["pkg.a", "pkg.c", "pkg.sub.b"]]


def test_every_entry_point_exists():
    assert set(import_graph()) >= ENTRY_POINTS


def test_no_library_module_imports_an_entry_point():
    graph = import_graph()
    bad = {m: sorted(deps & ENTRY_POINTS) for m, deps in graph.items() if m not in ENTRY_POINTS and deps & ENTRY_POINTS}
    assert not bad, f"library modules importing command-line front ends: {bad}"


def test_the_import_graph_has_no_cycle():
    assert cycles(import_graph()) == []


def test_every_module_sits_in_a_layer():
    assert [m for m in import_graph() if layer_of(m) is None] == []


def test_no_module_imports_from_a_layer_above_its_own():
    names = list(LAYERS)
    bad = [f"{m} ({names[layer_of(m)]}) imports {d} ({names[layer_of(d)]})"
           for m, deps in import_graph().items() for d in deps if layer_of(d) > layer_of(m)]
    assert bad == []


def test_the_plugins_import_only_foundation_physics_and_renderers():
    files = module_files()
    used = set()
    for path in PLUGINS.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith("mitsvbrdf"):
                used.add(_resolve(node.module, files))
            elif isinstance(node, ast.Import):
                used |= {_resolve(a.name, files) for a in node.names if a.name.startswith("mitsvbrdf.")}
    assert used and max(layer_of(m) for m in used) <= list(LAYERS).index("renderers")


def test_docs_architecture_names_every_layer_entry():
    text = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    missing = [n for names in LAYERS.values() for n in names if n and f"`{n}`" not in text]
    assert missing == []
