"""jaxhumanoid: differentiable trajectory optimisation of a planar humanoid (or any planar chain) with
unscheduled contacts.

Importing the package turns on float64 in JAX (``jax_enable_x64``): every model, transcription
and solver function works in double precision.
"""

import jaxhumanoid.runtime  # noqa: F401  (float64 before any array is made)
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain

__all__ = ["ContactParams", "FootParams", "PlanarChain"]
__version__ = "0.1.0"
