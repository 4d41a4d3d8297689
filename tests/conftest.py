"""Test-session set-up: the project's persistent compilation cache from the first test on, and
compiled programs released after each test module so they do not pile up in one process.

The cache is the one the command line uses (``runtime.enable_compilation_cache``: ``$JAXHUMANOID_CACHE``
or ``~/.cache/jaxhumanoid/jax``), so a rerun reads what the last run compiled; the notebooks' kernels
and the sweep workers turn on the same folder. Each module compiles its own NLPs, IPM cores and
derivative programs; one process running the whole suite would otherwise keep every executable
alive until it exits (several GiB by the middle of the suite).
"""

import gc

import jax
import pytest

from jaxhumanoid.runtime import enable_compilation_cache
from jaxhumanoid.strategy import problem


@pytest.fixture(autouse=True, scope="session")
def _persistent_compilation_cache():
    enable_compilation_cache()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    problem.clear_nlp_cache()
    jax.clear_caches()
    gc.collect()
