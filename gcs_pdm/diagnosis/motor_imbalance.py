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

**Unequal shares (multirotors).** The model's equal share is exact for motors on one shaft, not for
a multirotor: a centre of gravity a few centimetres off, or a yaw trim between the two spin
directions, makes healthy motors carry steadily different shares (17-20 % apart is common), which
the equal-share formula reads as a power loss. With ``learn_shares`` the detector first learns each
motor's own share — the median of its delivered power over the mean of all, over the first
``share_learn_s`` seconds (message time) of samples with power — and then judges each motor against
its learned share (its power divided by it). While it learns, only a loss of at least
``uncalibrated_raise`` (0.35: beyond trim asymmetry) is raised, and a motor raised by then keeps
the healthy motors' mean share (its loss is not learned away). The price: a loss smaller than that
present from take-off is learned as the motor's share and not reported; the learned shares are in
``shares`` and each fault's evidence.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from gcs_pdm.diagnosis.debounce import Debouncer
from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, Fault
from gcs_pdm.diagnosis.motor_power import MotorPowerConfig, median_of_sorted
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
    """Per-motor power loss from M ESC currents (M >= 2) and their bus voltages.

    It runs at every set of ESC readings, so the per-sample work is plain Python on M floats (numpy
    pays microseconds per call on arrays this small): the medians from sorted lists, the active
    mean from a running sum, and a fault's latest evidence built only when ``faults`` is read."""

    def __init__(self, motor_names: tuple[str, ...], motor_matrix: np.ndarray,
                 config: MotorPowerConfig = SMALL_VEHICLE_CONFIG, *, learn_shares: bool = False,
                 share_learn_s: float = 60.0, uncalibrated_raise: float = 0.35):
        if len(motor_names) < 2:
            raise ValueError("EscImbalanceDetector: needs at least two motors")
        self.names = tuple(motor_names)
        self.motors = np.asarray(motor_matrix, dtype=np.float64)
        self.config = config
        self._rw = [float(r) for r in self.motors[:, kernel.M_RW]]
        self._i0 = [float(r) for r in self.motors[:, kernel.M_I0]]
        # per motor, in ``names`` order (lists, not dicts by name: read on every sample): its window of
        # per-sample magnitudes, its debouncer, and while active the count and running sum of the
        # medians (the reported magnitude is their mean)
        self._window = [deque(maxlen=config.window) for _ in self.names]
        self._debounce = [Debouncer(config.debounce) for _ in self.names]
        self._active_n = [0] * len(self.names)
        self._active_sum = [0.0] * len(self.names)
        self._faults: dict[str, Fault] = {}
        #: an active fault's latest (time, magnitude, median, currents) not yet folded into ``faults``
        self._latest: dict[str, tuple] = {}
        self.samples = 0
        self.low_power_skipped = 0
        # the motors' own shares (module docstring): None while learning (or never, without
        # learn_shares); the ratios gathered so far
        self.learn_shares = learn_shares
        self.share_learn_s = float(share_learn_s)
        self._share_since = math.nan  # message time of the first sample learned from
        self.uncalibrated_raise = float(uncalibrated_raise)
        self.shares: list[float] | None = None
        self._share_ratios: list[list[float]] = [[] for _ in self.names]

    @property
    def faults(self) -> dict[str, Fault]:
        """Every motor's fault in its latest state (the per-sample refinements folded in on reading)."""
        for name, (time_s, mag, med, q, currents) in self._latest.items():
            self._faults[name] = self._faults[name].with_(magnitude=mag, updated_s=time_s,
                                                          evidence=_evidence(med, q, currents, self.shares))
        self._latest.clear()
        return self._faults

    def _powers(self, currents: list[float], bus_v: list[float]) -> list[float]:
        """Each motor's delivered power on the fault-free reading (``motor_power.delivered_power``)."""
        return [v * i - rw * i * i - 1.0 * i0 * v for i, v, rw, i0 in zip(currents, bus_v, self._rw, self._i0)]

    def magnitudes(self, currents, bus_v) -> np.ndarray:
        """Per-motor f from one set of readings (NaN where no power is delivered)."""
        currents, bus_v = _floats(currents), _floats(bus_v, len(self.names))
        return np.array(self._magnitudes(self._powers(currents, bus_v), bus_v))

    def _magnitudes(self, power: list[float], bus_v: list[float]) -> list[float]:
        m = len(self.names)
        k = 1.0 / (m - 1)
        # two motors: the other's power is the median of the others (the general path's value)
        order = sorted(range(m), key=power.__getitem__) if m > 2 else None
        out = [math.nan] * m
        for q in range(m):
            p_o = power[1 - q] if order is None else median_of_sorted([power[i] for i in order if i != q])
            if not p_o > 0.0:
                continue
            # the suspect's own no-load term is (1 - f) I_0 V: with A = V i - R_w i², c = I_0 V,
            # r = (A - (1 - f) c) / P_o in f = (1 - r)/(1 + k r) gives
            # c k f² + ((A - c) k + c + P_o) f + (A - c - P_o) = 0
            c = self._i0[q] * bus_v[q]
            a_q = power[q] + c
            a2, a1, a0 = c * k, (a_q - c) * k + c + p_o, a_q - c - p_o
            if a2 > 0.0:
                disc = a1 * a1 - 4.0 * a2 * a0
                f = (-a1 + math.sqrt(disc)) / (2.0 * a2) if disc >= 0.0 else math.nan
            else:
                f = -a0 / a1 if a1 != 0.0 else math.nan   # (numpy's ±inf/NaN: never appended either)
            out[q] = f
        return out

    def update(self, time_s: float, currents, bus_v) -> list[tuple[str, Fault]]:
        """One set of readings: each motor's current, A, and its bus voltage, V (a scalar: one bus)."""
        currents = _floats(currents)
        return self.update_floats(time_s, currents, _floats(bus_v, len(currents)))

    def update_floats(self, time_s: float, currents: list[float], bus_v: list[float]) -> list[tuple[str, Fault]]:
        """``update`` for lists of Python floats the detector may keep (the pipeline's per-sample
        call: its readings are floats already)."""
        power = self._powers(currents, bus_v)
        cfg = self.config
        isfinite = math.isfinite
        if not (all(map(isfinite, currents)) and sum(power) >= cfg.min_power_w):
            self.low_power_skipped += 1
            return []
        self.samples += 1
        events = []
        full, raise_at = cfg.window, cfg.raise_threshold
        if self.learn_shares:
            if self.shares is None:
                raise_at = max(raise_at, self.uncalibrated_raise)
                self._learn_share(time_s, power)
            else:
                power = [p / s for p, s in zip(power, self.shares)]
        windows, debouncers = self._window, self._debounce
        for q, f in enumerate(self._magnitudes(power, bus_v)):
            win = windows[q]
            if isfinite(f):
                win.append(f)
            if len(win) < full:
                continue
            deb = debouncers[q]
            if not deb.active and max(win) < raise_at and math.isnan(deb.pending_since):
                # nothing to change: the median (≤ the window's largest) cannot raise, nothing is pending
                continue
            med = median_of_sorted(sorted(win))
            ev = deb.update(time_s, med >= raise_at, med < cfg.clear_threshold)
            if deb.active:
                self._active_n[q] += 1
                self._active_sum[q] += med
            elif ev is None:
                continue
            name = self.names[q]
            n_active = self._active_n[q]
            mag = min(max(self._active_sum[q] / n_active if n_active else med, 0.0), 1.0)
            if ev == "raise":
                spread = float(np.std(win)) / math.sqrt(len(win)) + 1e-3
                conf = 0.5 * (1.0 + math.erf((med - cfg.clear_threshold) / spread / math.sqrt(2.0)))
                self._faults[name] = Fault(MOTOR_POWER_LOSS, name, mag, time_s, conf, _evidence(med, q, currents, self.shares),
                                           updated_s=time_s)
                self._latest.pop(name, None)
                events.append(("raise", self._faults[name]))
            elif ev == "clear":
                # from its latest refinement (``faults`` folds it in)
                self._faults[name] = self.faults[name].with_(active=False, cleared_s=time_s, confidence=0.0,
                                                              updated_s=time_s, evidence=_evidence(med, q, currents, self.shares))
                self._active_n[q], self._active_sum[q] = 0, 0.0
                events.append(("clear", self._faults[name]))
            else:
                self._latest[name] = (time_s, mag, med, q, currents)
        return events

    def _learn_share(self, time_s: float, power: list[float]) -> None:
        """One sample towards the motors' shares; after ``share_learn_s`` of them, the shares (each
        motor's median ratio to the mean, normalised to a mean of 1; a motor raised meanwhile gets
        the others' mean) replace the equal ones, and the windows restart on the new footing."""
        mean = sum(power) / len(power)
        for ratios, p in zip(self._share_ratios, power):
            ratios.append(p / mean)
        if math.isnan(self._share_since):
            self._share_since = time_s
        if time_s - self._share_since < self.share_learn_s:
            return
        shares = [median_of_sorted(sorted(r)) for r in self._share_ratios]
        raised = [self._debounce[q].active for q in range(len(shares))]
        healthy = [s for s, r in zip(shares, raised) if not r]
        if healthy:
            shares = [sum(healthy) / len(healthy) if r else s for s, r in zip(shares, raised)]
        norm = sum(shares) / len(shares)
        self.shares = [s / norm for s in shares]
        self._share_ratios = [[] for _ in self.names]
        for win in self._window:
            win.clear()

    def fault_vector(self) -> np.ndarray:
        faults = self._faults  # magnitudes only change on update: no need to fold in the evidence
        return np.array([(self._latest[n][1] if n in self._latest else faults[n].magnitude)
                         if n in faults and faults[n].active else 0.0 for n in self.names])


