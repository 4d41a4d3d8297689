"""Monte-Carlo execution of a plan: perturbed bodies, laws and starts, open loop against TVLQR
(and, with ``track(safety=...)``, TVLQR through the steady-foot QP filter of ``tracking.filter``).

Each trial draws (uniformly, from one seeded generator) link masses scaled by 1 +- ``mass`` and
lengths by 1 +- ``length`` (lengths scale a and c together; inertia scales with mass x length^2),
kappa and f0 scaled by 1 +- ``contact``, mu by 1 +- ``friction``, a start posture moved by up to
``start_rad`` per joint and then put back into static equilibrium for the *perturbed* body and law
(``_seat``: kept when it already keeps the foot steady with the small margins of ``START_SPEC``,
else its loaded contacts are moved back by millimetres to carry the plan's start forces, and only
then the nearest such posture is searched; a draw whose body and law can hold none within
``MAX_SEAT_MOVE`` is drawn again and counted in ``rejected_draws``), and Gaussian torque noise of
``torque_noise_Nm`` per joint, held over each plan interval. Each trial starts at rest with the
torques that hold it there, and that start is blended into the plan over ``start_blend_s``
(``simulator.rollout``). The policies run on the same draws, all trials as one ``vmap`` batch;
the gains are computed once, for the nominal body (the controller does not know the perturbation).

A trial succeeds when, at the end of the plan plus the hold, every joint angle lies within the goal
box widened by ``goal_slack`` (the plans end on the box's faces, so an unwidened box turns any
error into a coin flip), and at every step the foot stays steady and no joint is deeper than
``max_depth`` below the ground. The steady-foot test is (5) with the weight of the foot itself
added to f_n0 (``foot_mass_fraction`` of the body mass, Winter's 1.45 %): the model's foot is
massless, so a real foot is not lifted by the first newton of pull. The first failure names the
reason: ``foot lifts`` (5a), ``foot slips`` (5b), ``foot tips`` (5c), ``segment through the ground``,
``integrator failed`` (a Newton solve that did not converge), else ``goal missed``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.strategy.posture import MarginSpec, find_equilibrium, margins, seat_with_forces
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.tracking.filter import SafetyFilter, shield
from jaxhumanoid.tracking.lqr import DEFAULT_WEIGHTS, LQRWeights, check_number_fields, tvlqr_gains
from jaxhumanoid.tracking.plan import Goal, check_substeps, plant_and_goal, reference
from jaxhumanoid.tracking.simulator import Plant, Reference, Rollout, rollout

FOOT_REASONS = ("foot lifts", "foot slips", "foot slips", "foot tips", "foot tips")
RESIDUAL_FAIL = 1e-6  # scaled Newton residual above which a step counts as not converged


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """Half-widths of the uniform draws (fractions), the start offset (rad) and the torque noise
    (N m, standard deviation per joint, held over each plan interval). ``Perturbation.zero()`` draws nothing."""

    mass: float = 0.10
    length: float = 0.10
    contact: float = 0.50
    friction: float = 0.30
    start_rad: float = 0.02
    torque_noise_Nm: float = 5.0

    def __post_init__(self):
        check_number_fields(self, strict=False)
        for name in ("mass", "length", "contact", "friction"):
            if getattr(self, name) >= 1:
                raise ValueError(f"Perturbation.{name}: expected a fraction below 1, got {getattr(self, name)!r}")

    @classmethod
    def zero(cls) -> Perturbation:
        return cls(**{f.name: 0.0 for f in dataclasses.fields(cls)})


@dataclasses.dataclass(frozen=True)
class Criteria:
    """What success means (module docstring): goal_slack (rad), max_depth (m), foot_mass_fraction."""

    goal_slack: float = 0.02
    max_depth: float = 0.10
    foot_mass_fraction: float = 0.0145

    def __post_init__(self):
        check_number_fields(self, strict=False)


@dataclasses.dataclass
class Draw:
    """The draws of one trial (scales are factors on the nominal values)."""

    mass_scale: list[float]
    length_scale: list[float]
    kappa_scale: float
    f0_scale: float
    mu_scale: float
    start_offset: list[float]
    start_q: list[float]
    start_reseated: bool
    start_u: list[float] = dataclasses.field(default_factory=list)  # torques holding start_q at rest (N m)


def perturbed_plant(plant: Plant, d: Draw) -> Plant:
    """The nominal plant with the trial's scales applied (inertia ~ mass x length^2)."""
    b, law = plant.model, plant.contact
    sm, sl = np.asarray(d.mass_scale), np.asarray(d.length_scale)
    model = dataclasses.replace(b, a=b.a * sl, c=b.c * sl, m=b.m * sm, inertia=b.inertia * sm * sl**2)
    contact = ContactParams(
        kappa=law.kappa * d.kappa_scale, f0=law.f0 * d.f0_scale, xhat=law.xhat, mu=law.mu * d.mu_scale
    )
    return Plant(model, plant.foot, contact)


