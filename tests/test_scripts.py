"""The scripts in ``scripts/``: each imports, shows its ``--help``, and none imports another script
(what they share lives in the package, ``jaxhumanoid.studies.bench``)."""

from __future__ import annotations

import ast
import contextlib
import importlib.util
import io
import pathlib
import sys

import pytest

SCRIPTS = pathlib.Path(__file__).resolve().parents[1] / "scripts"
PATHS = sorted(SCRIPTS.glob("*.py"))


def script_imports(source: str, names: set[str]) -> list[str]:
    """The modules among ``names`` (script file stems) that ``source`` imports, anywhere in it."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append(node.module.split(".")[0])
    return sorted({m for m in found if m in names})


def load(path: pathlib.Path):
    """The script as a module (not ``__main__``: nothing runs), without ``scripts/`` on the path,
    so that an import of a sibling script fails here as it would from another folder."""
    spec = importlib.util.spec_from_file_location(f"script_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_there_are_scripts():
    assert len(PATHS) >= 5 and all(p.stem.isidentifier() for p in PATHS)


def test_no_script_imports_another():
    names = {p.stem for p in PATHS}
    bad = {p.name: script_imports(p.read_text(), names) for p in PATHS}
    assert not {k: v for k, v in bad.items() if v}, bad


def test_the_import_check_can_fail():
    names = {"bench_ipm", "_bench"}
    assert script_imports("from _bench import write\nimport numpy\n", names) == ["_bench"]
    assert script_imports("def f():\n    from bench_ipm import stage1_problem\n", names) == ["bench_ipm"]
    assert script_imports("from jaxhumanoid.studies.bench import write_record\n", names) == []


@pytest.mark.parametrize("path", PATHS, ids=[p.stem for p in PATHS])
def test_script_imports_and_shows_its_help(path, monkeypatch):
    module = load(path)
    assert callable(getattr(module, "main", None)), f"{path.name} has no main()"
    monkeypatch.setattr(sys, "argv", [str(path), "--help"])
    text = io.StringIO()
    with contextlib.redirect_stdout(text), pytest.raises(SystemExit) as done:
        module.main()
    assert done.value.code in (0, None) and "usage:" in text.getvalue()
