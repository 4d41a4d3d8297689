"""scripts/bench_iteration.py imports, parses IPOPT's timing statistics and its variants."""

import importlib.util
import pathlib

SCRIPT = pathlib.Path(__file__).resolve().parent.parent / "scripts" / "bench_iteration.py"

LOG = """
Number of Iterations....: 12
Timing Statistics:

OverallAlgorithm....................:      0.500 (sys:      0.010 wall:      0.700)
 PDSystemSolverTotal.................:      0.300 (sys:      0.005 wall:      0.400)
Function Evaluations................:      0.150 (sys:      0.001 wall:      0.200)
EXIT: Optimal Solution Found.
Number of Iterations....: 30
OverallAlgorithm....................:      2.000 (sys:      0.010 wall:      2.500)
"""


def _script():
    spec = importlib.util.spec_from_file_location("bench_iteration", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_parses_timing_statistics_and_variants():
    bench = _script()
    first, second = bench.timing_statistics(LOG)
    assert first == {
        "iterations": 12,
        "OverallAlgorithm": (0.5, 0.7),
        "PDSystemSolverTotal": (0.3, 0.4),
        "Function Evaluations": (0.15, 0.2),
    }
    assert second == {"iterations": 30, "OverallAlgorithm": (2.0, 2.5)}
    var = bench._parse_variant("amd,opt:mumps_pivot_order=0,env:OPENBLAS_CORETYPE=SkylakeX,lib:/x/libipopt.so")
    assert var["options"] == {"mumps_pivot_order": "0"} and var["library"] == "/x/libipopt.so"
    assert var["env"] == {"OPENBLAS_CORETYPE": "SkylakeX", "JAXHUMANOID_IPOPT_LIBRARY": "/x/libipopt.so"}
    ipm = bench._parse_variant("ipm,solver:ipm,sweeps:joint")
    assert (ipm["name"], ipm["solver"], ipm["sweeps"], ipm["options"]) == ("ipm", "ipm", "joint", {})
    assert bench._parse_variant("plain")["solver"] is None
