"""Closed-loop execution of a plan: a fine-step simulator of the body under the smooth contact law,
open-loop replay of the planned torques, time-varying LQR around the plan (no contact-mode schedule:
the law is smooth), and Monte-Carlo trials over perturbed bodies, laws and starts.

    res = track("out/T1", trials=100, seed=0)     # or a Solution; -> TrackingResult
    res.closed_loop_success_rate, res.open_loop_success_rate, res.save("out/T1")  # tracking.json
"""

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
    "TrackingResult",
    "linearise",
    "plant_and_goal",
    "reference",
    "riccati",
    "rollout",
    "static_plan",
    "step",
    "track",
    "tvlqr_gains",
]
