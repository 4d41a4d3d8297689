"""Values of command-line flags that several subcommands share: ``KEY=VALUE`` pairs and the IPOPT
options of stage 1 of 2S."""

from __future__ import annotations

from jaxhumanoid.solvers import ipopt_capi


def parse_pairs(pairs, flag: str = "--ipopt-option") -> dict:
    """``flag key=value`` pairs (``--ipopt-option``, ``--perturb``, ``--lqr``) as a dict, numbers parsed."""
    opts = {}
    for pair in pairs or []:
        if "=" not in pair:
            raise ValueError(f"{flag}: expected KEY=VALUE, got {pair!r}")
        key, val = pair.split("=", 1)
        for cast in (int, float):
            try:
                val = cast(val)
                break
            except ValueError:
                continue
        opts[key.strip()] = val
    return opts


def stage1_options_arg(pairs) -> dict | None:
    """The ``--stage1-option`` pairs, IPOPT options of stage 1 of 2S on top of the others, checked
    by IPOPT (stage 1's default solver) before any work; None where none is given."""
    if not pairs:
        return None
    opts = parse_pairs(pairs, "--stage1-option")
    try:
        ipopt_capi.check_options(opts)
    except ValueError as err:
        raise ValueError(f"--stage1-option: {err}") from err
    return opts