def _floats(x, n: int | None = None) -> list[float]:
    """A reading as a list of Python floats (a scalar bus voltage repeated ``n`` times)."""
    if type(x) is list:
        return list(map(float, x))   # the pipeline's readings (per sample: the short way)
    if isinstance(x, np.ndarray):
        return x.astype(np.float64).tolist() if x.ndim else [float(x)] * (1 if n is None else n)
    if isinstance(x, (list, tuple)):
        return [float(v) for v in x]
    return [float(x)] * (1 if n is None else n)


def _evidence(med: float, q: int, currents: list[float], shares: list[float] | None = None) -> dict:
    ev = {"median_f": round(med, 4), "current_a": round(currents[q], 2),
          "other_currents_a": [round(c, 2) for k, c in enumerate(currents) if k != q]}
    if shares is not None:  # judged against its own learned share of the power, not an equal one
        ev["learned_share"] = round(shares[q], 3)
    return ev


class NoMotorDiagnosis:
    """Stands in for a detector when the telemetry cannot show a motor's power loss: no faults."""

    def __init__(self, n_motors: int):
        self.faults: dict[str, Fault] = {}
        self.samples = 0
        self.low_power_skipped = 0
        self._n = n_motors

    def fault_vector(self) -> np.ndarray:
        return np.zeros(self._n)
