"""The simulated vehicle's hidden "true" propulsion parameters.

They differ from every set the service ships (``gcs_pdm.models.params.BUILTIN_SETS``), so that
learning, estimation and planning are tested against a vehicle they do not know, as in flight.
"""
from __future__ import annotations

import numpy as np

from gcs_pdm.models.params import ParameterSet, builtin, perturbed

DEFAULT_TRUTH_SEED = 2013


def true_parameters(seed: int = DEFAULT_TRUTH_SEED, spread: float = 0.15) -> ParameterSet:
    """The hidden truth: the physical reading of the paper's values, each parameter moved by up to
    ``spread`` (log-uniform, seeded)."""
    return perturbed(builtin("paper_si"), np.random.default_rng(seed), rel=spread, name=f"sim_truth_{seed}")
