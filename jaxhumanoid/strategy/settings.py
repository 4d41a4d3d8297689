"""The strategy settings of ``solve``: one frozen, checked object (``SolveSettings``).

The everyday arguments of a solve (the task, the scheme, the solver, the grid N and horizon T, the
body, the laws, the weights, the solver options of every stage) are ``solve``'s own keywords. How
the strategy runs (Sec. III-A.3) is set here: stage 1's grid and law, the first guess, the
hand-over, the solver of the relaxed-law stages, per-stage solver options, the foot margin and the
units the NLPs are solved in. The object is checked when it is made, so a bad setting fails with a
ValueError naming its field before anything is built or solved.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxhumanoid.model.foot import FootMargin
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp.scaling import check_scaling
from jaxhumanoid.strategy.problem import DEFAULT_STRATEGY_GUESS, STRATEGY_GUESSES

SOLVERS = ("ipopt", "ipm", "casadi")
# Stage 1's grid when ``N1`` is not given: min(STAGE1_N, N), never finer than the final grid.
STAGE1_N = 30
HANDOVERS = ("direct", "continuation")
# Two steps from the relaxed to the nominal law: on 12 perturbed problems they reach the optima of
# four steps (the same on 7, lower on 2, at most 3e-3 higher on 3) with a median continuation of 55
# iterations against 79; one step reaches higher optima, up to 8 % (docs/decisions.md).
CONTINUATION_STEPS = 2
# The defaults of ``solve`` (docs/results.md measures the alternatives): stage 1 from the static
# path, checked (``problem.DEFAULT_STRATEGY_GUESS``), the continuation hand-over, and IPOPT for
# the relaxed-law stages, so that the far-start globalisation is one backend's and ``solver``
# decides the continuation to the nominal law, where every backend reaches the same optimum.
DEFAULT_HANDOVER = "continuation"
DEFAULT_STAGE1_SOLVER = "ipopt"
STAGE1_SOLVERS = (*SOLVERS, "same", None)
_OPTION_FIELDS = ("stage1_options", "stage2_options")


def is_count(value, low: int) -> bool:
    """Whether ``value`` is an integer (not a bool) >= low."""
    return bool(not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= low)


@dataclasses.dataclass(frozen=True)
class SolveSettings:
    """How ``solve`` runs its strategy (Sec. III-A.3); every field has the default of the package.

    ``N1``: intervals of stage 1 of 2S, the pseudo-static problem (8) on its coarse grid (the
    paper's N1 = 30); None: min(30, N), never finer than the final grid. An integer >= 3.

    ``stage1_options``, ``stage2_options``: solver options of stage 1 and of the dynamic stages, on
    top of ``solve``'s ``options`` (which apply to every stage); stored read-only.

    ``contact_stage1``: the relaxed contact law (3)-(4) of the relaxed-law stages of 2S (default
    ``ContactParams.relaxed()``; a step towards the dynamic law where it cannot seat the start,
    ``handover.relaxed_stage_problem``).

    ``guess``: the initial guess of the first stage (``problem.STRATEGY_GUESSES``): ``"linear"``, the
    paper's (Sec. II-G); ``"inverse_dynamics"``, the same motion with torques and forces that
    satisfy its dynamics; ``"static_path"``, postures the body can hold at rest; ``"both"``, stage 1
    of 2S from each of the last two, the solution of lower objective handed over; ``"auto"``
    (default), stage 1 of 2S from the static path, and from the inverse-dynamics guess as well
    where that run kept the path's detour (``stage_one.stage_one``). 1S starts from the
    inverse-dynamics guess under ``"both"`` and ``"auto"``.

    ``handover``: how 2S passes from stage 1 to stage 2 (``HANDOVERS``): ``"direct"``, the paper's,
    stage 2 solved once under the nominal law from stage 1's interpolated primal solution, or
    ``"continuation"`` (default), stage 2 solved along a path of ``continuation_steps`` laws from
    stage 1's to the nominal one (``handover.law_path``), each from the last one's solution.

    ``stage1_solver``: the solver of 2S's relaxed-law stages (``SOLVERS``; default IPOPT; ``"same"``
    or None: ``solve``'s ``solver``).

    ``foot_margin``: keeps the foot that far inside the edges of the steady-foot rows (5) in every
    stage (``model.foot.FootMargin``; None: no margin).

    ``scaling``: the units every backend solves the NLPs in (``ocp.scaling.SCALINGS``): ``"none"``
    (default), as posed; ``"physical"``, units of O(1) (torques in 10 N m, forces in 100 N, the
    objective in 100).

    Settings are static configuration, compared by value and never traced (docs/decisions.md).
    """

    N1: int | None = None
    stage1_options: Mapping[str, Any] | None = None
    stage2_options: Mapping[str, Any] | None = None
    contact_stage1: ContactParams | None = None
    guess: str = DEFAULT_STRATEGY_GUESS
    handover: str = DEFAULT_HANDOVER
    continuation_steps: int = CONTINUATION_STEPS
    stage1_solver: str | None = DEFAULT_STAGE1_SOLVER
    foot_margin: FootMargin | None = None
    scaling: str = "none"

    def __post_init__(self) -> None:
        for name, allowed in (("stage1_solver", STAGE1_SOLVERS), ("guess", STRATEGY_GUESSES), ("handover", HANDOVERS)):
            value = getattr(self, name)
            if not isinstance(value, (str, type(None))) or value not in allowed:
                raise ValueError(f"{name}: {value!r} not in {allowed}")
        check_scaling(self.scaling)
        if not is_count(self.continuation_steps, 1):
            raise ValueError(f"continuation_steps: expected an integer >= 1, got {self.continuation_steps!r}")
        if self.N1 is not None and not is_count(self.N1, 3):
            raise ValueError(f"N1: expected an integer number of intervals >= 3, got {self.N1!r}")
        for name, cls in (("contact_stage1", ContactParams), ("foot_margin", FootMargin)):
            value = getattr(self, name)
            if value is not None and not isinstance(value, cls):
                raise ValueError(f"{name}: expected a {cls.__name__} or None, got {type(value).__name__}")
        for name in _OPTION_FIELDS:
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
                raise ValueError(f"{name}: expected a dict of solver options or None, got {type(value).__name__}")
            object.__setattr__(self, name, types.MappingProxyType(dict(value)))

    def replace(self, **changes) -> SolveSettings:
        """These settings with ``changes`` (field -> value), checked as a new object is."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_mapping(cls, d: Mapping[str, Any], where: str) -> SolveSettings:
        """Settings from a mapping of field -> value (a task file's ``[solve]`` table, command-line
        flags); an unknown key or a bad value is a ValueError that starts with ``where``."""
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(str(k) for k in d if k not in names)
        if unknown:
            raise ValueError(f"{where}: unknown settings {unknown}; allowed: {sorted(names)}")
        try:
            return cls(**d)
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from err

    def merged_stage1_options(self, extra: Mapping[str, Any]) -> dict[str, Any]:
        """Stage 1's options with ``extra`` on top (a task file's, then a command line's or a
        study case's)."""
        return {**(self.stage1_options or {}), **extra}

    def stage1_grid(self, N: int) -> int:
        """N1 of a solve on an N-interval final grid."""
        return min(STAGE1_N, int(N)) if self.N1 is None else int(self.N1)

    def relaxed_solver(self, solver: str) -> str:
        """The solver of the relaxed-law stages of a solve whose ``solver`` is given."""
        return solver if self.stage1_solver in ("same", None) else str(self.stage1_solver)
