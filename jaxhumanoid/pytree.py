"""The one way the package makes pytrees: frozen dataclasses whose fields are all leaves.

JAX rebuilds a pytree around tracers and cotangents when it transforms a function; the rebuilt
object bypasses ``__init__`` (and so ``__post_init__``), because a cotangent with a negative
entry is not an invalid model and a tracer cannot be validated. Validation runs only when a user
constructs an instance. ``dataclasses.replace`` works as for any dataclass (and validates).
"""

from __future__ import annotations

import dataclasses
from typing import TypeVar, dataclass_transform

import jax

T = TypeVar("T")


@dataclass_transform(frozen_default=True)
def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it with JAX, every field a pytree child."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    names = tuple(f.name for f in dataclasses.fields(cls))  # type: ignore[arg-type]  # cls is a dataclass now

    def flatten(obj):
        return tuple(getattr(obj, n) for n in names), None

    def unflatten(_, leaves):
        obj = object.__new__(cls)
        for n, v in zip(names, leaves):
            object.__setattr__(obj, n, v)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
    return cls
