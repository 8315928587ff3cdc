"""The import structure of legoh_rl and the recipes, read from the source (nothing is imported):
no import cycle, counting the imports inside functions too (nor between the C kernels of
legoh_rl/envs/native/, by the functions one calls of another); the layers of docs/architecture.md
(envs/, transforms/ and modules/ import nothing of each other, objectives/ only the masked VAE
network it trains, none of them the packages that wire them together); no recipe script imports
a sibling script."""

from __future__ import annotations

import ast
import functools
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "legoh_rl"

#: the library's layers (subpackages of legoh_rl) that the wiring layers (training, viewer,
#: paper_tables, demo) build on and that must not import them
LIBRARY = ("envs", "transforms", "modules", "objectives")


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """{dotted module name: file} for every ``.py`` file of legoh_rl (a package under its own name)."""
    out = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imported_names(path: Path, module: str, modules: set[str]) -> Iterator[str]:
    """Every name ``path`` imports, at the top or inside a function or class, as a dotted name to
    resolve against ``modules``: ``import a.b`` gives ``a.b``; ``from a import b`` gives ``a.b``
    when that is a module and ``a`` otherwise (b a name defined in a); relative imports are made
    absolute."""
    is_package = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = module.split(".") if is_package else module.split(".")[:-1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([node.module] if node.module else []))
            for alias in node.names:
                yield f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base


@functools.cache
def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """{module: the legoh_rl modules it imports}, each imported name resolved to the longest
    module of legoh_rl it names (``from legoh_rl.envs import HikingEnv`` -> ``legoh_rl.envs``,
    ``from legoh_rl.training import eval_run`` -> ``legoh_rl.training.eval_run``, ``import
    legoh_rl.envs.config`` -> ``legoh_rl.envs.config``). The packages a dotted import passes
    through on its way are not counted: their ``__init__.py`` runs first, whatever imports it."""
    files = module_files(root)
    graph = {}
    for module, path in files.items():
        edges = set()
        for name in imported_names(path, module, set(files)):
            while name and name not in files:
                name = name.rpartition(".")[0]
            if name and name != module:
                edges.add(name)
        graph[module] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(frozenset(component))
    return found


#: modules at the package's root that every layer may import: they import nothing of legoh_rl
#: (``kinds``: the settings' kinds the config dataclasses of envs/ and objectives/ declare;
#: ``registry``: the name -> entry tables of envs/ (terrain primitives, reward terms) and
#: modules/ (oracle, locomotion and perception networks))
FOUNDATION = ("legoh_rl.kinds", "legoh_rl.openmp", "legoh_rl.registry")


def layer(module: str) -> str:
    """The subpackage of legoh_rl a module belongs to (``legoh_rl.envs.trails.grid`` -> ``envs``;
    ``""`` for the package itself and the :data:`FOUNDATION` modules)."""
    parts = module.split(".")
    return "" if module in FOUNDATION or len(parts) < 2 else parts[1]


def test_foundation_modules_import_nothing_of_the_project():
    graph = import_graph()
    assert all(module in graph for module in FOUNDATION)
    assert not {m: graph[m] for m in FOUNDATION if graph[m]}, "a foundation module imports the project"


