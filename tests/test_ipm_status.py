"""The solver status enum: IPOPT's ApplicationReturnStatus names and codes (IpReturnCodes_inc.h)."""

import pytest

from jaxhumanoid.solvers.status import SUCCESS, Status, status_name

IPOPT_CODES = {
    0: "Solve_Succeeded",
    1: "Solved_To_Acceptable_Level",
    2: "Infeasible_Problem_Detected",
    3: "Search_Direction_Becomes_Too_Small",
    4: "Diverging_Iterates",
    5: "User_Requested_Stop",
    6: "Feasible_Point_Found",
    -1: "Maximum_Iterations_Exceeded",
    -2: "Restoration_Failed",
    -3: "Error_In_Step_Computation",
    -4: "Maximum_CpuTime_Exceeded",
    -5: "Maximum_WallTime_Exceeded",
    -10: "Not_Enough_Degrees_Of_Freedom",
    -11: "Invalid_Problem_Definition",
    -12: "Invalid_Option",
    -13: "Invalid_Number_Detected",
    -100: "Unrecoverable_Exception",
    -101: "NonIpopt_Exception_Thrown",
    -102: "Insufficient_Memory",
    -199: "Internal_Error",
}


def test_names_and_codes_are_ipopts():
    assert {int(s): s.name for s in Status if s is not Status.Running} == IPOPT_CODES
    assert int(Status.Running) not in IPOPT_CODES
    assert Status.from_ipopt_code(-13) is Status.Invalid_Number_Detected
    assert Status.from_ipopt_code(0).name == "Solve_Succeeded"
    assert status_name(-2) == "Restoration_Failed" and status_name(42) == "Unknown_Status_42"
    with pytest.raises(ValueError):
        Status.from_ipopt_code(int(Status.Running))
    with pytest.raises(ValueError):
        Status.from_ipopt_code(42)


def test_success_set():
    assert {Status.Solve_Succeeded, Status.Solved_To_Acceptable_Level} == SUCCESS
    assert Status.Solved_To_Acceptable_Level.success and not Status.Maximum_Iterations_Exceeded.success
