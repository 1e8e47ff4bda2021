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
        self.params = kernel.owned(np.broadcast_to(m, (n_motors, kernel.N_MOTOR_PARAMS)))  # one compiled step
        self.config = config
        self.mean = np.full((n_motors, 1), np.nan)
        self.cov = np.zeros((n_motors, 1, 1))
        self.initialised = np.zeros(n_motors, dtype=bool)
        self.rejected_in_row = np.zeros(n_motors, dtype=np.int64)
        self.rejected_total = np.zeros(n_motors, dtype=np.int64)
        self.relocks = np.zeros(n_motors, dtype=np.int64)
        # the compiled step's view of the counters: one channel per motor
        self._rejected_total_2d = self.rejected_total.reshape(-1, 1)
        self._rejected_in_row_2d = self.rejected_in_row.reshape(-1, 1)
        # ``ukf.motor_step_one``'s arguments other than the frame's (arrays updated in place, never replaced)
        c = config
        self._step_args = (self.params, self.mean, self.cov,
                           ukf.motor_step_constants(c.process_sigma_c ** 2, c.temperature_sigma_c ** 2, c.gate,
                                                    c.relock_after, c.relock_inflation),
                           self._rejected_total_2d, self._rejected_in_row_2d, self.relocks)

    def initialise(self, idx: np.ndarray, temperature: np.ndarray, sigma: float | None = None) -> None:
        idx = np.atleast_1d(idx)
        self.mean[idx, 0] = temperature
        s = self.config.initial_sigma_c if sigma is None else sigma
        self.cov[idx] = s * s
        self.initialised[idx] = True

    def step(self, idx: np.ndarray, dt: np.ndarray, current: np.ndarray, ambient: float,
             temperature: np.ndarray) -> None:
        """Advance motors ``idx`` by ``dt`` s at ``current`` A, then update with ``temperature`` °C
        (NaN = not measured). Compiled (``ukf.motor_step_rows``), in place."""
        idx = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        c = self.config
        rows = idx.shape
        ukf.motor_step_rows(self.params, self.mean, self.cov, idx, ukf.as_rows(dt, rows), ukf.as_rows(current, rows),
                            float(ambient), ukf.as_rows(temperature, rows), c.process_sigma_c ** 2,
                            c.temperature_sigma_c ** 2, c.gate, c.relock_after, c.relock_inflation,
                            self._rejected_total_2d, self._rejected_in_row_2d, self.relocks)

    def step_one(self, q: int, dt: float, current: float, ambient: float, temperature: float) -> None:
        """``step`` for one motor and plain floats (a telemetry frame), without the array set-up
        (``ukf.motor_step_one``: the same compiled arithmetic)."""
        ukf.motor_step_one(*self._step_args, q, dt, current, ambient, temperature)

    def temperature(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean[:, 0].copy(), np.sqrt(np.maximum(self.cov[:, 0, 0], 0.0))
