"""The Monte Carlo prediction's samples of packs on the extended variant (docs/model.md).

``prediction.predict`` draws the paper packs' states and parameters; for packs the estimator runs
on the extended variant (``StateEstimator.ext``) this module draws theirs from the extended filter's
Gaussian and spreads their parameters, and the samples then fly
``topology.simulate_vehicle_extended`` (or ``kernel.simulate_packs(variant="extended")`` at a held
current).

Parameter spread: the resistances, time constants, kinetic and diffusion scales, capacity and
thermal values move log-normally by the prediction's ``param_rel_sigma``; the open-circuit curve,
the Arrhenius and SoC-rise exponents and dU/dT do not (a relative spread of the OCV's 16-21 V would
be volts: its uncertainty is the SoC's, which the state carries). SoC is a fraction of the sampled
capacity, so the capacity spread reaches the time to cut-off as in the paper variant's ``restate``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gcs_pdm.models import kernel

#: extended values spread by the prediction's parameter uncertainty
SPREAD = np.array([kernel.E_R0, kernel.E_R1, kernel.E_TAU1, kernel.E_R2, kernel.E_TAU2, kernel.E_BCT, kernel.E_ICT,
                   kernel.E_KD, kernel.E_CMAX, kernel.E_CT, kernel.E_H])


@dataclass(frozen=True)
class ExtendedPacks:
    """Which packs are extended (P,), their values (P, N_EXT_PARAMS; zeros for paper packs) and
    their filter's mean (P, 5) and covariance (P, 5, 5)."""

    is_ext: np.ndarray
    params: np.ndarray
    mean: np.ndarray
    cov: np.ndarray

    @classmethod
    def of(cls, estimator, inflation: np.ndarray | None = None) -> "ExtendedPacks | None":
        """The estimator's extended packs (None if it has none); ``inflation`` (P,) scales each
        pack's covariance (``StateEstimator.prediction_inflation``)."""
        ext = getattr(estimator, "ext", None)
        if ext is None:
            return None
        n_packs = len(estimator.pack_names)
        is_ext = np.zeros(n_packs, dtype=bool)
        params = np.zeros((n_packs, kernel.N_EXT_PARAMS))
        mean = np.zeros((n_packs, kernel.N_EXT_STATE))
        cov = np.tile(np.eye(kernel.N_EXT_STATE), (n_packs, 1, 1))
        for b, row in estimator.ext_row.items():
            is_ext[b] = True
            params[b], mean[b] = ext.params[row], ext.mean[row]
            cov[b] = ext.cov[row] * (1.0 if inflation is None else float(inflation[b]))
        return cls(is_ext, params, mean, cov)

    def sample(self, x0_paper: np.ndarray, n: int, rng: np.random.Generator, rel_sigma: float
               ) -> tuple[np.ndarray, np.ndarray]:
        """(n, P, 5) states — the paper packs' ``x0_paper`` (n, P, 4) in the first four columns, the
        extended packs' drawn from their Gaussians — and (n, P, N_EXT_PARAMS) extended values."""
        n_packs = self.is_ext.size
        x0 = np.zeros((n, n_packs, kernel.N_EXT_STATE))
        x0[..., :kernel.N_PACK_STATE] = x0_paper
        chol = np.linalg.cholesky(self.cov + 1e-12 * np.eye(kernel.N_EXT_STATE))
        drawn = self.mean[None] + np.einsum("bij,nbj->nbi", chol, rng.standard_normal((n, n_packs, kernel.N_EXT_STATE)))
        x0[:, self.is_ext] = drawn[:, self.is_ext]
        params = np.repeat(self.params[None], n, axis=0)
        params[..., SPREAD] *= np.exp(rng.normal(0.0, rel_sigma, size=(n, n_packs, SPREAD.size)))
        return x0, params
