"""Motor power loss from the two motors' currents (and the shaft's rpm) against the model.

The model (``kernel._simulate_powertrain``): each motor owes half the shaft power P; a motor with
fault magnitude m delivers (1 - m) P/2 and the healthy one makes up the rest, (1 + m) P/2. A
motor's delivered shaft power follows from its input current i and bus voltage V through the
kernel's motor equation, V i = P_q + R_w i² + (1 - m_q) I_0 V. So with P_fwd, P_aft from the two
measured currents,

    m = (P_aft - P_fwd) / (P_aft + P_fwd)     (> 0: the fwd motor is faulted; < 0: the aft one)

— independent of air density, propeller and the faulted rotor's drag, which all scale P. The
(1 - m) on the faulted motor's no-load term makes this a quadratic in m, solved in closed form
(``fault_magnitude``); it holds down to low power, where a fixed-point iteration diverges.
The measured rpm is kept as evidence: it should match the total delivered power (``shaft_rpm``).

Per sample m is noisy (current noise) and one ESC spike moves it a lot, so the detector works on
the median of a short window, then debounces; the reported magnitude is the mean over the time
the fault has been active (more samples, smaller error).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from gcs_pdm.diagnosis.debounce import DebounceConfig, Debouncer
from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, Fault
from gcs_pdm.models import kernel
from gcs_pdm.models.params import MOTOR_NAMES
from gcs_pdm.models.powertrain import shaft_rpm


@dataclass(frozen=True)
class MotorPowerConfig:
    raise_threshold: float = 0.10
    clear_threshold: float = 0.05
    #: below this total delivered power the no-load terms dominate and m is not observable, W
    min_power_w: float = 150.0
    window: int = 7                   # samples in the median
    debounce: DebounceConfig = DebounceConfig(raise_after_s=3.0, clear_after_s=10.0)


def delivered_power(current_a: float, bus_v: float, motor: np.ndarray, fault: float) -> float:
    """Shaft power delivered by a motor drawing ``current_a`` from ``bus_v`` (kernel motor equation)."""
    return bus_v * current_a - motor[kernel.M_RW] * current_a * current_a - (1.0 - fault) * motor[kernel.M_I0] * bus_v


def fault_magnitude(i_fwd: float, i_aft: float, v_fwd: float, v_aft: float, motor: np.ndarray
                    ) -> tuple[float, float, float]:
    """Signed magnitude m (> 0: fwd faulted) and the two delivered powers (W).

    With A_q = V_q i_q - R_w i_q² and c_q = I_0 V_q, a fwd fault of magnitude a gives
    P_fwd = A_fwd - (1 - a) c_fwd and P_aft = A_aft - c_aft, and the model's a = (P_aft - P_fwd) /
    (P_aft + P_fwd) becomes c_fwd a² + (A_fwd + P_aft) a - (P_aft - A_fwd + c_fwd) = 0 (the same
    with the motors swapped for an aft fault). The motor that delivers less on the fault-free
    reading is the suspect; its magnitude is the root in [0, 1]. NaN when nothing is delivered."""
    rw, i0 = motor[kernel.M_RW], motor[kernel.M_I0]
    a_f = v_fwd * i_fwd - rw * i_fwd * i_fwd
    a_a = v_aft * i_aft - rw * i_aft * i_aft
    c_f, c_a = i0 * v_fwd, i0 * v_aft
    if a_a - c_a >= a_f - c_f:      # fwd delivers less: a fwd fault (or none)
        a_s, c_s, p_other, sign = a_f, c_f, a_a - c_a, 1.0
    else:
        a_s, c_s, p_other, sign = a_a, c_a, a_f - c_f, -1.0
    b = a_s + p_other
    c = p_other - a_s + c_s
    if c_s > 0.0:
        disc = b * b + 4.0 * c_s * c
        if disc < 0.0:
            return math.nan, math.nan, math.nan
        a = (-b + math.sqrt(disc)) / (2.0 * c_s)
    elif b != 0.0:
        a = c / b
    else:
        return math.nan, math.nan, math.nan
    a = min(max(a, 0.0), 1.0)
    p_s = a_s - (1.0 - a) * c_s
    if p_s + p_other <= 0.0:
        return math.nan, math.nan, math.nan
    return (a, p_s, p_other) if sign > 0 else (-a, p_other, p_s)


class MotorPowerLossDetector:
    """Runs at every paired sample, so the per-sample work is plain Python floats; an active fault's
    evidence (and its rpm check) is built only when ``faults`` is read."""

    def __init__(self, motor_params: np.ndarray, config: MotorPowerConfig = MotorPowerConfig()):
        self.motor = np.asarray(motor_params, dtype=np.float64)
        # the same numbers as Python floats: numpy scalar arithmetic costs several times more per sample
        self._motor = self.motor.tolist()
        self.config = config
        self._window: deque = deque(maxlen=config.window)
        self._debounce = {name: Debouncer(config.debounce) for name in MOTOR_NAMES}
        # the medians while active: their count and running sum (the reported magnitude is their
        # mean, asked for at every sample)
        self._active_n: dict[str, int] = {name: 0 for name in MOTOR_NAMES}
        self._active_sum: dict[str, float] = {name: 0.0 for name in MOTOR_NAMES}
        self._faults: dict[str, Fault] = {}
        #: an active fault's latest refinement (magnitude, confidence, evidence inputs) not yet in ``faults``
        self._latest: dict[str, tuple] = {}
        self.samples = 0
        self.low_power_skipped = 0

    @property
    def faults(self) -> dict[str, Fault]:
        """Both motors' faults in their latest state (the per-sample refinements folded in on reading)."""
        for name, (mag, conf, time_s, reading) in self._latest.items():
            self._faults[name] = self._faults[name].with_(magnitude=mag, confidence=conf, updated_s=time_s,
                                                          evidence=self._evidence(*reading))
        self._latest.clear()
        return self._faults

    def update(self, time_s: float, i_fwd: float, i_aft: float, v_fwd: float, v_aft: float,
               rpm: float = math.nan) -> list[tuple[str, Fault]]:
        """One paired observation; returns the (event, fault) pairs it caused ('raise'/'update'/'clear')."""
        # the power question first, on the fault-free reading (it differs from the faulted one by
        # at most the no-load loss, ~60 W): near idle the share carries no information
        healthy_total = (delivered_power(i_fwd, v_fwd, self._motor, 0.0) + delivered_power(i_aft, v_aft, self._motor, 0.0))
        if not healthy_total >= self.config.min_power_w:
            self.low_power_skipped += 1
            return []
        m, p0, p1 = fault_magnitude(i_fwd, i_aft, v_fwd, v_aft, self._motor)
        if not math.isfinite(m) or p0 + p1 < self.config.min_power_w:
            self.low_power_skipped += 1
            return []
        self.samples += 1
        self._window.append(m)
        if len(self._window) < self._window.maxlen:
            return []
        window = sorted(self._window)
        med = float(median_of_sorted(window))
        spread = math.nan   # the confidence's, computed once a motor is active (rare)
        events = []
        for q, name in enumerate(MOTOR_NAMES):
            mq = med if q == 0 else -med
            deb = self._debounce[name]
            ev = deb.update(time_s, mq >= self.config.raise_threshold, mq < self.config.clear_threshold)
            if not (deb.active or ev == "clear"):
                self._active_n[name], self._active_sum[name] = 0, 0.0
                continue
            if deb.active:
                self._active_n[name] += 1
                self._active_sum[name] += mq
            n_active = self._active_n[name]
            mag = self._active_sum[name] / n_active if n_active else mq
            if deb.active and math.isnan(spread):
                spread = _sd(window) / math.sqrt(len(window)) + 1e-3
            conf = _phi((mq - self.config.clear_threshold) / spread) if deb.active else 0.0
            reading = (med, n_active, p0, p1, i_fwd, i_aft, rpm, v_fwd if med > 0 else v_aft)
            if ev == "raise":
                f = Fault(MOTOR_POWER_LOSS, name, min(max(mag, 0.0), 1.0), time_s, conf,
                          self._evidence(*reading), updated_s=time_s)
                self._faults[name] = f
                events.append(("raise", f))
            elif ev == "clear":
                f = self.faults[name].with_(active=False, cleared_s=time_s, confidence=0.0, updated_s=time_s,
                                             evidence=self._evidence(*reading))
                self._faults[name] = f
                self._active_n[name], self._active_sum[name] = 0, 0.0
                events.append(("clear", f))
            else:
                self._latest[name] = (min(max(mag, 0.0), 1.0), conf, time_s, reading)
                continue
            self._latest.pop(name, None)
        return events

    def _evidence(self, med: float, n_active: int, p0: float, p1: float, i_fwd: float, i_aft: float, rpm: float,
                  v_f: float) -> dict:
        # the propeller gets what the motors deliver less the faulted rotor's drag (kernel:
        # fault_drag = 0.1 of its share) and its unpowered no-load loss
        p_prop = (p0 + p1 - abs(med) * self.motor[kernel.M_I0] * v_f) / (1.0 + 0.05 * abs(med))
        rpm_expected = float(shaft_rpm(max(p_prop, 0.0)))
        return {"median_m": round(med, 4), "n_samples": n_active,
                "power_fwd_w": round(p0, 1), "power_aft_w": round(p1, 1),
                "current_fwd_a": round(i_fwd, 2), "current_aft_a": round(i_aft, 2),
                "rpm_measured": None if not math.isfinite(rpm) else round(rpm, 0),
                "rpm_expected_sea_level": round(rpm_expected, 0)}

    def fault_vector(self) -> np.ndarray:
        """Active magnitudes (fwd, aft) for the kernel."""
        faults = self._faults
        return np.array([(self._latest[n][0] if n in self._latest else faults[n].magnitude)
                         if n in faults and faults[n].active else 0.0 for n in MOTOR_NAMES])


def median_of_sorted(v: list[float]) -> float:
    """np.median of a short sorted list of floats, without the array round trip (it runs per
    sample); NaN when empty."""
    n = len(v)
    if n == 0:
        return math.nan
    return v[n // 2] if n % 2 else (v[n // 2 - 1] + v[n // 2]) / 2.0


def _sd(v: list[float]) -> float:
    """Population standard deviation of a short sorted window (np.std without the array round trip)."""
    n = len(v)
    mean = sum(v) / n
    return math.sqrt(sum((x - mean) ** 2 for x in v) / n)


def _phi(z: float) -> float:
    return 0.5 * (1.0 + math.erf(z / math.sqrt(2.0)))