MAX_SEAT_MOVE = 0.05  # rad: a re-seated start further than this from the moved plan start is rejected
START_SPEC = MarginSpec(load_min=0.02, friction_margin=0.05, cop_margin=0.005, clearance=0.005)


def _seat(plant: Plant, nominal: Plant, q_plan, q_guess, active) -> tuple[np.ndarray, bool]:
    """A static start posture near q_guess (n,) for ``plant``: q_guess when it keeps the foot steady
    (``START_SPEC``), else the nearest such posture; a ValueError when none lies within
    MAX_SEAT_MOVE of q_guess.

    A moved or rescaled body lying on the ground presses a contact centimetres into it or lifts it
    off: the loaded contacts are first put back, by the least joint motion, where the plant's law
    carries the normal forces the plan's start q_plan carries on the ``nominal`` plant, scaled by
    the ratio of the body masses (``seat_with_forces``). Only when that posture still does not keep
    the foot steady does ``find_equilibrium`` search, from there.
    """
    seat = lambda q: margins(plant.model, q, active, contact=plant.contact, foot=plant.foot, spec=START_SPEC).ok  # noqa: E731
    q_guess = np.asarray(q_guess, dtype=float)
    if seat(q_guess):
        return q_guess, False
    forces = margins(nominal.model, q_plan, active, contact=nominal.contact, foot=nominal.foot).forces[:, 1]
    ratio = float(np.sum(np.asarray(plant.model.m)) / np.sum(np.asarray(nominal.model.m)))
    q = seat_with_forces(plant.model, plant.foot, plant.contact, q_guess, active, ratio * forces)
    if not seat(q):
        q = find_equilibrium(plant.model, q, active, contact=plant.contact, foot=plant.foot, spec=START_SPEC).q
    moved = float(np.max(np.abs(q - q_guess)))
    if moved > MAX_SEAT_MOVE:
        raise ValueError(f"start: the nearest seated posture is {moved:.3f} rad away (> {MAX_SEAT_MOVE} rad)")
    return q, True


MAX_REJECTED_PER_TRIAL = 10


def draw_trials(plant: Plant, q_start, active, trials: int, perturbation: Perturbation, seed: int):
    """``trials`` draws from the generator of ``seed`` (the first trial is always unperturbed), and
    the number of draws rejected because the perturbed body and law can hold no start posture near
    the moved one with the foot steady (they are drawn again)."""
    rng = np.random.default_rng(seed)
    n, p = plant.model.n, perturbation
    out: list[Draw] = []
    rejected = 0
    while len(out) < trials:
        w = 0.0 if not out else 1.0
        u = lambda k, h: np.ones(k) + w * h * rng.uniform(-1, 1, k)  # noqa: E731
        sm, sl, (sk, sf), (smu,) = u(n, p.mass), u(n, p.length), u(2, p.contact), u(1, p.friction)
        offset = w * p.start_rad * rng.uniform(-1, 1, n)
        d = Draw(sm.tolist(), sl.tolist(), float(sk), float(sf), float(smu), offset.tolist(), [], False)
        try:
            trial = perturbed_plant(plant, d)
            q0, moved = _seat(trial, plant, q_start, np.asarray(q_start) + offset, active)
        except ValueError:
            rejected += 1
            if rejected > MAX_REJECTED_PER_TRIAL * trials or not out:
                raise
            continue
        d.start_q, d.start_reseated = q0.tolist(), bool(moved)
        d.start_u = margins(trial.model, q0, active, contact=trial.contact, foot=trial.foot).u.tolist()
        out.append(d)
    return out, rejected


def _stack(plants: list[Plant]) -> Plant:
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x, dtype=jnp.float64) for x in xs]), *plants)


