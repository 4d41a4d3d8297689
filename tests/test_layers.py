"""The package's layers hold: data flows one way, with no cycles and no hidden imports.

    runtime, pytree, progress -> model -> ocp -> derivatives -> solvers -> validation -> strategy -> diff
    -> tracking -> studies -> outputs

A module may import its own layer and the layers below it, never one above. Imports are read
from the source (``ast``), so the test also sees imports inside functions, which may name only
third-party packages and must say why on the same line.
"""

from __future__ import annotations

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "jaxhumanoid"
LAYERS = (
    "runtime",
    "pytree",
    "model",
    "ocp",
    "derivatives",
    "solvers",
    "validation",
    "strategy",
    "diff",
    "tracking",
    "studies",
    "outputs",
)
RANK = {"runtime": 0, "pytree": 0, "progress": 0, **{name: i for i, name in enumerate(LAYERS) if i >= 2}}


def module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_of(module: str) -> str | None:
    """The layer of ``jaxhumanoid.<layer>...``; None for the package itself and ``__main__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in RANK else None


def imports_of(path: pathlib.Path, modules=()) -> list[tuple[str, int, bool, str]]:
    """(imported module, line, inside a function, source line) of every import in a file.

    ``from a import b`` imports ``a.b`` when that is one of ``modules``, else ``a``.
    """
    src = path.read_text()
    lines = src.splitlines()
    out = []

    def visit(node, in_fn):
        for child in ast.iter_child_nodes(node):
            fn = in_fn or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                mods = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                mods = [f"{child.module}.{a.name}" for a in child.names]
                mods = [m if m in modules else child.module for m in mods]
            else:
                mods = []
            out.extend((m, child.lineno, in_fn, lines[child.lineno - 1]) for m in dict.fromkeys(mods))
            visit(child, fn)

    visit(ast.parse(src), False)
    return out


def package_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports."""
    files = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {mod: {m for m, *_ in imports_of(path, files) if m in files and m != mod} for mod, path in files.items()}


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """Edges from a lower layer to a higher one, and bare imports of the package's ``__init__``."""
    bad = []
    for mod, deps in graph.items():
        lo = layer_of(mod)
        if lo is None:
            continue
        for dep in deps:
            hi = layer_of(dep)
            if dep == "jaxhumanoid" or (hi is not None and RANK[hi] > RANK[lo]):
                bad.append(f"{mod} ({lo}) imports {dep} ({hi or 'the package facade'})")
    return sorted(bad)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Import cycles among the modules (each reported once, from its smallest module)."""
    found, state = [], {}

    def dfs(node, stack):
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph.get(node, ())):
            if state.get(dep) == 1:
                cyc = stack[stack.index(dep) :]
                i = cyc.index(min(cyc))
                found.append(cyc[i:] + cyc[:i])
            elif dep not in state:
                dfs(dep, stack)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            dfs(node, [])
    return [list(c) for c in {tuple(c) for c in found}]


def test_every_module_belongs_to_a_layer():
    graph = package_graph()
    orphans = [m for m in graph if layer_of(m) is None and m not in ("jaxhumanoid", "jaxhumanoid.__main__")]
    assert not orphans, f"modules outside every layer: {orphans}"


def test_no_lower_layer_imports_a_higher_one():
    assert layer_violations(package_graph()) == []


def test_no_import_cycles():
    assert cycles(package_graph()) == []


def test_imports_inside_functions_are_third_party_and_explained():
    hidden = []
    for path in PACKAGE.rglob("*.py"):
        for mod, line, in_fn, text in imports_of(path):
            if in_fn and (mod.startswith("jaxhumanoid") or "#" not in text):
                hidden.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {text.strip()}")
    assert not hidden, "imports hidden in functions:\n" + "\n".join(sorted(set(hidden)))


@pytest.mark.parametrize(
    "graph, expected",
    [
        ({"jaxhumanoid.model.kinematics": {"jaxhumanoid.strategy.solve"}}, 1),
        ({"jaxhumanoid.solvers.ipopt": {"jaxhumanoid.ocp.nlp", "jaxhumanoid.runtime"}}, 0),
        ({"jaxhumanoid.ocp.nlp": {"jaxhumanoid"}}, 1),
        ({"jaxhumanoid.outputs.cli": {"jaxhumanoid.diff.fd", "jaxhumanoid.model.params"}}, 0),
    ],
)
def test_the_layer_check_can_fail(graph, expected):
    assert len(layer_violations(graph)) == expected


def test_the_cycle_check_can_fail():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
