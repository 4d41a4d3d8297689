"""Runtime set-up shared by every layer: float64 in JAX and the persistent compilation cache.

Importing this module turns on ``jax_enable_x64``: every model, transcription and solver function
works in double precision. It is the only module that writes JAX's configuration.
"""

from __future__ import annotations

import os
import pathlib

import jax

jax.config.update("jax_enable_x64", True)


def enable_compilation_cache(path: str | None = None) -> str:
    """Persistent JAX compilation cache, so a second process skips most compilation.

    ``path`` defaults to ``$JAXHUMANOID_CACHE`` or ``~/.cache/jaxhumanoid/jax``; returns the path used.
    """
    cache = path or os.environ.get("JAXHUMANOID_CACHE", str(pathlib.Path.home() / ".cache" / "jaxhumanoid" / "jax"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return cache