@functools.partial(jax.jit, static_argnums=1, static_argnames="safety")
def batch_rollout(
    plants: Plant, active: tuple, ref: Reference, x0, gains, noise, u_max, u_hold, blend, nominal=None, safety=None
) -> Rollout:
    """``rollout`` over a batch of plants (stacked leaves), starts (K, 2n), noise (K, M, n) and
    holding torques (K, n), with one start blend (M,); with ``safety`` (a ``SafetyFilter``) the
    torques pass through the steady-foot filter on the ``nominal`` plant (the controller's model)."""
    guard = None if safety is None else shield(nominal, active, ref.dt, u_max, safety)
    run = lambda pl, x, w, uh: rollout(pl, active, ref, x, gains, w, u_max, uh, blend, guard)  # noqa: E731
    return jax.vmap(run)(plants, x0, noise, u_hold)


def start_blend(t, blend_s: float) -> np.ndarray:
    """The weight of the start offset at the step times t (M,): 1 at t = 0, falling as
    (1 + cos(pi t / blend_s)) / 2 to 0 at blend_s (zero everywhere when blend_s = 0)."""
    t = np.asarray(t, dtype=float)
    if blend_s <= 0:
        return np.zeros_like(t)
    return np.where(t < blend_s, 0.5 * (1.0 + np.cos(np.pi * np.minimum(t, blend_s) / blend_s)), 0.0)


_gains = jax.jit(tvlqr_gains, static_argnums=(1, 3))


def weighted_foot_margins(foot_margins, plant: Plant, criteria: Criteria) -> np.ndarray:
    """The (5) products (..., 5) with the foot's own weight added to f_n0 (module docstring)."""
    b = plant.model
    weight = criteria.foot_mass_fraction * float(np.sum(np.asarray(b.m))) * float(b.g)
    mu = float(plant.contact.mu)
    return np.asarray(foot_margins) + weight * np.array([1.0, mu, mu, float(plant.foot.a0f), float(plant.foot.a0b)])


def tightest_foot_margin(foot_margins, plant: Plant, criteria: Criteria) -> np.ndarray:
    """The smallest of the weighted (5) products per step in units of body weight M g (the
    centre-of-pressure rows divided by the sole's half-lengths too), shape (...,): < 0 is a fall."""
    b, f = plant.model, plant.foot
    unit = float(np.sum(np.asarray(b.m))) * float(b.g) * np.array([1.0, 1.0, 1.0, float(f.a0f), float(f.a0b)])
    return np.min(weighted_foot_margins(foot_margins, plant, criteria) / unit, axis=-1)


def judge(r: Rollout, t, plant: Plant, goal: Goal, criteria: Criteria) -> dict[str, Any]:
    """Success, final error (rad, max over joints of |q(end) - goal|), whether the goal box was
    reached whatever happened on the way (``goal_reached``) and the first failure (its reason and
    time) of one trial's rollout (numpy arrays of one trial) on its own plant."""
    foot_bad = weighted_foot_margins(r.foot_margins, plant, criteria) < 0  # (M, 5)
    events = {
        "integrator failed": np.asarray(r.residual) > RESIDUAL_FAIL,
        "segment through the ground": np.any(np.asarray(r.gaps) < -criteria.max_depth, axis=1),
        **{reason: np.zeros(foot_bad.shape[0], bool) for reason in FOOT_REASONS},
    }
    for row, reason in enumerate(FOOT_REASONS):
        events[reason] = events[reason] | foot_bad[:, row]
    first = {k: int(np.argmax(v)) for k, v in events.items() if np.any(v)}
    q_end = np.asarray(r.x)[-1, : goal.q.size]
    final_error = float(np.max(np.abs(q_end - goal.q)))
    reached = bool(final_error <= goal.tolerance + criteria.goal_slack)
    out = {"success": reached and not first, "final_error": final_error, "goal_reached": reached}
    if first:
        reason = min(first, key=lambda k: first[k])
        return {**out, "reason": reason, "t_fail": float(t[first[reason] + 1])}
    return {**out, "reason": None if reached else "goal missed", "t_fail": None}


SLACK_ACTIVE = 1e-4  # body weights: a filter slack above this means its foot rows could not be met
SLACK_LOOKBACK_S = 0.05  # s: a failure counts as after an infeasible filter step if one lies this close before it


