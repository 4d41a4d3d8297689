"""Benchmark: one evaluation of B, C qd, G, Q and the foot reaction for 100 stages under vmap + jit.

python scripts/bench_model.py [--stages 100] [--out results/bench_model.json]
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

import jax
import jax.numpy as jnp
import numpy as np

import jaxhumanoid  # noqa: F401
from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import dynamics as dyn
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.studies.bench import time_fn, write_record


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--stages", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--out", default="results/bench_model.json")
    args = ap.parse_args()
    model, foot, contact = PlanarChain.humanoid(), FootParams.paper(), ContactParams.nominal()
    active = (1, 2, 3, 4, 5)
    rng = np.random.default_rng(0)
    q, qd, qdd, u = (jnp.asarray(rng.normal(size=(args.stages, 5))) for _ in range(4))

    def one(q, qd, qdd, u):
        f = ct.contact_forces(model, foot, contact, q, qd, active)
        return (
            dyn.inertia_matrix(model, q),
            dyn.coriolis_vector(model, q, qd),
            dyn.gravity_vector(model, q),
            dyn.generalized_forces(model, q, u, f, active),
            ft.foot_reaction(model, q, qd, qdd, f),
        )

    fns = {
        "B": jax.jit(jax.vmap(lambda a: dyn.inertia_matrix(model, a))),
        "all (B, C qd, G, Q with 5 contacts, foot reaction)": jax.jit(jax.vmap(one)),
    }
    res = {
        "B": time_fn(fns["B"], q, repeats=args.repeats),
        "all": time_fn(fns["all (B, C qd, G, Q with 5 contacts, foot reaction)"], q, qd, qdd, u, repeats=args.repeats),
    }
    print(f"{'function (' + str(args.stages) + ' stages, vmap+jit)':50s} {'median':>10s} {'min':>10s} {'compile':>10s}")
    for k, v in res.items():
        print(f"{k:50s} {v['median_ms'] * 1e3:8.1f}us {v['min_ms'] * 1e3:8.1f}us {v['compile_ms']:8.0f}ms")
    write_record({"stages": args.stages, "results": res}, args.out)


if __name__ == "__main__":
    main()
