"""Compiled programs are released after each test module, so they do not pile up in one process.

Each module compiles its own NLPs, IPM cores and derivative programs; one process running the
whole suite would otherwise keep every executable alive until it exits.
"""

import gc

import jax
import pytest

from jaxhumanoid.strategy import problem


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    problem.clear_nlp_cache()
    jax.clear_caches()
    gc.collect()
