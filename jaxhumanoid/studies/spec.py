"""Study specifications: a TOML file -> a list of cases, each one solve (or one inverse fit).

    name = "sweep-small"                  # optional
    kind = "solve"                        # "solve" (default) or "inverse" (multi-start weight fits)
    tasks = ["T3", "../bow_3link.toml"]   # paper keys or task files (relative to this file)
    schemes = ["A,F+C,1S"]                # default: the task file's, else A,F+C,2S
    solvers = ["ipopt"]                   # default: the task file's, else ipopt; innermost axis
    N = [10, 15]                          # default: the task file's, else 100
    T = [5.0]                             # default: the task file's, else 5
    N1 = [10]                             # stage-1 intervals of 2S (default min(30, N))
    scaling = "physical"                  # the NLPs' units (``ocp.scaling.SCALINGS``; default the task's)
    guess = "static_path"                 # the first stage's initial guess (``STRATEGY_GUESSES``; default the task's)
    contact_force_limit = 2.0             # cap on every body contact's normal force (M g, or "none";
                                          # default the task's)
    save = true                           # write each solution to DIR/cases/<id>/ (default true)
    [options]                             # solver options of every case (optional)
    tol = 1e-8
    [stage1_options]                      # IPOPT options of stage 1 of 2S, added to solve's (optional)
    mu_init = 1e-2
    [grid]                                # cartesian product of perturbations: lists of factors
    "weights.w_u" = [0.5, 1.0, 2.0]
    [random]                              # seeded draws, each a perturbed problem of every task
    draws = 8; seed = 0
    "contact.kappa" = { uniform = [0.5, 1.5] }        # factor uniform in [lo, hi]
    "weights.w_du" = { log_uniform = [0.5, 2.0] }     # factor log-uniform in [lo, hi]
    N = { choice = [50, 75] }; T = { uniform = [4.0, 6.0] }   # values, not factors
    start_deg = 2.0                       # start posture moved by +-2 deg per joint, then projected
    max_move = 0.1; max_redraws = 50      # onto the nearest static equilibrium (``run.perturbed_start``)

Perturbations (``FACTORS``) multiply the task's value: ``weights.*`` the cost weights of (7)
(``w_u`` one factor on every joint's weight), ``contact.*`` the law (3)-(4) of the dynamic
stage, ``body.*`` every link's mass, inertia, length (a and c together) or strength.

An inverse study (``kind = "inverse"``) takes ``tasks``, ``schemes``, ``N``, ``T``,
``methods = ["gn"]`` (``gn`` or ``lbfgs``), ``starts = K`` (start seeds 0..K-1, or
``seeds = [...]``), ``max_evals`` and ``recovery_rtol`` (default 1e-3): each case fits the weights
from one random start (``diff.inverse.perturbed_weights``).

Draw i of task k uses the generator seeded by (seed, crc32(k), i), so a draw does not depend
on how many others there are or in which order they run. A case's id is a short hash of its
canonical JSON parameters: the same parameters give the same id in every run (resume).
Every field is checked before any work, and an error names the field and what it allows.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import pathlib
import zlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from jaxhumanoid.ocp.scaling import SCALINGS
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, TASKS, get_task
from jaxhumanoid.runtime import read_toml
from jaxhumanoid.strategy.problem import STRATEGY_GUESSES
from jaxhumanoid.strategy.settings import SOLVERS
from jaxhumanoid.strategy.taskfile import load_task_file

KINDS = ("solve", "inverse")
FACTORS = (
    "weights.w_u",
    "weights.w_qd",
    "weights.w_dqd",
    "weights.w_du",
    "contact.kappa",
    "contact.f0",
    "contact.xhat",
    "contact.mu",
    "body.m",
    "body.inertia",
    "body.length",
    "body.u_max",
)
DISTRIBUTIONS = ("uniform", "log_uniform", "choice")
METHODS = ("gn", "lbfgs")
TOP_KEYS = {
    "solve": {"name", "kind", "tasks", "schemes", "solvers", "N", "T", "N1", "scaling", "save", "options", "grid"}
    | {"random", "contact_force_limit", "guess", "stage1_options"},
    "inverse": {"name", "kind", "tasks", "schemes", "N", "T", "methods", "starts", "seeds", "max_evals"}
    | {"recovery_rtol"},
}
RANDOM_KEYS = {"draws", "seed", "start_deg", "max_move", "max_redraws", "N", "T", *FACTORS}
DEFAULT_SCHEME = "A,F+C,2S"
MAX_MOVE = 0.1  # rad: the farthest the projection may move a perturbed start posture (max norm)
MAX_REDRAWS = 50
RECOVERY_RTOL = 1e-3


@dataclasses.dataclass(frozen=True)
class Case:
    """One solve of a study (or one inverse fit): everything needed to run it, JSON-able.

    task: as written in the spec (a key or a task file; ``task_path`` is where the file is);
    factors: (name, factor) pairs of ``FACTORS``; start_offset: the drawn joint offsets (rad,
    uniform in +-``start_deg``), projected onto a static equilibrium by the worker, which draws
    again (``draw_rng`` streams 1..``max_redraws``) when none lies within ``max_move``;
    draw: the index of the random draw (None without ``[random]``); problem: the id of the
    perturbed problem (the case without its solver), shared by the solvers of one problem.
    Inverse fits use ``method``, ``start_seed`` and ``max_evals``.
    """

    kind: str
    task: str
    scheme: str
    solver: str
    N: int | None
    T: float | None
    N1: int | None = None
    scaling: str | None = None
    contact_force_limit: float | str | None = None
    guess: str | None = None
    options: tuple[tuple[str, Any], ...] = ()
    stage1_options: tuple[tuple[str, Any], ...] = ()
    factors: tuple[tuple[str, float], ...] = ()
    start_offset: tuple[float, ...] | None = None
    start_deg: float = 0.0
    max_move: float = MAX_MOVE
    max_redraws: int = MAX_REDRAWS
    draw: int | None = None
    seed: int | None = None
    method: str | None = None
    start_seed: int | None = None
    max_evals: int | None = None
    save: bool = True
    task_path: str | None = dataclasses.field(default=None, compare=False)

    def params(self, with_solver: bool = True) -> dict[str, Any]:
        """The canonical parameters (everything but ``task_path``, ``save`` and an unset ``scaling``,
        ``contact_force_limit``, ``guess`` or ``stage1_options``, so that a case's id does not change
        where the spec leaves them to the task)."""
        d = dataclasses.asdict(self)
        d.pop("task_path")
        d.pop("save")
        for key in ("scaling", "contact_force_limit", "guess"):
            if d[key] is None:
                d.pop(key)
        d["options"] = dict(self.options)
        if self.stage1_options:
            d["stage1_options"] = dict(self.stage1_options)
        else:
            d.pop("stage1_options")
        d["factors"] = dict(self.factors)
        if not with_solver:
            d.pop("solver")
        return d

    @property
    def id(self) -> str:
        return short_hash(self.params())

    @property
    def problem(self) -> str:
        return short_hash(self.params(with_solver=False))


def short_hash(params: Mapping[str, Any]) -> str:
    """12 hex digits of the SHA-256 of the canonical JSON (sorted keys, repr of floats)."""
    text = json.dumps(params, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


@dataclasses.dataclass(frozen=True)
class Spec:
    """A checked study: its name, kind, cases and the settings the summary needs."""

    name: str
    kind: str
    cases: tuple[Case, ...]
    factor_names: tuple[str, ...]
    recovery_rtol: float = RECOVERY_RTOL
    path: str | None = None


# -- checks ---------------------------------------------------------------------------------------


def _list(field: str, value, kind: type | tuple[type, ...], allowed: Sequence | None = None) -> list:
    """A non-empty list of ``kind`` (a scalar is a list of one)."""
    values = value if isinstance(value, list) else [value]
    if not values:
        raise ValueError(f"{field}: expected a non-empty list, got []")
    for v in values:
        if isinstance(v, bool) or not isinstance(v, kind):
            names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
            raise ValueError(f"{field}: expected {names} values, got {v!r}")
        if allowed is not None and v not in allowed:
            raise ValueError(f"{field}: {v!r} not in {tuple(allowed)}")
    return values


def _positive(field: str, value: Any, integer: bool = False, minimum: float = 0.0) -> Any:
    """``value`` when it is a finite number (an integer with ``integer``) above ``minimum``."""
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok or not math.isfinite(value) or value <= minimum:
        what = "an integer" if integer else "a finite number"
        raise ValueError(f"{field}: expected {what} > {minimum:g}, got {value!r}")
    return value


def _check_keys(where: str, table: Mapping, allowed: set[str]) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ValueError(f"{where}{unknown[0]}: unknown field; allowed: {', '.join(sorted(allowed))}")


def _task(field: str, key: str, base: pathlib.Path) -> tuple[str, str | None, int, dict]:
    """(key as written, task file path or None, number of links, the file's [solve] scheme,
    solver, N and T as given), the file loaded and checked."""
    if key.upper() in TASKS or key in {t.name for t in TASKS.values()}:
        return key, None, get_task(key).n, {}
    path = (base / key).resolve()
    if not path.is_file():
        raise ValueError(f"{field}: {key!r} is neither a task in {tuple(TASKS)} nor a task file (looked for {path})")
    tf = load_task_file(path)
    return key, str(path), tf.model.n, tf.keywords


def _distribution(field: str, value) -> tuple[str, list]:
    if not isinstance(value, dict) or len(value) != 1 or next(iter(value)) not in DISTRIBUTIONS:
        raise ValueError(f"{field}: expected one of {{ {' | '.join(f'{d} = [...]' for d in DISTRIBUTIONS)} }}")
    ((dist, args),) = value.items()
    if dist == "choice":
        return dist, _list(f"{field}.choice", args, (int, float))
    if not isinstance(args, list) or len(args) != 2:
        raise ValueError(f"{field}.{dist}: expected [lo, hi], got {args!r}")
    lo, hi = (_positive(f"{field}.{dist}", a) if dist == "log_uniform" else a for a in args)
    if isinstance(lo, bool) or not isinstance(lo, (int, float)) or not isinstance(hi, (int, float)) or not lo <= hi:
        raise ValueError(f"{field}.{dist}: expected numbers lo <= hi, got {args!r}")
    return dist, [float(lo), float(hi)]


def _check_random(table: Mapping) -> dict[str, Any]:
    _check_keys("random.", table, RANDOM_KEYS)
    out: dict[str, Any] = {
        "draws": _positive("random.draws", table.get("draws", 1), integer=True),
        "seed": table.get("seed", 0),
        "start_deg": table.get("start_deg", 0.0),
        "max_move": float(_positive("random.max_move", table.get("max_move", MAX_MOVE))),
        "max_redraws": table.get("max_redraws", MAX_REDRAWS),
    }
    if isinstance(out["seed"], bool) or not isinstance(out["seed"], int) or out["seed"] < 0:
        raise ValueError(f"random.seed: expected an integer >= 0, got {out['seed']!r}")
    if not isinstance(out["max_redraws"], int) or out["max_redraws"] < 0:
        raise ValueError(f"random.max_redraws: expected an integer >= 0, got {out['max_redraws']!r}")
    deg = out["start_deg"]
    if isinstance(deg, bool) or not isinstance(deg, (int, float)) or not 0 <= deg <= 45:
        raise ValueError(f"random.start_deg: expected an offset in [0, 45] degrees, got {out['start_deg']!r}")
    out["dists"] = {k: _distribution(f"random.{k}", v) for k, v in table.items() if k in (*FACTORS, "N", "T")}
    for k, (dist, args) in out["dists"].items():
        if k != "N" and min(args) <= 0:
            raise ValueError(f"random.{k}: expected positive {'values' if k == 'T' else 'factors'}, got {dist} {args}")
    if "N" in out["dists"]:
        dist, args = out["dists"]["N"]
        if dist != "choice" or any(not isinstance(n, int) or n < 3 for n in args):
            raise ValueError(f"random.N: expected {{ choice = [grid sizes >= 3] }}, got {dist} {args}")
    return out


def _check_grid(table: Mapping) -> dict[str, list[float]]:
    _check_keys("grid.", table, set(FACTORS))
    grid = {}
    for k, v in table.items():
        grid[k] = [float(_positive(f"grid.{k}", f)) for f in _list(f"grid.{k}", v, (int, float))]
    return grid


def _axes(data: Mapping, field: str, kind, default, check) -> list:
    if field not in data:
        return [default]
    return [check(f"{field}", v) for v in _list(field, data[field], kind)]


def _grid_size(field: str, v):
    if v < 3:
        raise ValueError(f"{field}: expected grid sizes >= 3, got {v!r}")
    return int(v)


# -- random draws ---------------------------------------------------------------------------------


def draw_rng(seed: int, task: str, index: int, stream: int) -> np.random.Generator:
    """The generator of draw ``index`` of ``task``; ``stream`` 0 for the values, 1.. for redraws."""
    return np.random.default_rng([seed, zlib.crc32(task.encode()), index, stream])


def sample(dist: str, args: list, rng: np.random.Generator) -> Any:
    """One value of a distribution (``DISTRIBUTIONS``) from ``rng``. Log-uniform values go
    through the C library's ``exp`` and ``log`` (nearly correctly rounded), not numpy's, whose
    vectorised kernels round the last bit differently from one CPU to another: a case's id hashes
    its values, so the same spec must draw the same bits everywhere."""
    if dist == "uniform":
        return float(rng.uniform(*args))
    if dist == "log_uniform":
        return math.exp(float(rng.uniform(math.log(args[0]), math.log(args[1]))))
    return args[int(rng.integers(len(args)))]


def draw_values(random: Mapping[str, Any], task: str, n: int, index: int) -> dict[str, Any]:
    """Draw ``index`` of ``task`` (n links): every distribution in name order, then the offset."""
    rng = draw_rng(random["seed"], task, index, 0)
    values: dict[str, Any] = {}
    for k in sorted(random["dists"]):
        dist, args = random["dists"][k]
        values[k] = sample(dist, args, rng)
    if random["start_deg"] > 0:
        offset = np.deg2rad(rng.uniform(-random["start_deg"], random["start_deg"], n))
        values["start_offset"] = tuple(float(x) for x in offset)
    return values


# -- expansion ------------------------------------------------------------------------------------


def _solve_cases(data: Mapping, base: pathlib.Path) -> tuple[list[Case], tuple[str, ...]]:
    tasks = [_task(f"tasks[{i}]", t, base) for i, t in enumerate(_list("tasks", data["tasks"], str))]
    schemes = _list("schemes", data["schemes"], str) if "schemes" in data else [None]
    for s in schemes:
        try:
            parse_scheme(s or DEFAULT_SCHEME)
        except ValueError as err:
            raise ValueError(f"schemes: {err}") from err
    solvers = _list("solvers", data["solvers"], str, SOLVERS) if "solvers" in data else [None]
    Ns = _axes(data, "N", int, None, _grid_size)
    Ts = _axes(data, "T", (int, float), None, lambda f, v: float(_positive(f, v)))
    N1s = _axes(data, "N1", int, None, _grid_size)
    save = data.get("save", True)
    if not isinstance(save, bool):
        raise ValueError(f"save: expected true or false, got {save!r}")
    scaling = data.get("scaling")
    if scaling is not None and scaling not in SCALINGS:
        raise ValueError(f"scaling: expected one of {SCALINGS}, got {scaling!r}")
    guess = data.get("guess")
    if guess is not None and guess not in STRATEGY_GUESSES:
        raise ValueError(f"guess: expected one of {STRATEGY_GUESSES}, got {guess!r}")
    cap = data.get("contact_force_limit")
    if cap is not None and cap != NO_FORCE_LIMIT:
        try:
            cap = float(_positive("contact_force_limit", cap))
        except ValueError:
            want = f"body weights > 0 or {NO_FORCE_LIMIT!r}"
            raise ValueError(f"contact_force_limit: expected {want}, got {cap!r}") from None
    options = data.get("options", {})
    if not isinstance(options, dict):
        raise ValueError(f"options: expected a table of solver options, got {options!r}")
    stage1_options = data.get("stage1_options", {})
    if not isinstance(stage1_options, dict):
        raise ValueError(f"stage1_options: expected a table of IPOPT options, got {stage1_options!r}")
    grid = _check_grid(data.get("grid", {}))
    random = _check_random(data["random"]) if "random" in data else None
    for name in grid:
        if random and name in random["dists"]:
            raise ValueError(f"random.{name}: also under [grid]; give it in one of them")
    for axis in ("N", "T"):
        if random and axis in random["dists"] and axis in data:
            raise ValueError(f"{axis}: give it as a list or under [random], not both")
    names = tuple(sorted({*grid, *(k for k in (random or {"dists": {}})["dists"] if k in FACTORS)}))
    grid_points = [dict(zip(grid, p)) for p in itertools.product(*grid.values())]
    draws = range(random["draws"]) if random else [None]
    cases = []
    for (key, path, n, settings), scheme, N, T, N1, point, draw in itertools.product(
        tasks, schemes, Ns, Ts, N1s, grid_points, draws
    ):
        drawn = draw_values(random, key, n, draw) if random is not None and draw is not None else {}
        factors = {**point, **{k: v for k, v in drawn.items() if k in FACTORS}}
        for solver in solvers:
            cases.append(
                Case(
                    kind="solve",
                    task=key,
                    scheme=scheme or settings.get("scheme", DEFAULT_SCHEME),
                    solver=solver or settings.get("solver", "ipopt"),
                    N=int(drawn.get("N", N)) if drawn.get("N", N) is not None else None,
                    T=float(drawn.get("T", T)) if drawn.get("T", T) is not None else None,
                    N1=N1,
                    scaling=scaling,
                    contact_force_limit=cap,
                    guess=guess,
                    options=tuple(sorted(options.items())),
                    stage1_options=tuple(sorted(stage1_options.items())),
                    factors=tuple(sorted(factors.items())),
                    start_offset=drawn.get("start_offset"),
                    start_deg=random["start_deg"] if random else 0.0,
                    max_move=random["max_move"] if random else MAX_MOVE,
                    max_redraws=random["max_redraws"] if random else MAX_REDRAWS,
                    draw=draw,
                    seed=random["seed"] if random else None,
                    save=save,
                    task_path=path,
                )
            )
    return cases, names


def _inverse_cases(data: Mapping, base: pathlib.Path) -> list[Case]:
    tasks = [_task(f"tasks[{i}]", t, base) for i, t in enumerate(_list("tasks", data["tasks"], str))]
    schemes = _list("schemes", data.get("schemes", ["A,F+C,1S"]), str)
    for s in schemes:
        if parse_scheme(s).stages != 1:
            raise ValueError(f"schemes: an inverse fit solves one stage (…,1S), got {s!r}")
    Ns = _axes(data, "N", int, 15, _grid_size)
    Ts = _axes(data, "T", (int, float), 5.0, lambda f, v: float(_positive(f, v)))
    methods = _list("methods", data.get("methods", ["gn"]), str, METHODS)
    if "starts" in data and "seeds" in data:
        raise ValueError("starts, seeds: give one of them")
    if "seeds" in data:
        seeds = _list("seeds", data["seeds"], int)
    else:
        seeds = list(range(_positive("starts", data.get("starts", 5), integer=True)))
    max_evals = data.get("max_evals")
    if max_evals is not None:
        _positive("max_evals", max_evals, integer=True)
    cases = []
    for (key, path, _, _), scheme, N, T, method, seed in itertools.product(tasks, schemes, Ns, Ts, methods, seeds):
        cases.append(
            Case(
                kind="inverse",
                task=key,
                scheme=scheme,
                solver="ipopt",
                N=N,
                T=T,
                method=method,
                start_seed=seed,
                max_evals=max_evals,
                task_path=path,
            )
        )
    return cases


def parse_spec(data: Mapping[str, Any], base: pathlib.Path | str = ".", path: str | None = None) -> Spec:
    """Check a spec's fields (the module docstring) and expand it into cases; task files are
    looked up relative to ``base``. Raises ValueError naming the field."""
    kind = data.get("kind", "solve")
    if kind not in KINDS:
        raise ValueError(f"kind: {kind!r} not in {KINDS}")
    _check_keys("", data, TOP_KEYS[kind])
    if "tasks" not in data:
        raise ValueError("tasks: required (paper keys T1..T4 or task files)")
    name = data.get("name", pathlib.Path(path).stem if path else "study")
    if not isinstance(name, str) or not name:
        raise ValueError(f"name: expected a non-empty string, got {name!r}")
    base = pathlib.Path(base)
    if kind == "solve":
        cases, names = _solve_cases(data, base)
        rtol = RECOVERY_RTOL
    else:
        cases, names = _inverse_cases(data, base), ()
        rtol = float(_positive("recovery_rtol", data.get("recovery_rtol", RECOVERY_RTOL)))
    ids = [c.id for c in cases]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ValueError(f"tasks/axes: the spec lists the same case twice (id {dup}); remove the repeated value")
    return Spec(name, kind, tuple(cases), names, rtol, path)


def load_spec(path) -> Spec:
    """Read, check and expand a spec file (see the module docstring)."""
    path = pathlib.Path(path)
    data = read_toml(path, "spec")
    try:
        return parse_spec(data, path.parent, str(path))
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from err
