"""Independent checks of the model, the derivatives and the solvers.

``casadi_backend``: the transcription written again in CasADi from the paper's equations, a
second source for values, derivatives and optima; ``checks``: JAX against CasADi and against
finite differences; ``testproblems``: small NLPs with known solutions (Hock-Schittkowski, the
Waechter-Biegler example, an infeasible problem, a staged cart-pole OCP) for the solvers' tests.
"""
