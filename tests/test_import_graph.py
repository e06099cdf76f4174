"""No import cycles in pipeline/placeloc, read statically with ``ast``.

Every ``import placeloc.x`` and ``from placeloc.x import y`` counts, at module level and
inside functions alike: an import deferred into a function still makes the two modules
depend on each other (it only hides the cycle from the interpreter until that function
runs), and a reader following the arrows meets the same circle. Imports under
``if TYPE_CHECKING:`` are left out: they never run.

``from placeloc.x import y`` is an edge to ``placeloc.x.y`` when that is a module, else to
``placeloc.x``. Importing a module of a subpackage from outside it also runs the
subpackage's ``__init__``, so that is an edge too (``placeloc.seqslam.stages`` ->
``placeloc.evaluation`` when it imports ``placeloc.evaluation.matching``). The root
package ``placeloc`` is left out of that rule: its ``__init__`` only re-exports the API
lazily, and every module is below it.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "pipeline" / "placeloc"


def module_files(root: Path = PACKAGE) -> dict[str, Path]:
    """Dotted module name -> file, for every .py below ``root`` (packages by their __init__)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _type_checking_only(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    found: list[ast.Import | ast.ImportFrom] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking_only(child):
                for other in child.orelse:
                    visit(other)
                continue
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                found.append(child)
            visit(child)

    visit(tree)
    return found


def _package_of(module: str, path: Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the placeloc modules it imports (see the module docstring for the rules)."""
    files = module_files(root)
    top = root.name
    graph: dict[str, set[str]] = {m: set() for m in files}
    for module, path in files.items():
        for node in _imports(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                base = node.module or ""
                if node.level:  # relative: resolve against this module's package
                    pkg = _package_of(module, path).split(".")
                    pkg = pkg[: len(pkg) - node.level + 1]
                    base = ".".join(pkg + ([base] if base else []))
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    targets.append(sub if sub in files else base)
            for target in targets:
                if target != top and not target.startswith(top + "."):
                    continue
                while target not in files and "." in target:
                    target = target.rpartition(".")[0]
                if target == module:
                    continue
                graph[module].add(target)
                # the subpackages' __init__ on the way, unless this module is inside them
                parts = target.split(".")
                for i in range(2, len(parts)):
                    pkg = ".".join(parts[:i])
                    if pkg in files and not (module == pkg or module.startswith(pkg + ".")):
                        graph[module].add(pkg)
            graph[module].discard(top)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted,
    plus self-loops."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
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
            if len(comp) > 1 or v in graph.get(v, ()):
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def _a_path(graph: dict[str, set[str]], component: list[str]) -> str:
    """One concrete circle through a component, for the failure message."""
    members = set(component)
    start = component[0]
    prev: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & members):
                if w == start:
                    path = [start]
                    while v != start:
                        path.append(v)
                        v = prev[v]
                    return " -> ".join([start, *reversed(path[1:]), start])
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return " <-> ".join(component)


def test_the_package_has_no_import_cycles() -> None:
    graph = import_graph()
    assert len(graph) > 50 and "placeloc.core.config" in graph["placeloc.core.runner"]
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(_a_path(graph, c) for c in found)


def test_a_planted_cycle_is_found(tmp_path: Path) -> None:
    """Two modules that import each other, one of them inside a function, and a third
    reaching the first through a subpackage's __init__."""
    pkg = tmp_path / "demo"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from demo import b\n")
    (pkg / "b.py").write_text("def f():\n    from demo.a import thing\n")
    (pkg / "sub" / "__init__.py").write_text("from demo.sub.inner import x\n")
    (pkg / "sub" / "inner.py").write_text("from typing import TYPE_CHECKING\nx = 1\nif TYPE_CHECKING:\n    import demo.c\n")
    (pkg / "c.py").write_text("import demo.sub.inner\n")
    graph = import_graph(pkg)
    assert graph["demo.c"] == {"demo.sub.inner", "demo.sub"}
    assert graph["demo.sub.inner"] == set()              # TYPE_CHECKING imports do not count
    assert cycles(graph) == [["demo.a", "demo.b"]]
    assert _a_path(graph, ["demo.a", "demo.b"]) == "demo.a -> demo.b -> demo.a"


# ----------------------------------------------------------------------------- layers
# Methods are the subpackages with a stages.py (as placeloc.core.methods discovers them).
METHODS = tuple(sorted(d.name for d in PACKAGE.iterdir() if (d / "stages.py").is_file() and (d / "__init__.py").is_file()))
EXECUTORS = ("placeloc.core.executor", "placeloc.core.dask_executor", "placeloc.core.executors")


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    """Every module ``start`` imports, directly or through others."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        for target in graph[todo.pop()]:
            if target not in seen:
                seen.add(target)
                todo.append(target)
    return seen


def layer_violations(graph: dict[str, set[str]], methods: tuple[str, ...]) -> list[str]:
    """Edges that break the layer rules: evaluation imports no method, no method imports
    another, the executors reach no config."""
    bad = []
    for module, targets in sorted(graph.items()):
        layer = _layer(module)
        for target in sorted(targets):
            other = _layer(target)
            if layer == "evaluation" and other in methods:
                bad.append(f"evaluation imports a method: {module} -> {target}")
            if layer in methods and other in methods and other != layer:
                bad.append(f"a method imports another: {module} -> {target}")
    for module in EXECUTORS:
        if module in graph and "placeloc.core.config" in reachable(graph, module):
            bad.append(f"an executor reaches the config layer: {module} -> ... -> placeloc.core.config")
    return bad


def test_layers_stay_apart() -> None:
    graph = import_graph()
    assert {"seqslam", "pirf", "retrieval"} <= set(METHODS)
    assert all(m in graph for m in EXECUTORS)
    violations = layer_violations(graph, METHODS)
    assert not violations, "\n".join(violations)


def test_a_planted_layer_violation_is_found(tmp_path: Path) -> None:
    pkg = tmp_path / "placeloc"
    for sub in ("core", "evaluation", "alpha", "beta"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "core" / "config.py").write_text("")
    (pkg / "core" / "errors.py").write_text("")
    (pkg / "core" / "executor.py").write_text("from placeloc.core import errors\n")
    (pkg / "core" / "executors.py").write_text("def make():\n    from placeloc.core.middle import x\n")
    (pkg / "core" / "middle.py").write_text("from placeloc.core.config import y\n")
    (pkg / "alpha" / "stages.py").write_text("from placeloc.beta.numerics import f\n")
    (pkg / "beta" / "stages.py").write_text("")
    (pkg / "beta" / "numerics.py").write_text("")
    (pkg / "evaluation" / "ranked.py").write_text("import placeloc.alpha.stages\n")
    found = layer_violations(import_graph(pkg), ("alpha", "beta"))
    assert found == ["a method imports another: placeloc.alpha.stages -> placeloc.beta",
                     "a method imports another: placeloc.alpha.stages -> placeloc.beta.numerics",
                     "evaluation imports a method: placeloc.evaluation.ranked -> placeloc.alpha",
                     "evaluation imports a method: placeloc.evaluation.ranked -> placeloc.alpha.stages",
                     "an executor reaches the config layer: placeloc.core.executors -> ... -> placeloc.core.config"]
