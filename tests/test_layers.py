"""The folders are the layers: the rules of the package's structure, computed from the code itself.

Every module's imports are read from its source: every ``import`` statement (at the top, inside
functions, under ``TYPE_CHECKING``), a module named by its whole dotted name in a string (a verb table,
``importlib.import_module``), and the tables of :func:`lidarpkt.core.lazy.lazy_names`. Each is resolved to
the module of this tree that it loads. No list of modules is kept here: a layer is a folder.
"""

from __future__ import annotations

import ast
from collections import defaultdict, deque
from dataclasses import dataclass
from pathlib import Path

import pytest

PACKAGE_ROOT = Path(__file__).resolve().parents[1] / "lidarpkt"
MAX_LINES = 500

#: rank of each folder (or top-level module) of lidarpkt/: a module imports nothing of a higher rank
RANKS: dict[str, int] = {
    "core": 0, "errors.py": 0, "_version.py": 0,
    "containers": 1,
    "vendors": 2,
    "pipeline": 3,
    "writers": 4,
    "recorder": 5, "view": 5, "archive": 5, "analysis": 5, "fixtures": 5,
    "cli": 6,
    "__init__.py": 7, "__main__.py": 7,
}
#: modules of the package that are no Python source (the optional compiled kernels)
COMPILED = {"_native"}


@dataclass(frozen=True)
class Import:
    """One import of ``target`` by ``source`` at ``line`` (dotted module names)."""

    source: str
    target: str
    line: int

    def __str__(self) -> str:
        return f"{self.source} (line {self.line}) imports {self.target}"


def module_files(root: Path) -> dict[str, Path]:
    """Dotted module name -> source file, for every ``.py`` under ``root`` (a package's ``__init__.py``
    is the package)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = (root.name,) + path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _package_of(module: str, path: Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _lazy_tables(tree: ast.Module) -> list[ast.Dict]:
    """The dicts given to ``lazy_names(...)``: inline, or a module-level name bound to a dict literal."""
    assigned = {}
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        for target in targets:
            if isinstance(target, ast.Name) and isinstance(node.value, ast.Dict):
                assigned[target.id] = node.value
    tables = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "lazy_names"
                and len(node.args) >= 2):
            table = node.args[1]
            if isinstance(table, ast.Name):
                table = assigned.get(table.id)
            if isinstance(table, ast.Dict):
                tables.append(table)
    return tables


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> tuple[list[Import], list[str]]:
    """The imports of one module resolved to modules of ``modules``, and the names under the package's
    root that resolve to none (``pkg.missing``)."""
    root = module.split(".")[0]
    package = _package_of(module, path)
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[Import] = []
    unresolved: list[str] = []

    def resolve(name: str, line: int) -> None:
        if name != root and not name.startswith(root + "."):
            return
        parts = name.split(".")
        if len(parts) > 1 and parts[1] in COMPILED:
            return
        while parts and ".".join(parts) not in modules:
            parts.pop()
        if not parts:
            unresolved.append(f"{name} (line {line})")
            return
        found.append(Import(module, ".".join(parts), line))

    def absolute(node: ast.ImportFrom) -> str:
        if not node.level:
            return node.module or ""
        base = package.split(".")[: len(package.split(".")) - node.level + 1]
        return ".".join(base + ([node.module] if node.module else []))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                resolve(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            base = absolute(node)
            for alias in node.names:
                # ``from pkg import sub`` loads the module pkg.sub; ``from pkg import name`` loads pkg
                full = f"{base}.{alias.name}"
                resolve(full if full in modules or full.split(".")[1:] == [alias.name] and alias.name in COMPILED
                        else base, node.lineno)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and "." in node.value and node.value in modules:
            resolve(node.value, node.lineno)  # a module loaded by its name (importlib, a verb table)
    for table in _lazy_tables(tree):
        for value in table.values:
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                resolve(f"{package}.{value.value}", value.lineno)
    return [i for i in found if i.target != module], unresolved


def import_graph(root: Path) -> tuple[dict[str, Path], list[Import], list[str]]:
    """Every module under ``root``, every import among them, and the imports that resolve to none."""
    modules = module_files(root)
    edges: list[Import] = []
    unresolved: list[str] = []
    for module, path in modules.items():
        found, missing = imports_of(module, path, modules)
        edges += found
        unresolved += [f"{module}: {m}" for m in missing]
    return modules, edges, unresolved


def _place(module: str, modules: dict[str, Path]) -> tuple[str, ...]:
    """The path of a module's file inside its root package's folder, as parts."""
    path = modules[module]
    return path.relative_to(modules[module.split(".")[0]].parent).parts


def folder_of(module: str, modules: dict[str, Path]) -> str:
    """The layer's folder that holds a module, or the top-level file it is (``errors.py``, ``__init__.py``)."""
    return _place(module, modules)[0]


def package_of(module: str, modules: dict[str, Path]) -> str:
    """The package a module belongs to: its top-level folder, each vendor folder apart (``vendors/ouster``),
    each top-level file apart."""
    place = _place(module, modules)
    if place[0] == "vendors" and len(place) > 2:
        return "/".join(place[:2])
    return place[0]


