"""Kalman filter for the motors' temperature over ``kernel.simulate_motor_thermal``.

One state per motor (°C); input: the motor's current; observation: its temperature sensor.
The same unscented prediction as the packs (two sigma points per motor, all motors advanced in
one kernel call; the thermal step is affine in T, so the transform is exact), gated scalar updates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gcs_pdm.estimation import ukf
from gcs_pdm.models import kernel


@dataclass(frozen=True)
class MotorFilterConfig:
    temperature_sigma_c: float = 0.5
    process_sigma_c: float = 0.05       # per √s: heat the model does not know about
    initial_sigma_c: float = 2.0
    gate: float = 5.0
    relock_after: int = 5
    relock_inflation: float = 25.0


class MotorThermalFilter:
    def __init__(self, motor_params: np.ndarray, n_motors: int = 2, config: MotorFilterConfig = MotorFilterConfig()):
        m = np.asarray(motor_params, dtype=np.float64)
        self.params = np.ascontiguousarray(np.broadcast_to(m, (n_motors, kernel.N_MOTOR_PARAMS)))
        self.config = config
        self.mean = np.full((n_motors, 1), np.nan)
        self.cov = np.zeros((n_motors, 1, 1))
        self.initialised = np.zeros(n_motors, dtype=bool)
        self.rejected_in_row = np.zeros(n_motors, dtype=np.int64)
        self.rejected_total = np.zeros(n_motors, dtype=np.int64)
        self.relocks = np.zeros(n_motors, dtype=np.int64)
        self._h = np.ones((n_motors, 1))

    def initialise(self, idx: np.ndarray, temperature: np.ndarray, sigma: float | None = None) -> None:
        idx = np.atleast_1d(idx)
        self.mean[idx, 0] = temperature
        s = self.config.initial_sigma_c if sigma is None else sigma
        self.cov[idx] = s * s
        self.initialised[idx] = True

    def step(self, idx: np.ndarray, dt: np.ndarray, current: np.ndarray, ambient: float,
             temperature: np.ndarray) -> None:
        idx = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        dt = np.broadcast_to(np.asarray(dt, dtype=np.float64), idx.shape)
        current = np.broadcast_to(np.asarray(current, dtype=np.float64), idx.shape)
        mean, cov = self.mean[idx], self.cov[idx]
        if np.any(dt > 0):
            pts = ukf.sigma_points(mean, cov)                          # (m, 2, 1)
            out = kernel.simulate_motor_thermal(np.repeat(self.params[idx], 2, axis=0), pts.reshape(-1),
                                                np.repeat(dt, 2)[:, None], np.repeat(current, 2)[:, None],
                                                float(ambient))
            pmean, pcov = ukf.recombine(out[:, -1].reshape(idx.size, 2, 1))
            still = dt <= 0
            pmean[still], pcov[still] = mean[still], cov[still]
            mean = pmean
            cov = pcov + self.config.process_sigma_c ** 2 * np.maximum(dt, 0.0)[:, None, None]
        z = np.broadcast_to(np.asarray(temperature, dtype=np.float64), idx.shape)
        have = np.isfinite(z)
        if have.any():
            sel = np.flatnonzero(have)
            r = self.config.temperature_sigma_c ** 2
            nm, nc, _, norm = ukf.scalar_update(mean[sel], cov[sel], self._h[idx][sel], z[sel], r, self.config.gate)
            mean[sel], cov[sel] = nm, nc
            rows = idx[sel]
            gated = np.abs(norm) > self.config.gate
            self.rejected_total[rows[gated]] += 1
            self.rejected_in_row[rows] = np.where(gated, self.rejected_in_row[rows] + 1, 0)
            relock = self.rejected_in_row[rows] >= self.config.relock_after
            if relock.any():
                k = sel[relock]
                cov[k] *= self.config.relock_inflation
                rm, rc, _, _ = ukf.scalar_update(mean[k], cov[k], self._h[idx][k], z[k], r, np.inf)
                mean[k], cov[k] = rm, rc
                self.relocks[rows[relock]] += 1
                self.rejected_in_row[rows[relock]] = 0
        self.mean[idx], self.cov[idx] = mean, cov

    def temperature(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean[:, 0].copy(), np.sqrt(np.maximum(self.cov[:, 0, 0], 0.0))
