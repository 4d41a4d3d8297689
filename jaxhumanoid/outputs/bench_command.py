"""``jaxhumanoid bench``: the benchmark suites of ``studies.suites`` run by ``studies.runner``,
one JSON record and its markdown table per run (docs/benchmarks.md)."""

from __future__ import annotations

import sys

from jaxhumanoid.outputs.exits import working
from jaxhumanoid.outputs.flags import stage1_options_arg
from jaxhumanoid.runtime import writable_dir
from jaxhumanoid.strategy.problem import STRATEGY_GUESSES
from jaxhumanoid.studies.runner import (
    BACKENDS,
    DEFAULT_REFERENCE_DIR,
    BenchSettings,
    markdown,
    plan_run,
    run_record,
    write_run,
)
from jaxhumanoid.studies.suites import DEFAULT_SUITES, SUITES


def cmd_bench(args) -> int:
    """Run the named benchmark suites: one record (JSON) and its table (markdown) in ``--out``."""
    settings = BenchSettings(
        repeats=args.repeats,
        tasks=tuple(args.tasks),
        backends=tuple(args.backends),
        N=args.N,
        reference_dir=args.reference_dir,
        spec=args.spec,
        draws=args.draws,
        workers=args.workers,
        guess=args.guess,
        stage1_options=stage1_options_arg(args.stage1_option),
        work_dir=f"{args.out}/work",
        quiet=args.quiet,
    )
    planned = plan_run(args.suite, SUITES, settings)
    out = writable_dir(args.out)
    with working():
        record = run_record(planned, SUITES, settings, argv=sys.argv[1:])
    text = markdown(record, SUITES)
    json_path, md_path = write_run(record, text, out)
    if not args.quiet:
        print(text)
    print(f"wrote {json_path} and {md_path}")
    return 0


def add_bench_parser(sub) -> None:
    """The ``bench`` subcommand's parser, added to the subparsers ``sub``."""
    p = sub.add_parser("bench", help="run benchmark suites: one JSON record (commit, environment, medians) and a table")
    p.add_argument(
        "--suite",
        nargs="+",
        default=list(DEFAULT_SUITES),
        choices=list(SUITES),
        help=f"suites to run in turn (default {' '.join(DEFAULT_SUITES)}; docs/benchmarks.md)",
    )
    p.add_argument("--repeats", type=int, default=3, help="runs of each case, in alternation (default 3)")
    p.add_argument("--tasks", nargs="+", default=["T1", "T2", "T3", "T4"], help="built-in tasks (default all four)")
    p.add_argument("--backends", nargs="+", default=list(BACKENDS), choices=list(BACKENDS), help="default all three")
    p.add_argument("--N", type=int, default=None, help="grid of every solve (default: each task's, 100)")
    p.add_argument(
        "--reference-dir", default=DEFAULT_REFERENCE_DIR, help="the reference posing's T*.toml and README.md"
    )
    p.add_argument("--spec", default="examples/studies/robustness.toml", help="robustness suite: the study spec")
    p.add_argument(
        "--draws",
        type=int,
        default=None,
        help="robustness: the first K draws per task; reference-draws: K draws per file (default 6)",
    )
    p.add_argument("--workers", type=int, default=1, help="robustness suite: worker processes")
    p.add_argument(
        "--guess",
        default=None,
        choices=list(STRATEGY_GUESSES),
        help="the first stage's initial guess (default: solve's, the task file's, the spec's)",
    )
    p.add_argument(
        "--stage1-option",
        action="append",
        metavar="KEY=VALUE",
        help="an IPOPT option of stage 1 of 2S, on top of solve's, the task file's or the spec's; repeatable",
    )
    p.add_argument("--out", default="bench", help="folder of the records (default bench/)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_bench)