def filter_report(r: Rollout, t, verdict: dict, noise_every: int) -> dict[str, Any]:
    """What the safety filter did in one trial up to its first failure (after it the body is
    falling and the numbers say nothing): steps where its slack was active (the linearised foot
    rows could not be met within the strengths), the first such time, the largest slack (body
    weights), KKT residual and torque change (N m), whether a slack was active within
    SLACK_LOOKBACK_S before the first failure (``verdict`` from ``judge``), and whether that failure
    came at the first step of a new torque-noise draw (held over ``noise_every`` steps): a change
    no controller sees before it acts."""
    t_step = np.asarray(t)[1 : np.asarray(r.filter_slack).size + 1]
    upto = t_step <= (np.inf if verdict["t_fail"] is None else verdict["t_fail"])
    slack, resid, change = (np.asarray(a)[upto] for a in (r.filter_slack, r.filter_residual, r.filter_change))
    active = slack > SLACK_ACTIVE
    t_step = t_step[upto]
    out = {
        "slack_steps": int(np.sum(active)),
        "t_first_slack": float(t_step[np.argmax(active)]) if np.any(active) else None,
        "max_slack_bw": float(np.max(slack)),
        "max_qp_residual": float(np.max(resid)),
        "max_change_Nm": float(np.max(change)),
        "slack_before_failure": None,
        "at_noise_change": None,
    }
    if verdict["t_fail"] is not None:
        out["slack_before_failure"] = bool(np.any(active & (t_step >= verdict["t_fail"] - SLACK_LOOKBACK_S)))
        j = int(np.argmin(np.abs(np.asarray(t)[1:] - verdict["t_fail"])))  # the failing step
        out["at_noise_change"] = j % noise_every == 0
    return out


@dataclasses.dataclass
class TrackingResult:
    """tracking.json's record, plus the batch arrays the figures need (not written to JSON):
    open_loop / closed_loop (/ qp_filter) rollouts with leading trial axis, the reference and the
    gains. ``qp_filter_success_rate`` and ``safety_filter`` are None when the filter did not run."""

    task: str
    trials: int
    seed: int
    substeps: int
    hold_s: float
    start_blend_s: float
    perturbation: dict
    criteria: dict
    weights: dict
    rejected_draws: int
    open_loop_success_rate: float
    closed_loop_success_rate: float
    records: list[dict]
    timing_s: dict
    reference: Reference = dataclasses.field(repr=False)
    open_loop: Rollout = dataclasses.field(repr=False)
    closed_loop: Rollout = dataclasses.field(repr=False)
    goal: Goal = dataclasses.field(repr=False)
    plant: Plant = dataclasses.field(repr=False)
    qp_filter_success_rate: float | None = None
    safety_filter: dict | None = None
    qp_filter: Rollout | None = dataclasses.field(default=None, repr=False)

    def trial_plant(self, trial: int) -> Plant:
        """The perturbed plant of one trial."""
        return perturbed_plant(self.plant, Draw(**self.records[trial]["perturbation"]))

    def to_json(self) -> dict:
        keys = [f.name for f in dataclasses.fields(self) if f.repr]
        return {k: getattr(self, k) for k in keys}

    def save(self, out_dir) -> pathlib.Path:
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        path = out / "tracking.json"
        path.write_text(json.dumps(self.to_json(), indent=2) + "\n")
        return path


