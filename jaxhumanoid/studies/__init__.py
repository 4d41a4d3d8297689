"""Studies at scale: a TOML spec of many solves, run on a pool of worker processes or a cluster.

- ``spec``: the spec file -> cases (``Case``, a stable id each), grids and seeded random draws;
- ``run``: one case -> one solve (or one inverse fit) -> one row, errors caught into the row;
- ``engines``: the local pool of spawned processes (default) and Dask distributed;
- ``table``: the CSV table (appended per case, resume) and ``summary.json``;
- ``compare``: do several solvers reach the same optimum of one problem (``agreement``);
- ``sweep``: all of it (``jaxhumanoid sweep SPEC.toml --out DIR``).
"""

from jaxhumanoid.studies.compare import Outcome, agreement
from jaxhumanoid.studies.engines import ENGINES, Crash, run_jobs
from jaxhumanoid.studies.run import run_case
from jaxhumanoid.studies.spec import FACTORS, Case, Spec, load_spec, parse_spec
from jaxhumanoid.studies.sweep import sweep
from jaxhumanoid.studies.table import read_table, summarise

__all__ = [
    "ENGINES",
    "FACTORS",
    "Case",
    "Crash",
    "Outcome",
    "Spec",
    "agreement",
    "load_spec",
    "parse_spec",
    "read_table",
    "run_case",
    "run_jobs",
    "summarise",
    "sweep",
]
