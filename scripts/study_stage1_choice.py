"""Study: stage 1 of the robustness study's first 10 draws per task (IPOPT) from the inverse-dynamics
guess and from the static path, each with its fallbacks: iterations, success and objective.

    OMP_NUM_THREADS=1 python scripts/study_stage1_choice.py docs/study_stage1_choice.json

With the whole-2S rows of each guess (docs/study_stage1_guess.json) it gives the 2S that runs
stage 1 from both and hands over the solution of lower objective (docs/decisions.md).
"""
import json, sys, pathlib, time, os
import multiprocessing as mp

SPEC = str(pathlib.Path(__file__).resolve().parents[1] / "examples" / "studies" / "robustness.toml")

def case_both(cid):
    import jaxhumanoid as jh
    from jaxhumanoid.strategy.runner import Runner
    from jaxhumanoid.studies.spec import load_spec
    from jaxhumanoid.studies import run as run_mod
    class Stop(Exception): pass
    orig_run = Runner.run if not hasattr(Runner, "_orig") else Runner._orig
    Runner._orig = orig_run
    rec = []
    def run(self, problem, x0, options, stage):
        if not problem.layout.pseudo_static:
            raise Stop
        r = orig_run(self, problem, x0, options, stage)
        rec.append((stage, r.iterations, r.success, float(r.objective)))
        return r
    Runner.run = run
    orig_base = run_mod.base_problem if not hasattr(run_mod, "_orig_base") else run_mod._orig_base
    run_mod._orig_base = orig_base
    spec = load_spec(SPEC)
    case = next(c for c in spec.cases if c.id == cid)
    out = {"case": cid, "task": case.task, "draw": case.draw}
    for g in ["inverse_dynamics", "static_path"]:
        def base_problem(c, g=g):
            kw = orig_base(c); kw["settings"] = kw["settings"].replace(guess=g); return kw
        run_mod.base_problem = base_problem
        rec.clear()
        try:
            run_mod.solve_case(case, pathlib.Path("/tmp/study_stage1_choice"))
        except Stop:
            pass
        out[g] = {"iterations": sum(r[1] for r in rec), "success": rec[-1][2], "objective": rec[-1][3], "attempts": len(rec)}
    return out

if __name__ == "__main__":
    spec_cases = None
    import jaxhumanoid
    from jaxhumanoid.studies.spec import load_spec
    cases = [c.id for c in load_spec(SPEC).cases if c.solver == "ipopt" and (c.draw or 0) < 10]
    rows = []
    with mp.get_context("spawn").Pool(2, maxtasksperchild=5) as pool:
        for r in pool.imap_unordered(case_both, cases):
            rows.append(r); print(json.dumps(r), flush=True)
            json.dump(rows, open(sys.argv[1], "w"), indent=1)