def _check_int(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
    return int(value)


def as_solution(solution_or_dir) -> Solution:
    if isinstance(solution_or_dir, Solution):
        return solution_or_dir
    path = pathlib.Path(solution_or_dir)
    if not (path / "solution.npz").is_file():
        what = "has no solution.npz" if path.is_dir() else "is not a directory"
        raise ValueError(
            f"solution: {str(path)!r} {what}; give a Solution or a directory written by `jaxhumanoid solve`"
        )
    return Solution.load(path)


def track(
    solution_or_dir,
    trials: int = 100,
    seed: int = 0,
    substeps: int = 10,
    hold_s: float = 0.5,
    perturbation: Perturbation = Perturbation(),
    criteria: Criteria = Criteria(),
    weights: LQRWeights = DEFAULT_WEIGHTS,
    progress=None,
    start_blend_s: float = 1.0,
    safety: SafetyFilter | None = None,
) -> TrackingResult:
    """Run ``trials`` perturbed executions of a plan open loop and under TVLQR (module docstring).

    ``solution_or_dir``: a ``Solution`` or a directory written by ``jaxhumanoid solve``;
    ``substeps``: simulator steps per plan interval; ``hold_s``: seconds the final state is held
    after the horizon; ``progress``: an ``jaxhumanoid.progress.Progress``-like object with
    ``start(label)`` / ``finish(message)`` (or None); ``start_blend_s``: seconds over which the
    trial's start (its posture and holding torques) is blended into the plan (``start_blend``; 0:
    the policy aims at the plan's start from the first step); ``safety``: also run TVLQR through
    this steady-foot filter (``tracking.filter``; None: not run), on the same draws. Every argument
    is checked before any work.
    """
    trials, seed = _check_int("trials", trials, 1), _check_int("seed", seed, 0)
    substeps = check_substeps(substeps)
    for name, value, cls in (("perturbation", perturbation, Perturbation), ("criteria", criteria, Criteria)):
        if not isinstance(value, cls):
            raise ValueError(f"{name}: expected a {cls.__name__}, got {type(value).__name__}")
    if not isinstance(weights, LQRWeights):
        raise ValueError(f"weights: expected an LQRWeights, got {type(weights).__name__}")
    if safety is not None and not isinstance(safety, SafetyFilter):
        raise ValueError(f"safety: expected a SafetyFilter or None, got {type(safety).__name__}")
    b = start_blend_s
    if isinstance(b, bool) or not isinstance(b, (int, float)) or not np.isfinite(b) or b < 0:
        raise ValueError(f"start_blend_s: expected a finite time >= 0 (s), got {b!r}")
    sol = as_solution(solution_or_dir)
    plant, goal = plant_and_goal(sol)
    ref = reference(sol, substeps, hold_s)
    active, M, n = tuple(sol.active), ref.u.shape[0], plant.model.n
    timing: dict[str, float] = {}

    def stage(label, fn):
        if progress is not None:
            progress.start(label)
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        timing[label] = time.perf_counter() - t0
        if progress is not None:
            progress.finish()
        return out

    gains = stage("TVLQR gains", lambda: _gains(plant, active, ref, weights))
    draws, rejected = stage(
        "draws and start equilibria", lambda: draw_trials(plant, sol.q[0], active, trials, perturbation, seed)
    )
    plants = _stack([perturbed_plant(plant, d) for d in draws])
    x0 = jnp.asarray([np.r_[d.start_q, np.zeros(n)] for d in draws])
    held = np.random.default_rng(seed + 1).standard_normal((trials, -(-M // substeps), n))
    held[0] = 0.0
    noise = jnp.asarray(np.repeat(held, substeps, axis=1)[:, :M] * perturbation.torque_noise_Nm)
    u_max = jnp.asarray(plant.model.u_max)
    u_hold = jnp.asarray([d.start_u for d in draws])
    blend = jnp.asarray(start_blend(np.asarray(ref.t[:-1]) - float(ref.t[0]), start_blend_s))
    run = lambda K, **kw: batch_rollout(plants, active, ref, x0, K, noise, u_max, u_hold, blend, **kw)  # noqa: E731
    open_r = stage("open loop", lambda: run(jnp.zeros_like(gains)))
    closed_r = stage("closed loop", lambda: run(gains))
    qp_r = None
    if safety is not None:
        qp_r = stage("closed loop with the QP filter", lambda: run(gains, nominal=plant, safety=safety))
    t = np.asarray(ref.t)
    records: list[dict[str, Any]] = []
    for i, d in enumerate(draws):
        pick = lambda r: Rollout(*(np.asarray(a[i]) for a in r))  # type: ignore[arg-type]  # noqa: E731  # numpy views of one trial
        trial_plant = perturbed_plant(plant, d)
        record = {
            "trial": i,
            "perturbation": dataclasses.asdict(d),
            "open_loop": judge(pick(open_r), t, trial_plant, goal, criteria),
            "closed_loop": judge(pick(closed_r), t, trial_plant, goal, criteria),
        }
        if qp_r is not None:
            verdict = judge(pick(qp_r), t, trial_plant, goal, criteria)
            record["qp_filter"] = {**verdict, "filter": filter_report(pick(qp_r), t, verdict, substeps)}
        records.append(record)
    rate = lambda key: float(np.mean([r[key]["success"] for r in records]))  # noqa: E731
    return TrackingResult(
        task=sol.task,
        trials=trials,
        seed=seed,
        substeps=substeps,
        hold_s=float(hold_s),
        start_blend_s=float(start_blend_s),
        perturbation=dataclasses.asdict(perturbation),
        criteria=dataclasses.asdict(criteria),
        weights=dataclasses.asdict(weights),
        rejected_draws=rejected,
        open_loop_success_rate=rate("open_loop"),
        closed_loop_success_rate=rate("closed_loop"),
        records=records,
        timing_s=timing,
        reference=ref,
        open_loop=open_r,
        closed_loop=closed_r,
        goal=goal,
        plant=plant,
        qp_filter_success_rate=None if qp_r is None else rate("qp_filter"),
        safety_filter=None if safety is None else dataclasses.asdict(safety),
        qp_filter=qp_r,
    )