def test_the_reader_finds_deferred_imports_and_cycles(tmp_path):
    """The walker itself: an import inside a function is an edge, relative imports resolve, and a
    two-module loop closed only by a deferred import is a cycle."""
    pkg = tmp_path / PACKAGE / "sub"
    pkg.mkdir(parents=True)
    (tmp_path / PACKAGE / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from legoh_rl.sub.b import thing\n")
    (pkg / "b.py").write_text("def thing():\n    from .a import x\n    from . import c\n")
    (pkg / "c.py").write_text("import legoh_rl.sub\n")
    graph = import_graph(tmp_path)
    assert graph["legoh_rl.sub.a"] == {"legoh_rl.sub.b"}
    assert graph["legoh_rl.sub.b"] == {"legoh_rl.sub.a", "legoh_rl.sub.c"}
    assert graph["legoh_rl.sub.c"] == {"legoh_rl.sub"}
    assert cycles(graph) == [frozenset({"legoh_rl.sub.a", "legoh_rl.sub.b"})]
    assert cycles({"x": {"y"}, "y": {"z"}, "z": set()}) == []


def test_no_import_cycle_in_legoh_rl():
    """No loop of imports among legoh_rl's modules, deferred (function-level) imports included:
    a loop that works only because one import waits inside a function is still a loop."""
    found = [sorted(c) for c in cycles(import_graph())]
    assert not found, f"import cycles: {found}"


@pytest.mark.parametrize("package", LIBRARY)
def test_library_layers_import_only_what_docs_architecture_says(package):
    """envs/, transforms/ and modules/ import nothing of each other (they meet through TensorDict
    keys); objectives/ imports only the masked VAE network its losses train; none of them imports
    the layers that wire them together (training/, viewer/, paper_tables/). In particular modules/
    and objectives/ never import envs/."""
    allowed = {"objectives": {"legoh_rl.modules.masked_vae"}}.get(package, set())
    graph = import_graph()
    bad = sorted(f"{m} -> {dep}" for m, deps in graph.items() if layer(m) == package
                 for dep in deps if layer(dep) not in (package, "") and dep not in allowed)
    assert not bad, f"{package}/ imports outside its layer: {bad}"
    assert not any(layer(dep) == "envs" for m, deps in graph.items() if layer(m) in ("modules", "objectives")
                   for dep in deps)


def test_no_recipe_imports_a_sibling_script():
    """A recipe's reusable logic lives in legoh_rl (e.g. ``legoh_rl.training.eval_run`` for
    evaluate.py, ``legoh_rl.training.probes`` for the probes), so each script is a command line
    that no other script imports."""
    scripts = {p.stem: p for p in (ROOT / "recipes").glob("*.py")}
    bad = []
    for name, path in sorted(scripts.items()):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            bad += [f"{name}.py imports {n}" for n in names if n.split(".")[0] in scripts]
    assert not bad, bad


NATIVE = ROOT / PACKAGE / "envs" / "native"
#: a C function with external linkage defined at the start of a line (``int lh_march(...) {``, its
#: return type on the line before too)
_C_DEFINITION = re.compile(r"^(?!static\b)[A-Za-z_][\w \t\*\n]*?\b(lh_\w+)\s*\([^;]*?\)\s*\{", re.M | re.S)
_C_CALL = re.compile(r"\b(lh_\w+)\s*\(")


def c_call_graph(folder: Path = NATIVE) -> dict[str, set[str]]:
    """{C source: the other sources whose ``lh_*`` functions it calls} over ``folder``'s ``.c``
    files (the kernels' exported functions all start with ``lh_``)."""
    texts = {p.name: p.read_text() for p in sorted(folder.glob("*.c"))}
    defined = {name: src for src, text in texts.items() for name in _C_DEFINITION.findall(text)}
    return {src: {defined[n] for n in _C_CALL.findall(text) if n in defined and defined[n] != src}
            for src, text in texts.items()}


def test_the_c_reader_sees_definitions_and_calls(tmp_path):
    (tmp_path / "a.c").write_text("static int helper(void) { return lh_b(1); }\nint lh_a(int x) {\n    return x;\n}\n")
    (tmp_path / "b.c").write_text("int\nlh_b(int x) { return lh_a(x); }\n")
    assert c_call_graph(tmp_path) == {"a.c": {"b.c"}, "b.c": {"a.c"}}
    assert cycles(c_call_graph(tmp_path)) == [frozenset({"a.c", "b.c"})]


def test_no_call_cycle_between_the_c_kernels():
    """The native kernels call each other one way: the march and the camera (height_march.c) call
    the obstacle rays (obstacle_cast.c), and both the threads of parallel.c."""
    graph = c_call_graph()
    assert graph["height_march.c"] == {"obstacle_cast.c", "parallel.c"}
    assert not cycles(graph), graph