def strongly_connected(nodes: set[str], edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []
    counter = 0
    for start in sorted(nodes):
        if start in index:
            continue
        work = [(start, iter(sorted(edges.get(start, ()))))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(sorted(component))
    return components


def loop_through(first: str, members: list[str], edges: dict[str, set[str]]) -> list[str]:
    """The shortest path ``first -> ... -> first`` inside one strongly connected component."""
    inside = set(members)
    before: dict[str, str] = {}
    queue = deque([first])
    while queue:
        node = queue.popleft()
        for child in sorted(edges.get(node, ()) & inside):
            if child == first:
                path = [node]
                while path[-1] != first:
                    path.append(before[path[-1]])
                return [first] + path[::-1][1:] + [first] if node != first else [first, first]
            if child not in before:
                before[child] = node
                queue.append(child)
    raise AssertionError(f"no loop through {first}")


def cycles(edges: list[Import], node_of) -> list[str]:
    """Every import cycle among the nodes ``node_of`` maps modules to, as one line each: the members
    and a loop through them, each hop with the import that makes it."""
    graph: dict[str, set[str]] = defaultdict(set)
    witness: dict[tuple[str, str], Import] = {}
    for edge in edges:
        a, b = node_of(edge.source), node_of(edge.target)
        if a != b:
            graph[a].add(b)
            witness.setdefault((a, b), edge)
    nodes = set(graph) | {b for targets in graph.values() for b in targets}
    out = []
    for members in strongly_connected(nodes, graph):
        loop = loop_through(members[0], members, graph)
        hops = "; ".join(str(witness[(a, b)]) for a, b in zip(loop, loop[1:]))
        out.append(f"{{{', '.join(members)}}}: {' -> '.join(loop)} [{hops}]")
    return out


@pytest.fixture(scope="module")
def graph():
    return import_graph(PACKAGE_ROOT)


def test_every_module_is_in_a_layer_and_every_import_resolves(graph):
    modules, _, unresolved = graph
    homeless = sorted(m for m in modules if folder_of(m, modules) not in RANKS)
    assert not homeless, f"modules in no layer (give their folder a rank in RANKS): {homeless}"
    assert not unresolved, "imports of modules that do not exist:\n" + "\n".join(unresolved)


def test_no_module_imports_a_higher_layer(graph):
    modules, edges, _ = graph

    def rank(module: str) -> int:
        return RANKS[folder_of(module, modules)]

    bad = [f"{e} (rank {rank(e.source)} -> {rank(e.target)})" for e in edges if rank(e.target) > rank(e.source)]
    assert not bad, "imports from a lower layer to a higher one:\n" + "\n".join(bad)


def test_no_vendor_folder_imports_another(graph):
    modules, edges, _ = graph

    def vendor(module: str) -> str | None:
        package = package_of(module, modules)
        return package if package.startswith("vendors/") else None

    bad = [str(e) for e in edges if vendor(e.source) and vendor(e.target) and vendor(e.source) != vendor(e.target)]
    assert not bad, "a vendor folder imports another:\n" + "\n".join(bad)


def test_no_import_cycle_among_modules(graph):
    _, edges, _ = graph
    found = cycles(edges, lambda m: m)
    assert not found, "import cycles among modules:\n" + "\n".join(found)


def test_no_import_cycle_among_packages(graph):
    modules, edges, _ = graph
    found = cycles(edges, lambda m: package_of(m, modules))
    assert not found, "import cycles among packages:\n" + "\n".join(found)


def test_no_module_over_500_lines(graph):
    modules, _, _ = graph
    long = sorted(f"{p.relative_to(PACKAGE_ROOT.parent)}: {n} lines" for p in modules.values()
                  if (n := len(p.read_text().splitlines())) > MAX_LINES)
    assert not long, f"modules over {MAX_LINES} lines (split them along their seams):\n" + "\n".join(long)


def test_the_reader_sees_every_kind_of_import_and_finds_cycles(tmp_path):
    """The rules above hold only as far as the import reader sees: it is checked on a made-up package."""
    pkg = tmp_path / "pkg"
    (pkg / "core").mkdir(parents=True)
    (pkg / "cli").mkdir()
    (pkg / "__init__.py").write_text("from pkg.core.lazy import lazy_names\n"
                                     "_LAZY = {'Thing': 'core.a'}\n__getattr__, __dir__ = lazy_names(__name__, _LAZY, [])\n")
    (pkg / "core" / "__init__.py").write_text("")
    (pkg / "core" / "lazy.py").write_text("")
    (pkg / "core" / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.cli import verb\n")
    (pkg / "core" / "b.py").write_text("def f():\n    from . import a\n    from .a import something\n")
    (pkg / "cli" / "__init__.py").write_text("VERBS = {'x': 'pkg.cli.verb'}\nfrom pkg.core import missing\n")
    (pkg / "cli" / "verb.py").write_text("import pkg.core.b\nfrom .. import _native\n")
    modules, edges, unresolved = import_graph(pkg)
    assert {(e.source, e.target, e.line) for e in edges} == {
        ("pkg", "pkg.core.lazy", 1), ("pkg", "pkg.core.a", 2), ("pkg.core.a", "pkg.cli.verb", 3),
        ("pkg.core.b", "pkg.core.a", 2), ("pkg.core.b", "pkg.core.a", 3), ("pkg.cli", "pkg.cli.verb", 1),
        ("pkg.cli", "pkg.core", 2), ("pkg.cli.verb", "pkg.core.b", 1)}
    assert unresolved == []  # ``from pkg.core import missing``: a name of the package pkg.core
    assert cycles(edges, lambda m: m) == [
        "{pkg.cli.verb, pkg.core.a, pkg.core.b}: pkg.cli.verb -> pkg.core.b -> pkg.core.a -> pkg.cli.verb "
        "[pkg.cli.verb (line 1) imports pkg.core.b; pkg.core.b (line 2) imports pkg.core.a; "
        "pkg.core.a (line 3) imports pkg.cli.verb]"]
    assert cycles(edges, lambda m: package_of(m, modules)) == [
        "{cli, core}: cli -> core -> cli "
        "[pkg.cli (line 2) imports pkg.core; pkg.core.a (line 3) imports pkg.cli.verb]"]
