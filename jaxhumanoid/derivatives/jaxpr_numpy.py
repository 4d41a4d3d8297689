"""Evaluate a jaxpr with numpy, without compiling it: for functions evaluated a few times only.

Sparsity detection evaluates a dense Jacobian or Hessian of one interval at a few points. Under
``jax.jit`` that costs an XLA compilation of the whole derivative (seconds, for every layout of a
new problem); interpreted here, primitive by primitive on numpy arrays, it costs milliseconds.
The values agree with XLA's to rounding (other summation orders, no fused multiply-adds), which
is all a nonzero pattern needs.

``evaluator(fun, *example_args)`` traces ``fun`` once and returns ``call(*args)`` giving its
outputs as numpy arrays. A primitive that is not implemented raises ``Unsupported`` at the first
call; ``sparsity`` then compiles the function instead.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.extend import core as jcore


class Unsupported(NotImplementedError):
    """A primitive this interpreter does not implement."""


_UNARY: dict[str, Callable] = {
    "neg": np.negative,
    "sin": np.sin,
    "cos": np.cos,
    "tan": np.tan,
    "asin": np.arcsin,
    "acos": np.arccos,
    "atan": np.arctan,
    "sinh": np.sinh,
    "cosh": np.cosh,
    "tanh": np.tanh,
    "asinh": np.arcsinh,
    "acosh": np.arccosh,
    "atanh": np.arctanh,
    "exp": np.exp,
    "exp2": np.exp2,
    "log": np.log,
    "log1p": np.log1p,
    "expm1": np.expm1,
    "sqrt": np.sqrt,
    "rsqrt": lambda x: 1.0 / np.sqrt(x),
    "cbrt": np.cbrt,
    "abs": np.abs,
    "sign": np.sign,
    "floor": np.floor,
    "ceil": np.ceil,
    "round": np.round,
    "not": np.invert,
    "square": np.square,
    "is_finite": np.isfinite,
    "logistic": lambda x: 0.5 * (1.0 + np.tanh(0.5 * x)),
}
_BINARY: dict[str, Callable] = {
    "add": np.add,
    "add_any": np.add,
    "sub": np.subtract,
    "mul": np.multiply,
    "div": np.divide,
    "rem": np.fmod,
    "max": np.maximum,
    "min": np.minimum,
    "pow": np.power,
    "atan2": np.arctan2,
    "nextafter": np.nextafter,
    "eq": np.equal,
    "ne": np.not_equal,
    "lt": np.less,
    "le": np.less_equal,
    "gt": np.greater,
    "ge": np.greater_equal,
    "and": np.bitwise_and,
    "or": np.bitwise_or,
    "xor": np.bitwise_xor,
}
_REDUCE: dict[str, Callable] = {
    "reduce_sum": np.sum,
    "reduce_max": np.max,
    "reduce_min": np.min,
    "reduce_prod": np.prod,
    "reduce_and": np.all,
    "reduce_or": np.any,
}
_CUMULATIVE: dict[str, Callable] = {
    "cumsum": np.cumsum,
    "cumprod": np.cumprod,
    "cummax": np.maximum.accumulate,
    "cummin": np.minimum.accumulate,
}
# calls of inner jaxprs: the parameter that holds the jaxpr
_CALLS = {
    "jit": "jaxpr",
    "pjit": "jaxpr",
    "closed_call": "call_jaxpr",
    "core_call": "call_jaxpr",
    "remat": "jaxpr",
    "checkpoint": "jaxpr",
    "custom_jvp_call": "call_jaxpr",
    "custom_vjp_call": "call_jaxpr",
}
_IDENTITY = ("copy", "copy_p", "reduce_precision", "optimization_barrier", "stop_gradient")


def _closed(j):
    return (j.jaxpr, j.consts) if hasattr(j, "consts") else (j, ())


def _divide(x, y):
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.true_divide(x, y) if np.issubdtype(np.result_type(x, y), np.floating) else x // y


def _pad(a: np.ndarray, value, config) -> np.ndarray:
    """``lax.pad``: per dimension (low, high, interior), negative edges crop."""
    for d, (lo, hi, interior) in enumerate(config):
        if interior:
            n = a.shape[d]
            shape = list(a.shape)
            shape[d] = n + (n - 1) * interior if n else 0
            b = np.full(shape, value, dtype=a.dtype)
            b[(slice(None),) * d + (slice(0, None, interior + 1),)] = a
            a = b
        a = a[(slice(None),) * d + (slice(max(-lo, 0), a.shape[d] - max(-hi, 0)),)]
        widths = [(0, 0)] * a.ndim
        widths[d] = (max(lo, 0), max(hi, 0))
        a = np.pad(a, widths, constant_values=value)
    return a


def _starts(idx: np.ndarray, b, index_map, batching_dims, index_batching_dims, rank: int) -> list[int]:
    start = [0] * rank
    for k, od in enumerate(index_map):
        start[od] = int(idx[b + (k,)])
    for od, ib in zip(batching_dims, index_batching_dims):
        start[od] = b[ib]
    return start


def _fills(mode) -> bool:
    """Whether out-of-bounds windows are filled (gather) or dropped (scatter), not clamped."""
    return "FILL_OR_DROP" in str(mode)


def _gather(operand, indices, dn, slice_sizes, mode, fill_value) -> np.ndarray:
    idx = np.asarray(indices)
    batch_shape = idx.shape[:-1]
    kept = [d for d in range(operand.ndim) if d not in dn.collapsed_slice_dims and d not in dn.operand_batching_dims]
    rank = len(batch_shape) + len(kept)
    batch_dims = [d for d in range(rank) if d not in dn.offset_dims]
    shape = [0] * rank
    for d, s in zip(batch_dims, batch_shape):
        shape[d] = s
    for d, od in zip(dn.offset_dims, kept):
        shape[d] = slice_sizes[od]
    out = np.empty(shape, dtype=operand.dtype)
    # out[batch..., offset...] laid out with batch dims first, then moved into place
    stacked = out.transpose(batch_dims + list(dn.offset_dims))
    for b in np.ndindex(batch_shape):
        start = _starts(
            idx, b, dn.start_index_map, dn.operand_batching_dims, dn.start_indices_batching_dims, operand.ndim
        )
        inside = all(0 <= s <= operand.shape[d] - slice_sizes[d] for d, s in enumerate(start))
        if not inside and _fills(mode):
            stacked[b] = np.nan if fill_value is None and operand.dtype.kind == "f" else (fill_value or 0)
            continue
        start = [min(max(s, 0), operand.shape[d] - slice_sizes[d]) for d, s in enumerate(start)]
        window = operand[tuple(slice(s, s + z) for s, z in zip(start, slice_sizes))]
        stacked[b] = window.reshape([slice_sizes[d] for d in kept])
    return out


def _scatter(operand, indices, updates, dn, mode, combine) -> np.ndarray:
    out = np.array(operand, copy=True)
    idx = np.asarray(indices)
    batch_shape = idx.shape[:-1]
    window_dims = list(dn.update_window_dims)
    scatter_dims = [d for d in range(updates.ndim) if d not in window_dims]
    kept = [d for d in range(operand.ndim) if d not in dn.inserted_window_dims and d not in dn.operand_batching_dims]
    moved = updates.transpose(scatter_dims + window_dims)
    for b in np.ndindex(batch_shape):
        start = _starts(
            idx,
            b,
            dn.scatter_dims_to_operand_dims,
            dn.operand_batching_dims,
            dn.scatter_indices_batching_dims,
            operand.ndim,
        )
        window = moved[b]
        if not _fills(mode):  # clamped like a gather's window
            size = [1] * operand.ndim
            for d, z in zip(kept, window.shape):
                size[d] = z
            start = [min(max(s, 0), operand.shape[d] - size[d]) for d, s in enumerate(start)]
        for w in np.ndindex(window.shape):
            pos = list(start)
            for d, v in zip(kept, w):
                pos[d] += v
            if all(0 <= q < s for q, s in zip(pos, operand.shape)):  # out-of-bounds updates are dropped
                out[tuple(pos)] = combine(out[tuple(pos)], window[w])
    return out


def _scan(P: dict, ins: list) -> list:
    body = P["jaxpr"]
    nc, ncarry = P["num_consts"], P["num_carry"]
    consts, carry, xs = ins[:nc], list(ins[nc : nc + ncarry]), ins[nc + ncarry :]
    steps = range(P["length"] - 1, -1, -1) if P["reverse"] else range(P["length"])
    ys: list = []
    for i in steps:
        out = eval_jaxpr(body.jaxpr, body.consts, [*consts, *carry, *(x[i] for x in xs)])
        carry, y = out[:ncarry], out[ncarry:]
        ys.append(y)
    if P["reverse"]:
        ys.reverse()
    n_ys = len(body.jaxpr.outvars) - ncarry
    stacked = [np.stack([y[k] for y in ys]) if ys else np.zeros((0,)) for k in range(n_ys)]
    return [*carry, *stacked]


def _dot_general(a, b, dimension_numbers, preferred_element_type=None, **_):
    (ca, cb), (ba, bb) = dimension_numbers
    letters = iter("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ")
    sa = [next(letters) for _ in range(a.ndim)]
    sb = [next(letters) for _ in range(b.ndim)]
    for i, j in zip(ca, cb):
        sb[j] = sa[i]
    for i, j in zip(ba, bb):
        sb[j] = sa[i]
    free_a = [sa[d] for d in range(a.ndim) if d not in ca and d not in ba]
    free_b = [sb[d] for d in range(b.ndim) if d not in cb and d not in bb]
    out = "".join([sa[d] for d in ba] + free_a + free_b)
    res = np.einsum(f"{''.join(sa)},{''.join(sb)}->{out}", a, b)
    return res.astype(preferred_element_type) if preferred_element_type is not None else res


def _apply(name: str, params: dict, ins: list):
    P = params
    if name in _CALLS:
        sub = P.get(_CALLS[name]) or P.get("fun_jaxpr") or P.get("call_jaxpr")
        jaxpr, consts = _closed(sub)
        return eval_jaxpr(jaxpr, consts, ins[: len(jaxpr.invars)])
    if name in _IDENTITY:
        return ins if len(ins) > 1 else ins[0]
    if name in _UNARY:
        with np.errstate(all="ignore"):
            return np.asarray(_UNARY[name](ins[0]))
    if name in ("erf", "erfc", "lgamma", "digamma", "erf_inv"):
        import scipy.special  # noqa: PLC0415  (rare: only where a function uses them)

        fn = {"erf_inv": scipy.special.erfinv, "lgamma": scipy.special.gammaln, "digamma": scipy.special.psi}.get(name)
        return np.asarray((fn or getattr(scipy.special, name))(ins[0]))
    if name in _BINARY:
        with np.errstate(all="ignore"):
            out = _divide(*ins) if name == "div" else _BINARY[name](*ins)
        return np.asarray(out)
    a: Any = ins[0] if ins else np.zeros(())
    match name:
        case "integer_pow":
            return np.asarray(a ** P["y"], dtype=a.dtype)
        case "convert_element_type":
            return np.asarray(a).astype(np.dtype(P["new_dtype"]))
        case "select_n":
            return np.choose(np.asarray(ins[0], dtype=np.int64), ins[1:])
        case "clamp":
            return np.clip(ins[1], ins[0], ins[2])
        case "broadcast_in_dim":
            shape, dims = P["shape"], P["broadcast_dimensions"]
            expanded = [1] * len(shape)
            for i, d in enumerate(dims):
                expanded[d] = a.shape[i]
            return np.broadcast_to(a.reshape(expanded), shape)
        case "reshape":
            return np.reshape(a, P["new_sizes"])
        case "transpose":
            return np.transpose(a, P["permutation"])
        case "squeeze":
            return np.squeeze(a, axis=tuple(P["dimensions"]))
        case "expand_dims":
            return np.expand_dims(a, tuple(P["dimensions"]))
        case "rev":
            return np.flip(a, tuple(P["dimensions"]))
        case "slice":
            strides = P["strides"] or (1,) * a.ndim
            return a[tuple(slice(s, e, st) for s, e, st in zip(P["start_indices"], P["limit_indices"], strides))]
        case "concatenate":
            return np.concatenate(ins, axis=P["dimension"])
        case "pad":
            return _pad(a, ins[1][()], P["padding_config"])
        case "iota":
            shape, dim = P["shape"], P["dimension"]
            ramp = np.arange(shape[dim], dtype=np.dtype(P["dtype"]))
            return np.broadcast_to(ramp.reshape([-1 if d == dim else 1 for d in range(len(shape))]), shape)
        case "dynamic_slice":
            sizes = P["slice_sizes"]
            starts = [min(max(int(s), 0), a.shape[d] - sizes[d]) for d, s in enumerate(ins[1:])]
            return a[tuple(slice(s, s + z) for s, z in zip(starts, sizes))]
        case "dynamic_update_slice":
            upd = ins[1]
            starts = [min(max(int(s), 0), a.shape[d] - upd.shape[d]) for d, s in enumerate(ins[2:])]
            out = np.array(a, copy=True)
            out[tuple(slice(s, s + z) for s, z in zip(starts, upd.shape))] = upd
            return out
        case "gather":
            return _gather(a, ins[1], P["dimension_numbers"], P["slice_sizes"], P["mode"], P.get("fill_value"))
        case "scatter-add" | "scatter_add":
            return _scatter(a, ins[1], ins[2], P["dimension_numbers"], P["mode"], np.add)
        case "scatter":
            return _scatter(a, ins[1], ins[2], P["dimension_numbers"], P["mode"], lambda old, new: new)
        case "cond":
            branch = P["branches"][int(np.clip(ins[0], 0, len(P["branches"]) - 1))]
            return eval_jaxpr(branch.jaxpr, branch.consts, ins[1:])
        case "while":
            nc, nb = P["cond_nconsts"], P["body_nconsts"]
            cconsts, bconsts, carry = ins[:nc], ins[nc : nc + nb], ins[nc + nb :]
            cj, bj = P["cond_jaxpr"], P["body_jaxpr"]
            while eval_jaxpr(cj.jaxpr, cj.consts, [*cconsts, *carry])[0]:
                carry = eval_jaxpr(bj.jaxpr, bj.consts, [*bconsts, *carry])
            return carry
        case "scan":
            return _scan(P, ins)
        case "dot_general":
            return _dot_general(ins[0], ins[1], P["dimension_numbers"], P.get("preferred_element_type"))
        case "split":
            return np.split(a, np.cumsum(P["sizes"])[:-1], axis=P["axis"])
        case "stack":
            return np.stack(ins, axis=P["axis"])
        case "unstack":
            return [np.take(a, i, axis=P["axis"]) for i in range(a.shape[P["axis"]])]
        case "argmax" | "argmin":
            fn = np.argmax if name == "argmax" else np.argmin
            return fn(a, axis=P["axes"][0]).astype(np.dtype(P["index_dtype"]))
    if name in _REDUCE:
        return np.asarray(_REDUCE[name](a, axis=tuple(P["axes"])), dtype=a.dtype)
    if name in _CUMULATIVE:
        axis = P["axis"]
        src = np.flip(a, axis) if P["reverse"] else a
        out = _CUMULATIVE[name](src, axis=axis)
        return np.flip(out, axis) if P["reverse"] else out
    raise Unsupported(f"jaxpr_numpy: primitive {name!r} is not implemented")


def eval_jaxpr(jaxpr, consts, args) -> list:
    """The outputs of ``jaxpr`` at ``args`` (numpy arrays), every equation evaluated by numpy."""
    env: dict = {}

    def read(v):
        return np.asarray(v.val) if isinstance(v, jcore.Literal) else env[v]

    for v, c in zip(jaxpr.constvars, consts):
        env[v] = np.asarray(c)
    for v, a in zip(jaxpr.invars, args):
        env[v] = np.asarray(a)
    for eqn in jaxpr.eqns:
        outs: Any
        if eqn.primitive.name in ("empty", "empty2"):  # uninitialised buffers (a scan's transpose)
            zeros = [np.zeros(v.aval.shape, dtype=v.aval.dtype) for v in eqn.outvars]
            outs = zeros if eqn.primitive.multiple_results else zeros[0]
        else:
            outs = _apply(eqn.primitive.name, eqn.params, [read(v) for v in eqn.invars])
        if not eqn.primitive.multiple_results:
            outs = [outs]
        for v, o in zip(eqn.outvars, outs):
            if not isinstance(v, jcore.DropVar):
                env[v] = np.asarray(o)
    return [read(v) for v in jaxpr.outvars]


def evaluator(fun: Callable, *example_args) -> Callable:
    """``fun`` traced once at the shapes of ``example_args`` (pytrees); returns ``call(*args)``,
    its output pytree with numpy leaves, evaluated by ``eval_jaxpr``."""
    closed, out_shape = jax.make_jaxpr(fun, return_shape=True)(*example_args)
    out_tree = jax.tree_util.tree_structure(out_shape)

    def call(*args):
        leaves = [np.asarray(a) for a in jax.tree_util.tree_leaves(args)]
        return jax.tree_util.tree_unflatten(out_tree, eval_jaxpr(closed.jaxpr, closed.consts, leaves))

    return call


def cached_evaluator(fun: Callable, fallback: Callable | None = None) -> Callable:
    """``call(*args)`` evaluating ``fun`` by ``eval_jaxpr``, traced once per signature of its
    arguments (tree structure, shapes, dtypes). With ``fallback`` (e.g. ``jax.jit``), a function
    that uses a primitive not implemented here runs as ``fallback(fun)`` instead."""
    traced: dict = {}
    compiled: list = []

    def call(*args):
        if compiled:
            return compiled[0](*args)
        leaves, tree = jax.tree_util.tree_flatten(args)
        key = (tree, tuple((np.shape(a), str(a.dtype) if hasattr(a, "dtype") else type(a)) for a in leaves))
        try:
            if key not in traced:
                traced[key] = evaluator(fun, *args)
            return traced[key](*args)
        except Unsupported:
            if fallback is None:
                raise
            compiled.append(fallback(fun))
            return compiled[0](*args)

    return call
