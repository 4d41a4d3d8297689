"""The one way the package makes pytrees: frozen dataclasses whose fields are leaves or static.

A field is a pytree child unless it is declared ``static_field()`` (names, flags: hashable
metadata that JAX keeps in the tree structure, so a change recompiles). JAX rebuilds a pytree
around tracers and cotangents when it transforms a function; the rebuilt object bypasses
``__init__`` (and so ``__post_init__``), because a cotangent with a negative entry is not an
invalid model and a tracer cannot be validated. Validation runs only when a user constructs an
instance; ``dataclasses.replace`` works as for any dataclass (and validates).
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar, dataclass_transform

import jax

T = TypeVar("T")


def static_field(default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field kept in the pytree's structure instead of its leaves."""
    return dataclasses.field(default=default, metadata={"static": True})


@dataclass_transform(frozen_default=True, field_specifiers=(dataclasses.field, static_field))
def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass and register it with JAX (fields: children or static)."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    fields = dataclasses.fields(cls)  # type: ignore[arg-type]  # cls is a dataclass now
    return register(cls, static=tuple(f.name for f in fields if f.metadata.get("static")))


def register(cls: type[T], static: tuple[str, ...] = ()) -> type[T]:
    """Register the frozen dataclass ``cls`` with JAX: the fields named in ``static`` go to the
    tree structure, every other field is a child; unflattening bypasses ``__init__``."""
    fields = dataclasses.fields(cls)  # type: ignore[arg-type]
    leaves = tuple(f.name for f in fields if f.name not in static)
    static = tuple(f.name for f in fields if f.name in static)

    def flatten(obj):
        return tuple(getattr(obj, n) for n in leaves), tuple(getattr(obj, n) for n in static)

    def unflatten(meta, children):
        obj = object.__new__(cls)
        for n, v in zip(leaves + static, tuple(children) + tuple(meta)):
            object.__setattr__(obj, n, v)
        return obj

    jax.tree_util.register_pytree_node(cls, flatten, unflatten)
    return cls
