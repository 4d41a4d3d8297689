"""Runtime set-up shared by every layer: float64 in JAX, the same BLAS kernels on every x86-64 CPU
with AVX2, the persistent compilation cache, and the checked reading of TOML inputs and making of
output folders (errors that name the field).

Importing this module turns on ``jax_enable_x64``: every model, transcription and solver function
works in double precision. It is the only module that writes JAX's configuration.

It also sets ``OPENBLAS_CORETYPE=Haswell`` (unless set) before numpy loads, on x86-64 Linux CPUs
with AVX2 and FMA. The OpenBLAS builds that numpy, scipy (and through it JAX's LAPACK calls) and
IPOPT's MUMPS load pick their kernels by CPU (SkylakeX on AVX-512, Haswell or Zen on AVX2), and the
kernels round differently. These NLPs are chaotic: a start posture seated by a least-squares step
one ulp away can end at another optimum. With Haswell's kernels a solve gives the same bits on
every such CPU. OpenBLAS runs a forced core type without checking the CPU's instructions, so a
CPU without AVX2 and FMA (or whose flags cannot be read) keeps its own kernels. A program that
loads numpy before this module keeps the CPU's own kernels too: set the variable before Python
starts for bit-for-bit results there (the command line, the studies' workers and the tests have it).
"""

from __future__ import annotations

import os
import pathlib
import platform
import tempfile
import tomllib

BLAS_CORETYPE = "Haswell"


def runs_blas_coretype() -> bool:
    """Whether this CPU has the instructions of ``BLAS_CORETYPE``'s kernels (x86-64 with AVX2 and
    FMA, read from /proc/cpuinfo): OpenBLAS would run a forced core type's kernels without them."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        flags = set(pathlib.Path("/proc/cpuinfo").read_text().split())
    except OSError:
        return False
    return {"avx2", "fma"} <= flags


if "OPENBLAS_CORETYPE" not in os.environ and runs_blas_coretype():  # a set choice (a worker's) stays
    os.environ["OPENBLAS_CORETYPE"] = BLAS_CORETYPE

import jax  # noqa: E402  (after the BLAS kernels are chosen: jax loads numpy)

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


def read_toml(path, field: str) -> dict:
    """The TOML file ``path`` as a dict; a ValueError names ``field`` when it cannot be read and
    the file when it is not valid TOML."""
    path = pathlib.Path(path)
    try:
        return tomllib.loads(path.read_text())
    except OSError as err:
        raise ValueError(f"{field}: cannot read {str(path)!r} ({err.strerror or err})") from err
    except tomllib.TOMLDecodeError as err:
        raise ValueError(f"{path}: not valid TOML ({err})") from err


def writable_dir(path, field: str = "--out") -> pathlib.Path:
    """``path`` as a directory that exists and takes files, made if needed, before any work."""
    out = pathlib.Path(path)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".write_test_"):
            pass
    except OSError as err:
        raise ValueError(f"{field}: cannot write to {str(out)!r} ({err.strerror or err})") from err
    return out
