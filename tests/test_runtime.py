"""The BLAS kernel pin of ``jaxhumanoid.runtime``: set on import, kept where set, and a warning
where numpy loaded its OpenBLAS first, so that the pin cannot act on it."""

import os
import subprocess
import sys

import pytest

from jaxhumanoid.runtime import BLAS_CORETYPE, runs_blas_coretype

PROBE = """
import warnings
warnings.simplefilter("always")
{first}
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import jaxhumanoid.runtime as rt
import os
print(os.environ.get("OPENBLAS_CORETYPE"), rt.blas_kernels().get("numpy.libs", "unknown"))
print("WARNED" if any("OpenBLAS was loaded before jaxhumanoid" in str(w.message) for w in caught) else "QUIET")
"""


def probe(first: str, coretype: str | None = None) -> tuple[str, str, bool]:
    """(OPENBLAS_CORETYPE after the import, numpy's kernels, whether the import warned) in a fresh
    process that runs ``first`` before importing jaxhumanoid."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    if coretype is not None:
        env["OPENBLAS_CORETYPE"] = coretype
    out = subprocess.run([sys.executable, "-c", PROBE.format(first=first)], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    value, kernels, warned = out.stdout.split()
    return value, kernels, warned == "WARNED"


@pytest.mark.skipif(not runs_blas_coretype(), reason="a CPU without the pinned kernels' instructions")
def test_numpy_loaded_first_warns_that_the_pin_cannot_act():
    value, kernels, warned = probe("import numpy")
    if kernels == "unknown":
        pytest.skip("numpy is not linked to a bundled OpenBLAS")
    assert warned and value == BLAS_CORETYPE  # still set, for the copies that load later (scipy, MUMPS)


@pytest.mark.skipif(not runs_blas_coretype(), reason="a CPU without the pinned kernels' instructions")
def test_the_pin_is_quiet_when_it_acts_or_when_the_variable_is_set():
    value, kernels, warned = probe("")
    assert not warned and value == BLAS_CORETYPE
    if kernels != "unknown":
        assert kernels == BLAS_CORETYPE
    value, _, warned = probe("import numpy", coretype="Sandybridge")  # the user's choice, before Python
    assert not warned and value == "Sandybridge"
