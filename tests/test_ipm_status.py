"""The solver status enum: IPOPT's ApplicationReturnStatus names and codes."""

import pytest

from jaxhumanoid.solvers import ipopt
from jaxhumanoid.solvers.status import SUCCESS, Status, status_name


def test_names_and_codes_are_ipopts():
    assert {int(s): s.name for s in Status if s is not Status.Running} == ipopt.STATUS
    assert Status.from_ipopt_code(-13) is Status.Invalid_Number_Detected
    assert Status.from_ipopt_code(0).name == "Solve_Succeeded"
    assert status_name(-2) == "Restoration_Failed" and status_name(42) == "Unknown_Status_42"
    with pytest.raises(ValueError):
        Status.from_ipopt_code(int(Status.Running))
    with pytest.raises(ValueError):
        Status.from_ipopt_code(42)


def test_success_set():
    assert SUCCESS == {Status.Solve_Succeeded, Status.Solved_To_Acceptable_Level}
    assert {s.name for s in SUCCESS} == set(ipopt.SUCCESS)
    assert Status.Solved_To_Acceptable_Level.success and not Status.Maximum_Iterations_Exceeded.success
