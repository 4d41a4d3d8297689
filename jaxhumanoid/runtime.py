"""Runtime set-up shared by every layer: float64 in JAX, the same BLAS kernels on every x86-64 CPU
with AVX2, the persistent compilation cache, and the checked reading of TOML inputs and making of
output folders (errors that name the field).

Importing this module turns on ``jax_enable_x64``: every model, transcription and solver function
works in double precision. It is the only module that writes JAX's configuration.

It also sets ``OPENBLAS_CORETYPE=Haswell`` (unless set) in the process's environment, which
child processes inherit, before numpy loads, on x86-64 Linux CPUs with AVX2 and FMA
(``pin_blas_kernels``). The OpenBLAS builds that numpy, scipy (and through it JAX's LAPACK calls) and
IPOPT's MUMPS load pick their kernels by CPU (SkylakeX on AVX-512, Haswell or Zen on AVX2), and the
kernels round differently. These NLPs are chaotic: a start posture seated by a least-squares step
one ulp away can end at another optimum. With Haswell's kernels a solve gives the same bits on
every such CPU. OpenBLAS runs a forced core type without checking the CPU's instructions, so a
CPU without AVX2 and FMA (or whose flags cannot be read) keeps its own kernels. A program that
loads numpy before this module keeps the CPU's own kernels for numpy, and a warning says so: set
the variable before Python starts for bit-for-bit results there (the command line, the studies'
workers and the tests have it). The pin costs no measurable speed: IPOPT's KKT solves on the
cyipopt wheel's OpenBLAS took as long per iteration on Haswell's as on SkylakeX's kernels, and the
casadi wheel's IPOPT (the default, ``solvers.ipopt_capi``) runs on one fixed kernel set anyway.
"""

from __future__ import annotations

import ctypes
import importlib.metadata
import os
import pathlib
import platform
import sys
import tempfile
import tomllib
import warnings

BLAS_CORETYPE = "Haswell"


def _cpuinfo() -> str:
    """/proc/cpuinfo's text, empty where it cannot be read (not Linux)."""
    try:
        return pathlib.Path("/proc/cpuinfo").read_text()
    except OSError:
        return ""


def runs_blas_coretype() -> bool:
    """Whether this CPU has the instructions of ``BLAS_CORETYPE``'s kernels (x86-64 with AVX2 and
    FMA, read from /proc/cpuinfo): OpenBLAS would run a forced core type's kernels without them."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    return {"avx2", "fma"} <= set(_cpuinfo().split())


def _loaded_openblas() -> list[str]:
    """The folders of the OpenBLAS libraries this process has loaded so far (``numpy.libs``, ...):
    from /proc/self/maps, else numpy's if numpy is imported (where the maps cannot be read)."""
    try:
        maps = pathlib.Path("/proc/self/maps").read_text()
    except OSError:
        return ["numpy"] if "numpy" in sys.modules else []
    paths = {line.split(maxsplit=5)[-1] for line in maps.splitlines() if "openblas" in line.lower()}
    return sorted({pathlib.Path(p).parent.name for p in paths if "openblas" in pathlib.Path(p).name.lower()})


def pin_blas_kernels() -> bool:
    """Set ``OPENBLAS_CORETYPE=BLAS_CORETYPE`` (unless set) in this process's environment, which
    its children inherit; OpenBLAS reads it when it loads, so it acts on the copies that load
    later. Warns once where one has loaded already (numpy imported first). Returns whether it
    set the variable. Called when this module is imported."""
    if "OPENBLAS_CORETYPE" in os.environ or not runs_blas_coretype():  # a set choice (a worker's) stays
        return False
    loaded = _loaded_openblas()
    if loaded:
        warnings.warn(
            f"jaxhumanoid: OpenBLAS was loaded before jaxhumanoid ({', '.join(loaded)}: numpy imported first), "
            f"so it keeps this CPU's own kernels, not {BLAS_CORETYPE}'s, and iteration counts can differ from "
            f"the documented ones; set OPENBLAS_CORETYPE={BLAS_CORETYPE} before Python starts",
            RuntimeWarning,
            stacklevel=3,
        )
    os.environ["OPENBLAS_CORETYPE"] = BLAS_CORETYPE
    return True


pin_blas_kernels()

import jax  # noqa: E402  (after the BLAS kernels are chosen: jax loads numpy)

jax.config.update("jax_enable_x64", True)

_CORENAME = ("scipy_openblas_get_corename64_", "scipy_openblas_get_corename", "openblas_get_corename")
_PACKAGES = ("jax", "jaxlib", "numpy", "scipy", "cyipopt-wheels", "casadi")


def blas_kernels() -> dict[str, str]:
    """The kernels (OpenBLAS's core name, e.g. ``Haswell``) of every OpenBLAS this process has
    loaded, keyed by the folder it was loaded from (``numpy.libs``, ``scipy.libs``,
    ``cyipopt_wheels.libs``); empty where the loaded libraries cannot be listed (not Linux)."""
    try:
        maps = pathlib.Path("/proc/self/maps").read_text()
    except OSError:
        return {}
    paths = {f[5] for f in (line.split(maxsplit=5) for line in maps.splitlines()) if len(f) == 6}
    kernels = {}
    for path in sorted(p for p in paths if "openblas" in pathlib.Path(p).name.lower()):
        lib = ctypes.CDLL(path)  # already loaded: the same handle, nothing new runs
        fn = next((getattr(lib, name) for name in _CORENAME if hasattr(lib, name)), None)
        if fn is not None:
            fn.restype = ctypes.c_char_p
            kernels[pathlib.Path(path).parent.name] = fn().decode()
    return kernels


def environment() -> dict:
    """What a result's bits depend on besides its inputs: the package versions, the CPU, the BLAS
    kernels and IPOPT libraries in use and the thread settings (``report.json``'s ``environment``)."""
    versions: dict[str, str | None] = {}
    for name in _PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "python": platform.python_version(),
        "packages": versions,
        "machine": platform.machine(),
        "cpu": _cpu_model(),
        "blas_kernels": blas_kernels(),
        "ipopt_libraries": _loaded_libraries("libipopt"),
        "OPENBLAS_CORETYPE": os.environ.get("OPENBLAS_CORETYPE"),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
        "platform": sys.platform,
    }


def _loaded_libraries(stem: str) -> list[str]:
    """The files of the loaded libraries whose name starts with ``stem`` (e.g. the IPOPT a solve
    ran), from /proc/self/maps; empty where it cannot be read."""
    try:
        maps = pathlib.Path("/proc/self/maps").read_text()
    except OSError:
        return []
    paths = {f[5] for f in (line.split(maxsplit=5) for line in maps.splitlines()) if len(f) == 6}
    return sorted(p for p in paths if pathlib.Path(p).name.startswith(stem))


def _cpu_model() -> str:
    models = (line.split(":", 1)[1].strip() for line in _cpuinfo().splitlines() if line.startswith("model name"))
    return next(models, platform.processor())


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
