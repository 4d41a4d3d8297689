"""jaxhumanoid: differentiable trajectory optimisation of planar articulated bodies (the paper's
humanoid or any planar chain) that make and break contacts with the ground on their own.

The public API (``import jaxhumanoid as jh``)::

    jh.PlanarChain(a, c, m, inertia, g=9.81, names=None)   # a body; jh.PlanarChain.humanoid() is Table I
    jh.ContactParams, jh.FootParams                        # the contact law (3)-(4), the foot of (5)
    jh.Task(name, start, goal, active, weights=jh.Weights(...)), jh.get_task("T1")
    jh.find_equilibrium(model, q_guess, active)            # a start posture that keeps the foot steady
    jh.solve(task, scheme="A,F+C,2S", solver="ipopt", N=100, T=5.0, model=..., contact=..., weights=...,
             settings=jh.SolveSettings(N1=30, handover="direct", ...))  # the strategy's settings
    jh.load_task_file("task.toml")                         # body, task and settings from a TOML file
    jh.build_problem("T1", "A,F+C,1S", N=20)               # one NLP of a task (its callbacks, bounds, guess)
    jh.enable_compilation_cache()                          # JAX's persistent cache: a second process compiles less

Importing the package turns on float64 in JAX (``jax_enable_x64``).
"""

import jaxhumanoid.runtime  # noqa: F401  (float64 before any array is made)
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp.tasks import Task, Weights, get_task
from jaxhumanoid.runtime import enable_compilation_cache
from jaxhumanoid.strategy.posture import Equilibrium, find_equilibrium
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.strategy.taskfile import load_task_file

__all__ = [
    "ContactParams",
    "Equilibrium",
    "FootParams",
    "PlanarChain",
    "Solution",
    "SolveSettings",
    "Task",
    "Weights",
    "build_problem",
    "enable_compilation_cache",
    "find_equilibrium",
    "get_task",
    "load_task_file",
    "solve",
]
__version__ = "0.1.0"
