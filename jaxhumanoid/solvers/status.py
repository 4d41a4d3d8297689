"""Solver return statuses: IPOPT's ``ApplicationReturnStatus`` (IpReturnCodes_inc.h) as one enum.

Every solver reports its outcome as the member's name (``NLPResult.status``), e.g.
``"Solve_Succeeded"``; the integer values are IPOPT's codes, so the status of IPOPT's C interface
maps one to one (``Status.from_ipopt_code``). ``Running`` is internal to the own interior-point
method: the value of its loop state before a termination test fires.
"""

from __future__ import annotations

import enum


class Status(enum.IntEnum):
    Solve_Succeeded = 0
    Solved_To_Acceptable_Level = 1
    Infeasible_Problem_Detected = 2
    Search_Direction_Becomes_Too_Small = 3
    Diverging_Iterates = 4
    User_Requested_Stop = 5
    Feasible_Point_Found = 6
    Maximum_Iterations_Exceeded = -1
    Restoration_Failed = -2
    Error_In_Step_Computation = -3
    Maximum_CpuTime_Exceeded = -4
    Maximum_WallTime_Exceeded = -5
    Not_Enough_Degrees_Of_Freedom = -10
    Invalid_Problem_Definition = -11
    Invalid_Option = -12
    Invalid_Number_Detected = -13
    Unrecoverable_Exception = -100
    NonIpopt_Exception_Thrown = -101
    Insufficient_Memory = -102
    Internal_Error = -199
    # not an IPOPT code: the own IPM's loop runs while its status is this value
    Running = 1000

    @classmethod
    def from_ipopt_code(cls, code: int) -> Status:
        """The member of IPOPT's integer return code; ValueError for a code IPOPT does not define."""
        status = cls(int(code))
        if status is cls.Running:
            raise ValueError(f"{int(code)} is not an IPOPT return code")
        return status

    @property
    def success(self) -> bool:
        return self in SUCCESS


SUCCESS = frozenset({Status.Solve_Succeeded, Status.Solved_To_Acceptable_Level})


def succeeded(name: str) -> bool:
    """Whether a status name (``NLPResult.status``) is one of ``SUCCESS``."""
    return name in {s.name for s in SUCCESS}


def status_name(code: int) -> str:
    """The name of IPOPT's return code ``code``, ``"Unknown_Status_<code>"`` for any other value."""
    try:
        return Status.from_ipopt_code(code).name
    except ValueError:
        return f"Unknown_Status_{int(code)}"
