"""The code stays in parts of a screen or two: no module of the package or of ``scripts/`` over
700 lines, no function over 150."""

from __future__ import annotations

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
FILES = sorted([*(ROOT / "jaxhumanoid").rglob("*.py"), *(ROOT / "scripts").glob("*.py")])
MAX_MODULE, MAX_FUNCTION = 700, 150


def long_parts(source: str, name: str) -> list[str]:
    """The module itself and its functions (methods and nested ones too) over the limits."""
    out = []
    if len(source.splitlines()) > MAX_MODULE:
        out.append(f"{name}: {len(source.splitlines())} lines")
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNCTION:
                out.append(f"{name}:{node.lineno} {node.name}: {n} lines")
    return out


def test_the_size_check_can_fail():
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION))
    assert long_parts(f"def f():\n{body}", "m.py") == [f"m.py:1 f: {MAX_FUNCTION + 1} lines"]
    assert long_parts("x = 1\n" * (MAX_MODULE + 1), "m.py") == [f"m.py: {MAX_MODULE + 1} lines"]


def test_no_long_module_or_function():
    assert FILES
    found = [p for f in FILES for p in long_parts(f.read_text(), str(f.relative_to(ROOT)))]
    assert not found, found
