"""The project's persistent compilation cache for every test, and compiled programs released after
each test module so they do not pile up in one process.

The cache is the one the command line uses (``runtime.enable_compilation_cache``: ``$JAXHUMANOID_CACHE``
or ``~/.cache/jaxhumanoid/jax``), so a rerun reads what the last run compiled; the notebooks' kernels
and the sweep workers turn on the same folder. Each module compiles its own NLPs, IPM cores and
derivative programs; one process running the whole suite would otherwise keep every executable
alive until it exits (several GiB by the middle of the suite).

``jaxhumanoid.runtime`` is imported before anything loads numpy, so that the tests run on the BLAS
kernels it pins (its docstring).
"""

import gc

from jaxhumanoid.runtime import enable_compilation_cache

# isort: split
import jax
import pytest

from jaxhumanoid.strategy import problem

enable_compilation_cache()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    problem.clear_nlp_cache()
    jax.clear_caches()
    gc.collect()
