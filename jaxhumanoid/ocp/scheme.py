"""Solution schemes of Table II (Sec. III-A).

* forces: "E" (embedded: contact laws inside Q) or "A" (augmented: contact forces are variables and
  their laws (3)-(4) equality constraints);
* contacts: "F" (every joint O_1..O_n carries a contact force) or "F+C" (only the task's active
  set does; the others get clearance constraints y_Oi(q) >= 0);
* stages: 1 (one solve, "1S") or 2 (pseudo-static warm start on a coarse grid, then the full
  problem, "2S").
"""

from __future__ import annotations

import dataclasses

_FORCES = ("E", "A")
_CONTACTS = ("F", "F+C")
_STAGES = ("1S", "2S")


@dataclasses.dataclass(frozen=True)
class Scheme:
    forces: str = "A"
    contacts: str = "F+C"
    stages: int = 2

    def __post_init__(self):
        if self.forces not in _FORCES:
            raise ValueError(f"scheme.forces: {self.forces!r} not in {_FORCES}")
        if self.contacts not in _CONTACTS:
            raise ValueError(f"scheme.contacts: {self.contacts!r} not in {_CONTACTS}")
        if self.stages not in (1, 2):
            raise ValueError(f"scheme.stages: {self.stages!r} not in (1, 2)")

    @property
    def augmented(self) -> bool:
        return self.forces == "A"

    @property
    def clearance(self) -> bool:
        return self.contacts == "F+C"

    def __str__(self) -> str:
        return f"{self.forces},{self.contacts},{self.stages}S"

    def active_set(self, task_active: tuple, n_links: int) -> tuple:
        """Joints carrying contact forces: all of 1..n_links under F, the task's set under F+C."""
        return tuple(task_active) if self.clearance else tuple(range(1, n_links + 1))


def parse_scheme(text) -> Scheme:
    """Parse the paper's notation: ``A,F+C,2S``, ``E-F-1S``, ``a f+c 2s`` ..."""
    if isinstance(text, Scheme):
        return text
    parts = [p for p in str(text).upper().replace(",", " ").replace("-", " ").replace("/", " ").split() if p]
    err = (
        f"scheme: cannot parse {text!r}; expected forces in {_FORCES}, contacts in {_CONTACTS}, "
        f"stages in {_STAGES}, e.g. 'A,F+C,2S'"
    )
    if len(parts) != 3 or parts[0] not in _FORCES or parts[1] not in _CONTACTS or parts[2] not in _STAGES:
        raise ValueError(err)
    return Scheme(parts[0], parts[1], int(parts[2][0]))


TABLE2_SCHEMES = ("E,F,1S", "A,F,1S", "A,F+C,1S", "A,F+C,2S")
