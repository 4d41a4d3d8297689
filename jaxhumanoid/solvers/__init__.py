"""NLP solvers: IPOPT through cyipopt, the own interior-point method in JAX, CasADi + IPOPT."""
