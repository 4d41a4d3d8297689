"""IPOPT-style iteration log, produced after the solve from the fixed-size history arrays."""

from __future__ import annotations

import math

import numpy as np

HEADER = "iter    objective    inf_pr   inf_du lg(mu)  ||d||  lg(rg) alpha_du alpha_pr  ls"


def _lg(v):
    return "   - " if not (v > 0 and math.isfinite(v)) else f"{math.log10(v):5.1f}"


def format_log(history: dict, iterations: int, status: str, header: str | None = None) -> str:
    """Text log in IPOPT's column layout; history arrays are read up to ``iterations``."""
    lines = []
    if header:
        lines.append(header)
    lines.append(HEADER)
    for k in range(int(iterations) + 1):
        kind = int(history["kind"][k])
        tag = chr(kind) if kind > 0 else " "
        r = "r" if int(history["mode"][k]) else " "
        d = history["d_norm"][k]
        lines.append(
            f"{k:4d}{r} {history['obj'][k]: .7e} {history['inf_pr'][k]:.2e} {history['inf_du'][k]:.2e}"
            f" {_lg(history['mu'][k])} {(d if k else 0.0):.2e} {_lg(history['reg'][k]) if k else '   - '}"
            f" {history['alpha_du'][k]:.2e} {history['alpha_pr'][k]:.2e}{tag if k else ' '}"
            f" {int(history['ls'][k]) if k else 0:2d}"
        )
    lines.append("")
    lines.append(f"Number of Iterations....: {int(iterations)}")
    lines.append(f"EXIT: {status}")
    return "\n".join(lines)


def trim_history(history: dict, iterations: int) -> dict:
    """Copy the first ``iterations + 1`` rows of every history array to numpy."""
    return {k: np.asarray(v)[: int(iterations) + 1] for k, v in history.items()}
