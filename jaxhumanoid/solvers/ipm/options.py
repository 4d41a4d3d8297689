"""Options of the interior-point method, with IPOPT's names and defaults.

References are to Waechter & Biegler (2006), "On the implementation of an interior-point filter
line-search algorithm for large-scale nonlinear programming", Math. Program. 106:25-57 (the IPOPT
paper).

``IPMOptions`` is a JAX pytree: its float fields (tolerances, mu_init, ...) are the leaves, so a
jitted solver takes them as runtime inputs and a new value does not recompile; the integer,
boolean and string fields shape the compiled loop (array sizes, branches) and are static pytree
metadata, so a new value compiles a new solver.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from typing import Any

import jax
import numpy as np

from jaxhumanoid.pytree import register


@dataclasses.dataclass(frozen=True)
class IPMOptions:
    # termination (Sec. 2.1, eq. (5)) and IPOPT's unscaled tests
    tol: float = 1e-8
    max_iter: int = 3000
    s_max: float = 100.0
    constr_viol_tol: float = 1e-4
    dual_inf_tol: float = 1.0
    compl_inf_tol: float = 1e-4
    acceptable_tol: float = 1e-6
    acceptable_iter: int = 15
    acceptable_constr_viol_tol: float = 1e-2
    acceptable_dual_inf_tol: float = 1e10
    acceptable_compl_inf_tol: float = 1e-2
    # barrier parameter update (Sec. 2.1, eq. (7)): monotone Fiacco-McCormick
    mu_init: float = 0.1
    kappa_eps: float = 10.0
    kappa_mu: float = 0.2
    theta_mu: float = 1.5
    tau_min: float = 0.99
    # adaptive barrier update (Nocedal, Waechter & Waltz 2009; ``mu_oracle``): "monotone" is the
    # rule (7) above, "adaptive" the quality-function oracle with the obj-constr-filter safeguard
    mu_strategy: str = "monotone"
    mu_min: float = 1e-11
    mu_max_fact: float = 1e3
    sigma_max: float = 100.0
    sigma_min: float = 1e-6
    quality_function_max_section_steps: int = 8
    quality_function_section_sigma_tol: float = 1e-2
    quality_function_section_qf_tol: float = 0.0
    adaptive_mu_monotone_init_factor: float = 0.8
    filter_margin_fact: float = 1e-5
    filter_max_margin: float = 1.0
    # variable and inequality bounds relaxed by this factor (IPOPT's default)
    bound_relax_factor: float = 1e-8
    # initial point (Sec. 3.6). The slacks' push and fraction take bound_push's and bound_frac's
    # values unless given (NaN: not given), as in IPOPT, so that a warm start's small push reaches
    # the inequality rows too
    bound_push: float = 1e-2
    bound_frac: float = 1e-2
    slack_bound_push: float = math.nan
    slack_bound_frac: float = math.nan
    bound_mult_init_val: float = 1.0
    constr_mult_init_max: float = 1e3
    # gradient-based scaling (Sec. 3.8)
    nlp_scaling_method: str = "gradient-based"
    nlp_scaling_max_gradient: float = 100.0
    nlp_scaling_min_value: float = 1e-8
    obj_scaling_factor: float = 1.0
    # linear damping of one-sided bounds (Sec. 3.7): IPOPT 3.14's default, a tenth of the paper's
    kappa_d: float = 1e-5
    # bound-multiplier safeguard (eq. (16))
    kappa_sigma: float = 1e10
    # filter line search (Sec. 2.3, eqs. (18)-(22))
    theta_max_fact: float = 1e4
    theta_min_fact: float = 1e-4
    gamma_theta: float = 1e-5
    gamma_phi: float = 1e-8
    delta: float = 1.0
    s_theta: float = 1.1
    s_phi: float = 2.3
    eta_phi: float = 1e-8
    alpha_min_frac: float = 0.05
    max_ls_trials: int = 40
    # IPOPT's watchdog (IPOPT's default trigger is 10). Off by default here: with it, T1's stage 2
    # ends at max_iter instead of converging (README)
    watchdog_shortened_iter_trigger: int = 0
    watchdog_trial_iter_max: int = 3
    filter_size: int = 256
    # second-order correction (Sec. 2.4)
    max_soc: int = 4
    kappa_soc: float = 0.99
    # inertia correction (Sec. 3.1, Algorithm IC)
    first_hessian_perturbation: float = 1e-4
    min_hessian_perturbation: float = 1e-20
    max_hessian_perturbation: float = 1e20
    perturb_inc_fact_first: float = 100.0
    perturb_inc_fact: float = 8.0
    perturb_dec_fact: float = 1.0 / 3.0
    jacobian_regularization_value: float = 1e-8
    jacobian_regularization_exponent: float = 0.25
    max_inertia_trials: int = 60
    degen_iters_max: int = 3  # IPOPT's degeneracy test: iterations before a part is declared degenerate
    # the first trial of an iteration: "zero" (IPOPT's: delta_w = 0 first), or "last": once the
    # degeneracy test has decided the Hessian and the last iteration needed delta_w > 0, start at
    # max(min_hessian_perturbation, perturb_dec_fact delta_w_last) (one factorisation fewer
    # wherever the plain trial would fail again)
    inertia_first_trial: str = "zero"
    # linear algebra: the KKT solve, "block_ldl" (the block LDL^T over whole stages) or
    # "condensed" (each stage's local unknowns eliminated first, then the recursion over the
    # unknowns that link the stages; ``kkt.condensed``); both give the exact inertia
    kkt_method: str = "block_ldl"
    # adaptive iterative refinement (IPOPT's names and defaults)
    min_refinement_steps: int = 1
    max_refinement_steps: int = 10
    residual_ratio_max: float = 1e-10
    # feasibility restoration (Sec. 3.3): the l1 restoration problem (see state.Resto)
    max_resto_iter: int = 3000000
    kappa_resto: float = 0.9  # IPOPT's required_infeasibility_reduction
    resto_penalty_parameter: float = 1000.0  # rho
    resto_proximity_weight: float = 1.0  # eta = weight * sqrt(mu)
    resto_theta_max_fact: float = 1e8  # IPOPT's resto.theta_max_fact
    bound_mult_reset_threshold: float = 1000.0
    # output
    print_level: int = 0
    keep_history: bool = True

    def __post_init__(self):
        # JAX rebuilds the options from traced leaves inside jit and vmap; those were validated
        # as the concrete numbers they came from
        if all(isinstance(getattr(self, name), numbers.Real) for name in FLOAT_FIELDS):
            for slack, bound in (("slack_bound_push", "bound_push"), ("slack_bound_frac", "bound_frac")):
                if math.isnan(getattr(self, slack)):
                    object.__setattr__(self, slack, getattr(self, bound))
            validate(self)

    def replace(self, **kw: Any) -> IPMOptions:
        return dataclasses.replace(self, **kw)


_NONNEG = ("bound_relax_factor", "sigma_min", "kappa_d")
_POSITIVE = (
    "tol",
    "s_max",
    "constr_viol_tol",
    "dual_inf_tol",
    "compl_inf_tol",
    "acceptable_tol",
    "acceptable_constr_viol_tol",
    "acceptable_dual_inf_tol",
    "acceptable_compl_inf_tol",
    "mu_init",
    "kappa_eps",
    "mu_min",
    "mu_max_fact",
    "sigma_max",
    "adaptive_mu_monotone_init_factor",
    "filter_max_margin",
    "bound_push",
    "bound_frac",
    "slack_bound_push",
    "slack_bound_frac",
    "bound_mult_init_val",
    "nlp_scaling_max_gradient",
    "nlp_scaling_min_value",
    "kappa_sigma",
    "theta_max_fact",
    "theta_min_fact",
    "gamma_theta",
    "gamma_phi",
    "delta",
    "eta_phi",
    "alpha_min_frac",
    "first_hessian_perturbation",
    "min_hessian_perturbation",
    "max_hessian_perturbation",
    "perturb_inc_fact_first",
    "perturb_inc_fact",
    "jacobian_regularization_value",
    "obj_scaling_factor",
    "residual_ratio_max",
    "resto_penalty_parameter",
    "resto_proximity_weight",
    "resto_theta_max_fact",
    "bound_mult_reset_threshold",
)
_OPEN_UNIT = ("kappa_mu", "tau_min", "perturb_dec_fact", "kappa_soc", "kappa_resto", "filter_margin_fact")
_UNIT_LEFT_CLOSED = ("quality_function_section_sigma_tol", "quality_function_section_qf_tol")
_NONNEG_INT = (
    "acceptable_iter",
    "max_soc",
    "min_refinement_steps",
    "max_refinement_steps",
    "print_level",
    "degen_iters_max",
    "watchdog_shortened_iter_trigger",
    "quality_function_max_section_steps",
)

_POS_INT = (
    "max_iter",
    "max_ls_trials",
    "filter_size",
    "max_inertia_trials",
    "max_resto_iter",
    "watchdog_trial_iter_max",
)
SCALING_METHODS = ("gradient-based", "none")
MU_STRATEGIES = ("monotone", "adaptive")
INERTIA_FIRST_TRIALS = ("zero", "last")
KKT_METHODS = ("block_ldl", "condensed")


def validate(o: IPMOptions) -> None:
    """Raise ValueError naming the offending option and its allowed values."""
    for name in _POSITIVE:
        v = getattr(o, name)
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ValueError(f"IPMOptions.{name} must be a finite number > 0, got {v!r}")
    for name in _NONNEG:
        v = getattr(o, name)
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ValueError(f"IPMOptions.{name} must be a finite number >= 0, got {v!r}")
    for name in _OPEN_UNIT:
        v = getattr(o, name)
        if not isinstance(v, (int, float)) or not 0.0 < v < 1.0:
            raise ValueError(f"IPMOptions.{name} must lie in the open interval (0, 1), got {v!r}")
    for name in _NONNEG_INT:
        v = getattr(o, name)
        if not isinstance(v, int) or isinstance(v, bool) or v < 0:
            raise ValueError(f"IPMOptions.{name} must be an integer >= 0, got {v!r}")
    for name in _POS_INT:
        v = getattr(o, name)
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise ValueError(f"IPMOptions.{name} must be an integer >= 1, got {v!r}")
    for name in _UNIT_LEFT_CLOSED:
        v = getattr(o, name)
        if not isinstance(v, (int, float)) or not 0.0 <= v < 1.0:
            raise ValueError(f"IPMOptions.{name} must lie in [0, 1), got {v!r}")
    if not 1.0 < o.theta_mu < 2.0:
        raise ValueError(f"IPMOptions.theta_mu must lie in (1, 2), got {o.theta_mu!r}")
    if not o.s_theta > 1.0:
        raise ValueError(f"IPMOptions.s_theta must be > 1, got {o.s_theta!r}")
    if not o.s_phi > 1.0:
        raise ValueError(f"IPMOptions.s_phi must be > 1, got {o.s_phi!r}")
    if not 0.0 < o.jacobian_regularization_exponent < 1.0:
        raise ValueError(
            "IPMOptions.jacobian_regularization_exponent must lie in (0, 1), "
            f"got {o.jacobian_regularization_exponent!r}"
        )
    if o.bound_frac > 0.5 or o.slack_bound_frac > 0.5:
        raise ValueError("IPMOptions.bound_frac and slack_bound_frac must be <= 0.5")
    if o.nlp_scaling_method not in SCALING_METHODS:
        raise ValueError(
            f"IPMOptions.nlp_scaling_method must be one of {SCALING_METHODS}, got {o.nlp_scaling_method!r}"
        )
    if o.mu_strategy not in MU_STRATEGIES:
        raise ValueError(f"IPMOptions.mu_strategy must be one of {MU_STRATEGIES}, got {o.mu_strategy!r}")
    if o.inertia_first_trial not in INERTIA_FIRST_TRIALS:
        raise ValueError(
            f"IPMOptions.inertia_first_trial must be one of {INERTIA_FIRST_TRIALS}, got {o.inertia_first_trial!r}"
        )
    if o.kkt_method not in KKT_METHODS:
        raise ValueError(f"IPMOptions.kkt_method must be one of {KKT_METHODS}, got {o.kkt_method!r}")
    if o.sigma_min >= o.sigma_max:
        raise ValueError("IPMOptions.sigma_min must be < sigma_max")
    if o.min_hessian_perturbation >= o.max_hessian_perturbation:
        raise ValueError("IPMOptions.min_hessian_perturbation must be < max_hessian_perturbation")
    if not isinstance(o.keep_history, bool):
        raise ValueError(f"IPMOptions.keep_history must be True or False, got {o.keep_history!r}")


def make_options(options: IPMOptions | dict | None) -> IPMOptions:
    """Accept None, an IPMOptions or a dict of IPOPT-style option names."""
    if options is None:
        return IPMOptions()
    if isinstance(options, IPMOptions):
        return options
    if isinstance(options, dict):
        names = {f.name for f in dataclasses.fields(IPMOptions)}
        unknown = sorted(set(options) - names)
        if unknown:
            raise ValueError(f"unknown IPM option(s) {unknown}; allowed: {sorted(names)}")
        return IPMOptions(**options)
    raise ValueError(f"options must be None, a dict or an IPMOptions, got {type(options).__name__}")


FLOAT_FIELDS = tuple(f.name for f in dataclasses.fields(IPMOptions) if f.type in ("float", float))
STATIC_FIELDS = tuple(f.name for f in dataclasses.fields(IPMOptions) if f.name not in FLOAT_FIELDS)
register(IPMOptions, static=STATIC_FIELDS)


def as_float64(o: IPMOptions) -> IPMOptions:
    """The options with every float leaf a NumPy float64 (a strongly typed jit input)."""
    return jax.tree.map(np.float64, o)
