"""The notebooks use the public API (``import jaxhumanoid as jh``): no import of the modules behind
it, and no name that ``jaxhumanoid`` exports taken from anywhere else. Read from the code cells'
source (``ast``), without running them."""

from __future__ import annotations

import ast
import json
import pathlib

import pytest

import jaxhumanoid

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
# the modules whose public part ``jaxhumanoid`` exports: a notebook imports none of them
BEHIND_THE_API = (
    "jaxhumanoid.outputs.cli",
    "jaxhumanoid.runtime",
    "jaxhumanoid.strategy.settings",
    "jaxhumanoid.strategy.solve",
    "jaxhumanoid.strategy.solution",
    "jaxhumanoid.strategy.problem",
    "jaxhumanoid.strategy.taskfile",
)


def code(cell_source: str) -> str:
    """A cell's source without IPython's magics and shell lines."""
    return "\n".join("" if line.lstrip().startswith(("%", "!")) else line for line in cell_source.splitlines())


def internal_imports(source: str) -> list[str]:
    """The imports in ``source`` that bypass the public API."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            bad += [a.name for a in node.names if a.name.startswith(BEHIND_THE_API)]
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("jaxhumanoid."):
            if node.module.startswith(BEHIND_THE_API):
                bad.append(f"from {node.module} import {', '.join(a.name for a in node.names)}")
            else:
                bad += [f"from {node.module} import {a.name}" for a in node.names if a.name in jaxhumanoid.__all__]
    return bad


def notebook_imports(path: pathlib.Path) -> list[str]:
    cells = json.loads(path.read_text())["cells"]
    return [
        f"cell {i}: {imp}"
        for i, c in enumerate(cells)
        if c["cell_type"] == "code"
        for imp in internal_imports(code("".join(c["source"])))
    ]


def test_the_scanner_finds_internal_imports():
    cell = (
        "%matplotlib inline\nimport jaxhumanoid as jh\nfrom jaxhumanoid.outputs import plots\n"
        "from jaxhumanoid.outputs.cli import enable_compilation_cache\nimport jaxhumanoid.strategy.solve\n"
        "from jaxhumanoid.model.params import PlanarChain, ContactParams\nfrom jaxhumanoid.model import dynamics\n"
    )
    assert internal_imports(code(cell)) == [
        "from jaxhumanoid.outputs.cli import enable_compilation_cache",
        "jaxhumanoid.strategy.solve",
        "from jaxhumanoid.model.params import PlanarChain",
        "from jaxhumanoid.model.params import ContactParams",
    ]


def test_the_api_exports_what_the_notebooks_need():
    for name in (
        "solve",
        "SolveSettings",
        "Solution",
        "build_problem",
        "enable_compilation_cache",
        "PlanarChain",
        "ContactParams",
    ):
        assert name in jaxhumanoid.__all__ and hasattr(jaxhumanoid, name), name


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebooks_use_the_public_api(path):
    assert notebook_imports(path) == []
