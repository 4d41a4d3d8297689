"""Figures for the README and docs/results.md: solve T1..T4 with 2S (A,F+C,2S) and draw them.

    python scripts/make_figures.py [--out docs] [--N 100] [--tasks T1 T2 T3 T4] [--gif T1] [--quiet]

writes, for each task Tk,

    docs/Tk.png            paper-style summary (frame strip, angles, torques, contact forces)
    docs/Tk_contacts.png   contact timeline and steady-foot margins

plus docs/T1.gif (an animation of the ``--gif`` task) and docs/results.json (each task's
``Solution.report()`` with its contact summary and the wall time). Each task takes about 1-2 min
at N = 100 on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

GIF_MAX_BYTES = 1_500_000


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(pathlib.Path(__file__).resolve().parent.parent / "docs"))
    parser.add_argument("--N", type=int, default=100)
    parser.add_argument("--scheme", default="A,F+C,2S")
    parser.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    parser.add_argument("--gif", default="T1", help="task to animate ('' for none)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)

    from jaxhumanoid.outputs.animation import animate
    from jaxhumanoid.outputs.plots import plot_solution
    from jaxhumanoid.outputs.timeline import contact_summary, plot_contact_timeline
    from jaxhumanoid.progress import Progress
    from jaxhumanoid.runtime import enable_compilation_cache
    from jaxhumanoid.strategy.solve import solve

    enable_compilation_cache()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results_path = out / "results.json"
    results = json.loads(results_path.read_text()) if results_path.is_file() else {}
    progress = Progress(len(args.tasks), quiet=args.quiet)
    failed = []
    for task in progress.iter(args.tasks):
        t0 = time.perf_counter()
        sol = solve(task, args.scheme, N=args.N)
        wall = time.perf_counter() - t0
        report = sol.report()
        report["contacts"] = contact_summary(sol)
        report["wall_time_s"] = wall
        results[task] = report
        results_path.write_text(json.dumps(results, indent=2) + "\n")
        plot_solution(sol, path=out / f"{task}.png", dpi=100)
        plot_contact_timeline(sol, path=out / f"{task}_contacts.png", dpi=90)
        if task == args.gif:
            gif = animate(sol, out / f"{task}.gif", fps=10, max_frames=50, dpi=90)
            if gif.stat().st_size > GIF_MAX_BYTES:  # fewer, smaller frames
                gif = animate(sol, gif, fps=8, max_frames=40, dpi=70)
            progress.note(f"{gif.name} {gif.stat().st_size / 1e6:.2f} MB")
        if not sol.success:
            failed.append(task)
        its = "+".join(str(i) for i in report["iterations"])
        status = report["status"] if sol.success else "NOT CONVERGED: " + " + ".join(report["stage_status"])
        progress.note(f"{status}, iterations {its}, objective {report['objective']:.4g}")
    progress.summary()
    if failed:
        print(f"not converged: {failed}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
