"""IPOPT's C interface (``IpStdCInterface.h``, IPOPT 3.14) through ctypes.

The IPOPT library is the one the pinned casadi wheel ships (``default_library_path``; the pinned
``cyipopt-wheels`` package's where casadi has none, or by choice). cyipopt's own callbacks copy
every Jacobian and Hessian value into IPOPT's arrays one Python object at a time, which costs
milliseconds per iteration at N = 100 (30k Jacobian and 19k Hessian nonzeros); here the values are
written with one ``memcpy`` into a numpy view of IPOPT's buffer, and IPOPT's ``new_x`` flag tells
the caller when x has changed.

``solve(...)`` takes plain Python callables:

    f(x) -> float,  g(x) -> (m,),  grad(x) -> (n,),  jac(x) -> (nnz_jac,),
    hess(x, lam, obj_factor) -> (nnz_hess,),  intermediate(*stats) -> None,  new_point() -> None

A callable that raises stops IPOPT (the callback returns false) and the exception is re-raised
after ``IpoptSolve`` returns, so an error in the model is never mistaken for a solver status.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import sys
from functools import lru_cache

import cyipopt
import numpy as np

_idx = ctypes.c_int  # ipindex: IPOPT's default 32-bit build, as in the wheel
_num = ctypes.c_double
_P_NUM = ctypes.POINTER(_num)
_P_IDX = ctypes.POINTER(_idx)
_cb = ctypes.CFUNCTYPE
EVAL_F = _cb(ctypes.c_bool, _idx, _P_NUM, ctypes.c_bool, _P_NUM, ctypes.c_void_p)
EVAL_GRAD_F = _cb(ctypes.c_bool, _idx, _P_NUM, ctypes.c_bool, _P_NUM, ctypes.c_void_p)
EVAL_G = _cb(ctypes.c_bool, _idx, _P_NUM, ctypes.c_bool, _idx, _P_NUM, ctypes.c_void_p)
EVAL_JAC_G = _cb(ctypes.c_bool, _idx, _P_NUM, ctypes.c_bool, _idx, _idx, _P_IDX, _P_IDX, _P_NUM, ctypes.c_void_p)
EVAL_H = _cb(
    ctypes.c_bool,
    _idx,
    _P_NUM,
    ctypes.c_bool,
    _num,
    _idx,
    _P_NUM,
    ctypes.c_bool,
    _idx,
    _P_IDX,
    _P_IDX,
    _P_NUM,
    ctypes.c_void_p,
)
INTERMEDIATE = _cb(ctypes.c_bool, _idx, _idx, _num, _num, _num, _num, _num, _num, _num, _num, _idx, ctypes.c_void_p)


def default_library_path() -> str:
    """The IPOPT library ``solve`` loads unless told: ``$JAXHUMANOID_IPOPT_LIBRARY``, else the
    casadi wheel's (``casadi_library_path``), else the cyipopt wheel's (``wheel_library_path``)."""
    return os.environ.get("JAXHUMANOID_IPOPT_LIBRARY") or casadi_library_path() or wheel_library_path()


def casadi_library_path() -> str | None:
    """The IPOPT library of the pinned casadi wheel (IPOPT 3.14.19, MUMPS with METIS, OpenBLAS on
    one kernel set for every x86-64 CPU), None where it has none. Its KKT solves take 16-38 % less
    time per iteration than the cyipopt wheel's on the reference posing's T1 and T4
    (scripts/bench_iteration.py): MUMPS orders the KKT matrices with METIS there."""
    try:
        import casadi  # noqa: PLC0415  (only to find its folder)
    except ImportError:
        return None
    folder = os.path.dirname(os.path.abspath(casadi.__file__))
    for pattern in ("libipopt.so*", "libipopt*.dylib", "libipopt*.dll", "ipopt*.dll"):
        found = sorted(glob.glob(os.path.join(folder, pattern)))
        if found:
            return found[0]
    return None


def wheel_library_path() -> str:
    """The IPOPT library the pinned cyipopt wheel ships next to itself (IPOPT 3.14.11, MUMPS
    without METIS): the one cyipopt's own binding runs (``ipopt.solve_cyipopt_reference``)."""
    site = os.path.dirname(os.path.dirname(os.path.abspath(cyipopt.__file__)))
    found = sorted(
        glob.glob(os.path.join(site, "cyipopt*.libs", "libipopt*.so*"))
        + glob.glob(os.path.join(site, "cyipopt*", ".dylibs", "libipopt*.dylib"))
    )
    if not found and os.path.exists("/proc/self/maps"):  # a cyipopt built against a system IPOPT
        with open("/proc/self/maps") as fh:
            found = sorted({line.split()[-1] for line in fh if "libipopt" in line})
    if not found:
        raise RuntimeError(f"IPOPT library not found next to cyipopt in {site}: install the pinned cyipopt-wheels")
    return found[0]


