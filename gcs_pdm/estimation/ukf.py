"""Batched unscented-transform helpers shared by the pack and motor filters.

The filters here have a nonlinear process (the kernel's step: R_cp depends on SoC) and *linear*
observations (terminal voltage and temperature are linear in the kernel's state), so the
unscented transform is only needed for the prediction; the update is the exact Kalman update,
done one scalar observation at a time so that a missing or gated channel simply drops out.

Sigma points: the symmetric set with kappa = 0 (weights 1/2n, centre weight 0) — every weight
positive, so the predicted covariance stays positive semi-definite without repair.
"""
from __future__ import annotations

import numpy as np


def sigma_points(mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(m, n) means and (m, n, n) covariances -> (m, 2n, n) sigma points."""
    m, n = mean.shape
    # a covariance driven to the edge of PSD by round-off gets a tiny jitter rather than a crash
    try:
        chol = np.linalg.cholesky(n * cov)
    except np.linalg.LinAlgError:
        jitter = 1e-9 * np.einsum("kii->ki", cov).max(axis=1)[:, None, None] * np.eye(n)
        chol = np.linalg.cholesky(n * (0.5 * (cov + cov.transpose(0, 2, 1)) + jitter + 1e-12 * np.eye(n)))
    offsets = chol.transpose(0, 2, 1)  # rows are the columns of the factor
    return np.concatenate([mean[:, None, :] + offsets, mean[:, None, :] - offsets], axis=1)


def recombine(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m, 2n, n) propagated sigma points -> means (m, n) and covariances (m, n, n)."""
    mean = points.mean(axis=1)
    dev = points - mean[:, None, :]
    cov = np.einsum("kji,kjl->kil", dev, dev) / points.shape[1]
    return mean, cov


def scalar_update(mean: np.ndarray, cov: np.ndarray, h: np.ndarray, z: np.ndarray, r: float | np.ndarray,
                  gate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Kalman update of rows with a linear scalar observation z = h·x + noise(r), gated.

    mean (m, n), cov (m, n, n), h (m, n), z (m,). Rows whose normalised innovation exceeds
    ``gate`` are left untouched. Returns (mean, cov, innovation, normalised innovation)."""
    r = np.broadcast_to(np.asarray(r, dtype=np.float64), z.shape)
    ph = np.einsum("kij,kj->ki", cov, h)
    s = np.einsum("ki,ki->k", h, ph) + r
    nu = z - np.einsum("ki,ki->k", h, mean)
    norm = nu / np.sqrt(s)
    ok = np.abs(norm) <= gate
    gain = ph / s[:, None]
    gain[~ok] = 0.0
    mean = mean + gain * nu[:, None]
    # Joseph form keeps the covariance symmetric and PSD with any gain
    eye = np.eye(mean.shape[1])
    a = eye - gain[:, :, None] * h[:, None, :]
    cov = np.einsum("kij,kjl,kml->kim", a, cov, a) + (r[:, None] * gain)[:, :, None] * gain[:, None, :]
    return mean, cov, nu, norm
