"""Closed-loop execution of a plan: a fine-step simulator of the body under the smooth contact law,
open-loop replay of the planned torques, time-varying LQR around the plan (no contact-mode schedule:
the law is smooth), a per-step QP safety filter that enforces the steady-foot conditions (5) on
TVLQR's torques, and Monte-Carlo trials over perturbed bodies, laws and starts.

    res = track("out/T1", trials=100, seed=0, safety=SafetyFilter())  # or a Solution; -> TrackingResult
    res.closed_loop_success_rate, res.qp_filter_success_rate, res.save("out/T1")  # tracking.json
"""

from jaxhumanoid.tracking.filter import SafetyFilter, filter_torque, solve_qp
from jaxhumanoid.tracking.lqr import LQRWeights, linearise, riccati, tvlqr_gains
from jaxhumanoid.tracking.montecarlo import Criteria, Perturbation, TrackingResult, track
from jaxhumanoid.tracking.plan import Goal, plant_and_goal, reference, static_plan
from jaxhumanoid.tracking.simulator import Plant, Reference, Rollout, rollout, step

__all__ = [
    "Criteria",
    "Goal",
    "LQRWeights",
    "Perturbation",
    "Plant",
    "Reference",
    "Rollout",
    "SafetyFilter",
    "TrackingResult",
    "filter_torque",
    "linearise",
    "plant_and_goal",
    "reference",
    "riccati",
    "rollout",
    "solve_qp",
    "static_plan",
    "step",
    "track",
    "tvlqr_gains",
]
