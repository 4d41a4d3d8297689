"""Exit statuses of the command line: 2 for input rejected before any work (a ``ValueError``
raised before the work starts), 1 for a run that failed while working (``RunFailed``)."""

from __future__ import annotations

import contextlib


class RunFailed(Exception):
    """A command's work failed after its input was accepted: exit status 1, with the message."""


@contextlib.contextmanager
def working():
    """Where a command's work runs: a ValueError raised there (no static equilibrium found near a
    start posture, say) is a failed run, exit status 1, not rejected input (2)."""
    try:
        yield
    except ValueError as err:
        raise RunFailed(str(err)) from err
