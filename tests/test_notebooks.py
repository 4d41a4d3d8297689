"""Every notebook in notebooks/ runs top to bottom without an error (nbclient, a fresh kernel each).

The kernel is the ``python3`` kernelspec that ipykernel installs into the virtual environment
(``<venv>/share/jupyter/kernels/python3``, argv ``python -m ipykernel_launcher``; jupyter_client
replaces a bare ``python`` by ``sys.executable``), so the notebooks run in the same interpreter as
the tests and no ``python -m ipykernel install --user`` is needed. Should the spec be missing, the
``kernel_name`` fixture installs it into ``sys.prefix``.

Notebooks are stored without outputs; executing them here does not write them back.
"""

from __future__ import annotations

import pathlib
import sys

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOK_DIR = pathlib.Path(__file__).resolve().parent.parent / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
KERNEL = "python3"
CELL_TIMEOUT_S = 600


@pytest.fixture(scope="module")
def kernel_name() -> str:
    from jupyter_client.kernelspec import KernelSpecManager, NoSuchKernel

    try:
        KernelSpecManager().get_kernel_spec(KERNEL)
    except NoSuchKernel:
        from ipykernel.kernelspec import install

        install(prefix=sys.prefix, kernel_name=KERNEL)
    spec = KernelSpecManager().get_kernel_spec(KERNEL)
    assert (
        spec.argv[0] in ("python", "python3", sys.executable)
        or pathlib.Path(spec.argv[0]).resolve() == pathlib.Path(sys.executable).resolve()
    ), spec.argv
    return KERNEL


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks in {NOTEBOOK_DIR}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_without_outputs(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    dirty = [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and (c.outputs or c.execution_count)]
    assert not dirty, f"{path.name}: cells {dirty} carry outputs; clear them before committing"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, kernel_name, tmp_path):
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb, timeout=CELL_TIMEOUT_S, kernel_name=kernel_name, resources={"metadata": {"path": str(tmp_path)}}
    )
    try:
        client.execute()
    except nbclient.exceptions.CellExecutionError as err:  # names the cell and carries the traceback
        pytest.fail(f"{path.name}: a cell raised\n{err}", pytrace=False)
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.get("output_type") == "error"]
    assert not errors, f"{path.name}: {[(e['ename'], e['evalue']) for e in errors]}"