def library(path: str | None = None) -> ctypes.CDLL:
    """The IPOPT library at ``path`` (default ``default_library_path()``), loaded once."""
    return _load(os.path.realpath(path or default_library_path()))


@lru_cache(maxsize=4)
def _load(path: str) -> ctypes.CDLL:
    lib = ctypes.CDLL(path)
    lib.CreateIpoptProblem.restype = ctypes.c_void_p
    lib.CreateIpoptProblem.argtypes = [
        _idx,
        _P_NUM,
        _P_NUM,
        _idx,
        _P_NUM,
        _P_NUM,
        _idx,
        _idx,
        _idx,
        EVAL_F,
        EVAL_G,
        EVAL_GRAD_F,
        EVAL_JAC_G,
        EVAL_H,
    ]
    lib.FreeIpoptProblem.restype = None
    lib.FreeIpoptProblem.argtypes = [ctypes.c_void_p]
    for name, kind in (
        ("AddIpoptStrOption", ctypes.c_char_p),
        ("AddIpoptNumOption", _num),
        ("AddIpoptIntOption", _idx),
    ):
        fn = getattr(lib, name)
        fn.restype = ctypes.c_bool
        fn.argtypes = [ctypes.c_void_p, ctypes.c_char_p, kind]
    lib.SetIntermediateCallback.restype = ctypes.c_bool
    lib.SetIntermediateCallback.argtypes = [ctypes.c_void_p, INTERMEDIATE]
    lib.IpoptSolve.restype = ctypes.c_int
    lib.IpoptSolve.argtypes = [ctypes.c_void_p, _P_NUM, _P_NUM, _P_NUM, _P_NUM, _P_NUM, _P_NUM, ctypes.c_void_p]
    return lib


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(_P_NUM)


def _view(ptr, size: int) -> np.ndarray:
    return np.ctypeslib.as_array(ptr, shape=(size,))


def _structure(rows, cols, r: np.ndarray, c: np.ndarray) -> None:
    np.ctypeslib.as_array(rows, shape=r.shape)[:] = r
    np.ctypeslib.as_array(cols, shape=c.shape)[:] = c


def add_option(handle, key: str, val, lib: ctypes.CDLL | None = None) -> None:
    """One IPOPT option; raises ValueError naming it when IPOPT rejects the key or value.

    IPOPT has one setter per option type and rejects a value given through another type's setter,
    so an integral value (``tol=1``, ``mu_init=1`` from a command line or a TOML file) goes to the
    number setter unless the integer setter takes it."""
    lib = lib or library()
    k = key.encode()
    if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating, str)):
        raise ValueError(f"options[{key!r}]: expected a str, int or float, got {val!r}")
    if isinstance(val, str):
        ok = lib.AddIpoptStrOption(handle, k, val.encode())
    elif isinstance(val, (int, np.integer)) and _integer_setter_takes(key, int(val)):
        ok = lib.AddIpoptIntOption(handle, k, int(val))
    else:
        ok = lib.AddIpoptNumOption(handle, k, float(val))
    if not ok:
        raise ValueError(f"options[{key!r}]: IPOPT rejected the option or its value {val!r} (see IPOPT's option list)")


@lru_cache(maxsize=256)
def _integer_setter_takes(key: str, val: int) -> bool:
    """Whether IPOPT takes ``val`` for ``key`` through its integer setter, asked of a problem that
    is never solved (an integer option in range: yes; a number option, or a value out of range,
    or no such option: no)."""
    lib = library()
    handle = _probe_problem()
    try:
        with _silenced_stdout():  # IPOPT prints its own complaint about the wrong setter
            return bool(lib.AddIpoptIntOption(handle, key.encode(), int(val)))
    finally:
        lib.FreeIpoptProblem(handle)


def _no_eval(*_args):
    return False


_NO_EVAL = (EVAL_F(_no_eval), EVAL_G(_no_eval), EVAL_GRAD_F(_no_eval), EVAL_JAC_G(_no_eval), EVAL_H(_no_eval))


def _probe_problem():
    """A one-variable problem that is never solved, to give options to (free it with
    ``FreeIpoptProblem``)."""
    lib = library()
    one = np.zeros(1)
    handle = lib.CreateIpoptProblem(1, _ptr(one), _ptr(one), 0, _ptr(one), _ptr(one), 0, 0, 0, *_NO_EVAL)
    if not handle:
        raise RuntimeError("IPOPT could not create the problem (CreateIpoptProblem returned NULL)")
    return handle


