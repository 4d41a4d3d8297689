"""Study: the direct hand-over's stage-2 start and barrier on the reference-posing files, over
perturbed cost weights (draw 0 as posed, draw d >= 1 each weight times 1 + 0.01 z of seed d).

Variants: ``base`` (the package's: velocities from the interpolated positions, STAGE2_DEFAULTS),
``ipdef`` (the same start under IPOPT's default barrier and bound push), ``interp_ipdef`` (the
interpolated start, velocities included, under IPOPT's defaults: the independent implementation's
hand-over). Optional JSON of extra ``SolveSettings`` fields, e.g. '{"handover": "continuation"}'.

    OMP_NUM_THREADS=1 OPENBLAS_CORETYPE=Haswell python scripts/study_handover_reference.py T1,T2,T3,T4 6 base,ipdef,interp_ipdef
"""

from __future__ import annotations

import json
import sys
import time
import warnings

import numpy as np

import jaxhumanoid as jh
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.strategy import handover
from jaxhumanoid.strategy import solve as solve_module
from jaxhumanoid.strategy.taskfile import solve_kwargs

IPOPT_DEFAULTS = {"mu_init": 0.1, "bound_push": 1e-2, "bound_frac": 1e-2}


def interpolated_start(Z1, final):
    Zf = handover.interpolate_full(Z1, float(final.p.T), final.layout)
    x0 = np.clip(np.asarray(tr.free_from_full(final.layout, Zf)), final.bounds.xl, final.bounds.xu)
    return x0, Zf


VARIANTS = {
    "base": (handover.stage_two_start, None),
    "ipdef": (handover.stage_two_start, IPOPT_DEFAULTS),
    "interp_ipdef": (interpolated_start, IPOPT_DEFAULTS),
}


def main(argv: list[str]) -> None:
    warnings.simplefilter("ignore")
    tasks, draws, names = argv[0].split(","), int(argv[1]), argv[2].split(",")
    extra = json.loads(argv[3]) if len(argv) > 3 else {}
    for t in tasks:
        kw = solve_kwargs(f"../shared/reference_posing/{t}.toml")
        w0 = kw["task"].weights.as_array(kw["model"].n)
        for d in range(draws):
            w = w0 * (1 + 0.01 * np.random.default_rng(d).standard_normal(w0.shape)) if d else None
            for v in names:
                start, stage2 = VARIANTS[v]
                solve_module.stage_two_start = start
                settings = kw["settings"].replace(**extra, **({"stage2_options": stage2} if stage2 else {}))
                t0 = time.perf_counter()
                sol = jh.solve(**{**kw, "settings": settings}, weights=w)
                row = {"task": t, "draw": d, "variant": v, "iterations": [s.iterations for s in sol.stages]}
                row.update(ok=bool(sol.success), objective=float(sol.objective), wall_s=time.perf_counter() - t0)
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
