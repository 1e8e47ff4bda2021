"""Motor power loss on any vehicle from the imbalance between its ESCs, and whether it can be seen.

The topology powertrain (``gcs_pdm.models.topology``) shares the demanded power equally over the M
motors; a motor with power-loss fault f delivers (1 - f) of its share and the least-faulted motors
make up the shortfall, each (1 + f/(M - 1)) of a share. From each motor's measured current and its
bus voltage the delivered power follows through the kernel's motor equation
(``motor_power.delivered_power``), so with r = P_q / median(P_others):

    f = (1 - r) / (1 + r / (M - 1))

— for M = 2 the shared-shaft formula of ``motor_power`` (m = (P_a - P_f)/(P_a + P_f)). The
suspect's delivered power itself depends on f (its no-load loss is (1 - f) I_0 V), which makes it
a quadratic in f, solved in closed form as ``motor_power.fault_magnitude`` does for two motors.
Like it, the per-sample value is noisy: a windowed median, then a debouncer per motor.

``motor_diagnosis_capability(desc)`` says whether a description's telemetry can show a motor's
power loss at all, and if not, why — for the status the operator sees.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from gcs_pdm.diagnosis.debounce import Debouncer
from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, Fault
from gcs_pdm.diagnosis.motor_power import MotorPowerConfig, delivered_power
from gcs_pdm.models import kernel


def motor_diagnosis_capability(desc) -> tuple[bool, str]:
    """(diagnosable, how or why not) for a ``VehicleDescription``."""
    with_current = [m.name for m in desc.motors if m.readings.current]
    if len(desc.motors) < 2:
        return False, ("not diagnosable with this telemetry: one motor, nothing to compare its current with "
                       "(its power loss shows only as the vehicle's performance)")
    if len(with_current) < len(desc.motors):
        silent = [m.name for m in desc.motors if not m.readings.current]
        return False, f"not diagnosable with this telemetry: no ESC current from {', '.join(silent)}"
    if desc.airframe.type == "fixed_wing" and desc.airframe.shared_shaft:
        return True, "motors on one shaft: their shares of the shaft power"
    if desc.airframe.type == "multirotor":
        return True, "multirotor: the imbalance of delivered power between ESCs"
    return True, "the imbalance of delivered power between ESCs"


#: a 1.6 kg quad hovers on ~150 W: the fixed-wing 150 W floor would hide it; below ~20 W the
#: motors' no-load terms dominate
SMALL_VEHICLE_CONFIG = MotorPowerConfig(min_power_w=20.0)


class EscImbalanceDetector:
    """Per-motor power loss from M ESC currents (M >= 2) and their bus voltages."""

    def __init__(self, motor_names: tuple[str, ...], motor_matrix: np.ndarray,
                 config: MotorPowerConfig = SMALL_VEHICLE_CONFIG):
        if len(motor_names) < 2:
            raise ValueError("EscImbalanceDetector: needs at least two motors")
        self.names = tuple(motor_names)
        self.motors = np.asarray(motor_matrix, dtype=np.float64)
        self.config = config
        self._window: dict[str, deque] = {n: deque(maxlen=config.window) for n in self.names}
        self._debounce = {n: Debouncer(config.debounce) for n in self.names}
        self._active: dict[str, list[float]] = {n: [] for n in self.names}
        self.faults: dict[str, Fault] = {}
        self.samples = 0
        self.low_power_skipped = 0

    def magnitudes(self, currents: np.ndarray, bus_v: np.ndarray) -> np.ndarray:
        """Per-motor f from one set of readings (NaN where no power is delivered)."""
        m = len(self.names)
        k = 1.0 / (m - 1)
        power = np.array([delivered_power(float(currents[q]), float(bus_v[q]), self.motors[q], 0.0)
                          for q in range(m)])
        out = np.full(m, np.nan)
        for q in range(m):
            p_o = float(np.median(np.delete(power, q)))
            if not p_o > 0.0:
                continue
            # the suspect's own no-load term is (1 - f) I_0 V: with A = V i - R_w i², c = I_0 V,
            # r = (A - (1 - f) c) / P_o in f = (1 - r)/(1 + k r) gives
            # c k f² + ((A - c) k + c + P_o) f + (A - c - P_o) = 0
            c = self.motors[q, kernel.M_I0] * float(bus_v[q])
            a_q = power[q] + c
            a2, a1, a0 = c * k, (a_q - c) * k + c + p_o, a_q - c - p_o
            if a2 > 0.0:
                disc = a1 * a1 - 4.0 * a2 * a0
                f = (-a1 + math.sqrt(disc)) / (2.0 * a2) if disc >= 0.0 else math.nan
            else:
                f = -a0 / a1
            out[q] = f
        return out

    def update(self, time_s: float, currents: np.ndarray, bus_v: np.ndarray) -> list[tuple[str, Fault]]:
        currents = np.asarray(currents, dtype=np.float64)
        bus_v = np.broadcast_to(np.asarray(bus_v, dtype=np.float64), currents.shape)
        total = sum(delivered_power(float(i), float(v), self.motors[q], 0.0)
                    for q, (i, v) in enumerate(zip(currents, bus_v)))
        if not (np.all(np.isfinite(currents)) and total >= self.config.min_power_w):
            self.low_power_skipped += 1
            return []
        self.samples += 1
        events = []
        for q, (name, f) in enumerate(zip(self.names, self.magnitudes(currents, bus_v))):
            win = self._window[name]
            if math.isfinite(f):
                win.append(f)
            if len(win) < win.maxlen:
                continue
            med = float(np.median(win))
            deb = self._debounce[name]
            ev = deb.update(time_s, med >= self.config.raise_threshold, med < self.config.clear_threshold)
            if deb.active:
                self._active[name].append(med)
            mag = min(max(float(np.mean(self._active[name])) if self._active[name] else med, 0.0), 1.0)
            evidence = {"median_f": round(med, 4), "current_a": round(float(currents[q]), 2),
                        "other_currents_a": [round(float(c), 2) for k, c in enumerate(currents) if k != q]}
            if ev == "raise":
                spread = float(np.std(win)) / math.sqrt(len(win)) + 1e-3
                conf = 0.5 * (1.0 + math.erf((med - self.config.clear_threshold) / spread / math.sqrt(2.0)))
                self.faults[name] = Fault(MOTOR_POWER_LOSS, name, mag, time_s, conf, evidence, updated_s=time_s)
                events.append(("raise", self.faults[name]))
            elif ev == "clear":
                self.faults[name] = self.faults[name].with_(active=False, cleared_s=time_s, confidence=0.0,
                                                            updated_s=time_s, evidence=evidence)
                self._active[name] = []
                events.append(("clear", self.faults[name]))
            elif deb.active:
                self.faults[name] = self.faults[name].with_(magnitude=mag, updated_s=time_s, evidence=evidence)
        return events

    def fault_vector(self) -> np.ndarray:
        return np.array([self.faults[n].magnitude if n in self.faults and self.faults[n].active else 0.0
                         for n in self.names])


class NoMotorDiagnosis:
    """Stands in for a detector when the telemetry cannot show a motor's power loss: no faults."""

    def __init__(self, n_motors: int):
        self.faults: dict[str, Fault] = {}
        self.samples = 0
        self.low_power_skipped = 0
        self._n = n_motors

    def fault_vector(self) -> np.ndarray:
        return np.zeros(self._n)