def check_options(options: dict) -> None:
    """Raise ValueError naming the first option whose name or value IPOPT rejects, before any
    problem is built: the options are given to a one-variable problem that is never solved."""
    lib = library()
    handle = _probe_problem()
    try:
        with _silenced_stdout():  # IPOPT prints its own complaint; the ValueError says it once
            for key, val in options.items():
                add_option(handle, key, val)
    finally:
        lib.FreeIpoptProblem(handle)


@contextlib.contextmanager
def _silenced_stdout():
    """Send the process's file descriptor 1 (where IPOPT's journalist writes) to /dev/null."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def solve(
    n,
    m,
    xl,
    xu,
    gl,
    gu,
    jac_structure,
    hess_structure,
    funcs: dict,
    options: dict,
    x0,
    mult_g=None,
    mult_x_L=None,
    mult_x_U=None,
    library_path: str | None = None,
):
    """Run ``IpoptSolve`` of the IPOPT library at ``library_path`` (default
    ``default_library_path()``); returns (status code, x, g, obj, mult_g, mult_x_L, mult_x_U)."""
    lib = library(library_path)
    jr, jc = (np.ascontiguousarray(a, dtype=np.int32) for a in jac_structure)
    hr, hc = (np.ascontiguousarray(a, dtype=np.int32) for a in hess_structure)
    nnz_j, nnz_h = jr.size, hr.size
    errors: list[BaseException] = []

    def guarded(fn):
        def wrapper(*args):
            if errors:
                return False
            try:
                return fn(*args)
            except BaseException as err:  # noqa: BLE001 - re-raised after IpoptSolve
                errors.append(err)
                return False

        return wrapper

    def point(x, new_x):
        if new_x:
            funcs["new_point"]()
        return np.array(_view(x, n))

    @guarded
    def eval_f(n_, x, new_x, obj, _):
        obj[0] = funcs["f"](point(x, new_x))
        return True

    @guarded
    def eval_g(n_, x, new_x, m_, g, _):
        _view(g, m)[:] = funcs["g"](point(x, new_x))
        return True

    @guarded
    def eval_grad(n_, x, new_x, grad, _):
        _view(grad, n)[:] = funcs["grad"](point(x, new_x))
        return True

    @guarded
    def eval_jac(n_, x, new_x, m_, nele, rows, cols, values, _):
        if not values:  # IPOPT asks for the pattern first
            _structure(rows, cols, jr, jc)
        else:
            _view(values, nnz_j)[:] = funcs["jac"](point(x, new_x))
        return True

    @guarded
    def eval_h(n_, x, new_x, obj_factor, m_, lam, new_lam, nele, rows, cols, values, _):
        if not values:
            _structure(rows, cols, hr, hc)
        else:
            _view(values, nnz_h)[:] = funcs["hess"](point(x, new_x), np.array(_view(lam, m)), obj_factor)
        return True

    @guarded
    def intermediate(*stats):
        funcs["intermediate"](*stats[:-1])
        return True

    # keep the ctypes trampolines alive for the whole solve
    cbs = (EVAL_F(eval_f), EVAL_G(eval_g), EVAL_GRAD_F(eval_grad), EVAL_JAC_G(eval_jac), EVAL_H(eval_h))
    bounds = [np.ascontiguousarray(a, dtype=float) for a in (xl, xu, gl, gu)]
    handle = lib.CreateIpoptProblem(
        n, _ptr(bounds[0]), _ptr(bounds[1]), m, _ptr(bounds[2]), _ptr(bounds[3]), nnz_j, nnz_h, 0, *cbs
    )
    if not handle:
        raise RuntimeError("IPOPT could not create the problem (CreateIpoptProblem returned NULL)")
    inter = INTERMEDIATE(intermediate)
    try:
        for key, val in options.items():
            add_option(handle, key, val, lib)
        lib.SetIntermediateCallback(handle, inter)
        x = np.array(x0, dtype=float)
        g, obj = np.zeros(m), np.zeros(1)
        lam = np.zeros(m) if mult_g is None else np.array(mult_g, dtype=float)
        zl = np.zeros(n) if mult_x_L is None else np.array(mult_x_L, dtype=float)
        zu = np.zeros(n) if mult_x_U is None else np.array(mult_x_U, dtype=float)
        status = lib.IpoptSolve(handle, _ptr(x), _ptr(g), _ptr(obj), _ptr(lam), _ptr(zl), _ptr(zu), None)
    finally:
        lib.FreeIpoptProblem(handle)
    if errors:
        raise errors[0]
    return int(status), x, g, float(obj[0]), lam, zl, zu
