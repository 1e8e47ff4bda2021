"""Frames in, estimate and faults out: the estimator and every detector, driven by message time.

``DiagnosisPipeline.consume(frame)`` is the frame consumer for the live link and for
``gcs-pdm replay`` (``report()`` gives the replay summary its ``faults``). ``faults`` holds every
fault raised (latest state, active or cleared), ``events`` the raise/clear history in order.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from gcs_pdm.diagnosis.faults import PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE, Fault
from gcs_pdm.diagnosis.motor_imbalance import EscImbalanceDetector, NoMotorDiagnosis, motor_diagnosis_capability
from gcs_pdm.diagnosis.motor_power import MotorPowerConfig, MotorPowerLossDetector
from gcs_pdm.diagnosis.model_fidelity import ModelMismatchMonitor
from gcs_pdm.diagnosis.pack_health import PackHealthConfig, PackHealthMonitor
from gcs_pdm.diagnosis.prognosis import PrognosisConfig, PrognosisMonitor
from gcs_pdm.estimation.estimator import MOTOR_OF_PACK, EstimatorConfig, StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.models.params import ParameterSet, default_set
from gcs_pdm.models.powertrain import Limits

log = logging.getLogger(__name__)


class DiagnosisPipeline:
    def __init__(self, params: ParameterSet | None = None, *, limits: Limits = Limits(),
                 estimator_config: EstimatorConfig = EstimatorConfig(),
                 motor_config: MotorPowerConfig = MotorPowerConfig(),
                 pack_config: PackHealthConfig = PackHealthConfig(),
                 prognosis_config: PrognosisConfig = PrognosisConfig(), seed: int = 0,
                 pair_within_s: float = 0.6, voltage_fresh_s: float = 3.0, vehicle=None):
        """``vehicle``: a ``VehicleDescription`` to diagnose instead of the paper's aircraft (its
        packs and motors; motor power loss from the ESCs' imbalance where its telemetry shows it)."""
        self.vehicle = vehicle
        if vehicle is None:
            self.params = params or default_set()
            self.estimator = StateEstimator(self.params, estimator_config)
            self.motor_power = MotorPowerLossDetector(self.params.motor_vector(), motor_config)
            self.motor_diagnosis = "motors on one shaft: their shares of the shaft power"
        else:
            self.params = None
            self.estimator = StateEstimator(config=estimator_config, vehicle=vehicle)
            diagnosable, self.motor_diagnosis = motor_diagnosis_capability(vehicle)
            self.motor_power = (EscImbalanceDetector(self.estimator.motor_names, self.estimator.motors.params)
                                if diagnosable else NoMotorDiagnosis(len(self.estimator.motor_names)))
        est = self.estimator
        self.pack_health = PackHealthMonitor(est.packs.params.copy(), pack_config, names=est.pack_names)
        self.prognosis = PrognosisMonitor(limits, prognosis_config, seed=seed)
        self.model_fidelity = ModelMismatchMonitor(est.pack_names)
        self.pair_within_s = pair_within_s
        self.voltage_fresh_s = voltage_fresh_s
        self._pack_v = np.full(len(est.pack_names), np.nan)
        self._pack_v_time = np.full(len(est.pack_names), -math.inf)
        self._faults: list[Fault] = []
        self._index: dict[tuple[str, str], int] = {}
        self.events: list[dict] = []
        self.frames = 0
        self._adopted: dict[str, tuple[float, float]] = {}

    # ---- input ---------------------------------------------------------------------------------------
    def set_mission(self, load: FutureLoad, start_s: float | None = None) -> None:
        """The shaft-power load of the rest of the mission from message time ``start_s`` (default: now)."""
        self.prognosis.set_mission(load, self.estimator.time_s if start_s is None else start_s)

    def consume(self, frame) -> None:
        self.frames += 1
        est = self.estimator
        est.consume(frame)
        t = float(getattr(frame, "time_s", math.nan))
        if isinstance(frame, PackFrame):
            b = est.pack_names.index(frame.pack) if frame.pack in est.pack_names else -1
            if b >= 0:
                if frame.voltage_v is not None and math.isfinite(frame.voltage_v):
                    self._pack_v[b], self._pack_v_time[b] = frame.voltage_v, t
                if est.packs.initialised[b] and frame.voltage_v is not None:
                    self.pack_health.add(b, t, float(est.pack_current[b]), float(frame.voltage_v), est.ambient_c)
                self._record(self.model_fidelity.update(t, est, frame.pack))
        elif isinstance(frame, MotorFrame) and frame.motor in est.motor_names:
            if self.vehicle is None:
                self._motor_pair(t)
            else:
                self._motor_set(t)
        else:
            return
        pack_events = self.pack_health.check(t)
        self._record(pack_events)
        if pack_events or self.pack_health.faults:
            self._adopt_pack_degradation()
        if self.prognosis.due(t):
            self._record(self.prognosis.check(t, est, self.motor_power.fault_vector()))

    #: a pipeline is itself a frame consumer (``replay_tlog(frame_consumer=pipeline)`` then finds ``report``)
    def __call__(self, frame) -> None:
        self.consume(frame)

    def _motor_pair(self, t: float) -> None:
        est = self.estimator
        tc = est.motor_current_time
        # evaluate once per pair, on its later frame, with both currents fresh
        if abs(tc[0] - tc[1]) > self.pair_within_s or t < max(tc[0], tc[1]):
            return
        v_string = np.empty(2)
        v_filter = None  # the filter's voltages only if a reading is stale (rare: spare the einsum)
        for q in range(2):
            total = 0.0
            for b in range(4):
                if MOTOR_OF_PACK[b] != q:
                    continue
                if t - self._pack_v_time[b] <= self.voltage_fresh_s:
                    total += self._pack_v[b]
                else:
                    if v_filter is None:
                        v_filter, _ = est.packs.voltage()
                    total += v_filter[b]
            v_string[q] = total
        if not np.all(np.isfinite(v_string)):
            return
        heard = [r for r in est.motor_rpm.tolist() if math.isfinite(r)]  # np.nanmean, without its warning machinery
        rpm = sum(heard) / len(heard) if heard else math.nan
        self._record(self.motor_power.update(t, float(est.motor_current[0]), float(est.motor_current[1]),
                                             float(v_string[0]), float(v_string[1]), rpm))
        # keep stored faults' latest state in step with the detector's (magnitude refines while active)
        for f in self.motor_power.faults.values():
            if f.key in self._index:
                self._faults[self._index[f.key]] = f

    def _motor_set(self, t: float) -> None:
        """A described vehicle: every motor's current, fresh together, against its bus voltage."""
        est = self.estimator
        if not isinstance(self.motor_power, EscImbalanceDetector):
            return
        tc = est.motor_current_time
        if tc.max() - tc.min() > self.pair_within_s or t < tc.max():
            return
        inputs = est.inputs
        v_filter, _ = est.packs.voltage()
        fresh = t - self._pack_v_time <= self.voltage_fresh_s
        v = np.where(fresh, self._pack_v, v_filter)
        bus = np.zeros(len(inputs.bus_parallel))
        np.add.at(bus, inputs.bus_of_pack, v)
        bus = np.where(inputs.bus_parallel, bus / np.bincount(inputs.bus_of_pack, minlength=len(bus)), bus)
        bus_of_motor = bus[inputs.bus_of_motor]
        if not (np.all(np.isfinite(bus_of_motor)) and np.all(np.isfinite(est.motor_current))):
            return
        self._record(self.motor_power.update(t, est.motor_current.copy(), bus_of_motor))
        for f in self.motor_power.faults.values():
            if f.key in self._index:
                self._faults[self._index[f.key]] = f

    def readiness(self) -> dict[str, str]:
        """What the pipeline can do now and why not: the estimator's readiness plus motor diagnosis."""
        return {**self.estimator.readiness(), "motor_diagnosis": self.motor_diagnosis}

    def _adopt_pack_degradation(self) -> None:
        """Let the estimator (and so the predictions) run each degraded pack on its diagnosed
        capacity and resistance; back to the parameter set when the fault clears."""
        for name in self.estimator.pack_names:
            est = self.pack_health.latest.get(name)
            cap = self.pack_health.faults.get((PACK_CAPACITY_LOSS, name))
            res = self.pack_health.faults.get((PACK_RESISTANCE_RISE, name))
            want = (est.resistance_rise + 1.0 if est is not None and res is not None and res.active else 1.0,
                    est.capacity_factor if est is not None and cap is not None and cap.active else 1.0)
            have = self._adopted.get(name, (1.0, 1.0))
            if abs(want[0] - have[0]) > 0.05 or abs(want[1] - have[1]) > 0.02:
                self.estimator.adopt_pack_scales(name, *want)
                self._adopted[name] = want
                self.prognosis.reset_baseline()
                log.info("pack %s: estimator adopts resistance x%.2f, capacity x%.2f", name, *want)

    def _record(self, events: list[tuple[str, Fault]]) -> None:
        for kind, f in events:
            if kind == "raise" and f.key in self._index and self._faults[self._index[f.key]].active:
                kind = "update"
            if kind == "raise":
                self._index[f.key] = len(self._faults)
                self._faults.append(f)
            elif f.key in self._index:
                self._faults[self._index[f.key]] = f
            self.events.append({"event": kind, "time_s": round(float(f.updated_s if f.updated_s is not None else f.time_s), 3),
                                "type": f.type, "component": f.component, "magnitude": round(float(f.magnitude), 4),
                                "confidence": round(float(f.confidence), 3)})
            log.info("%s %s %s m=%.3f at t=%.1f s", kind, f.type, f.component, f.magnitude, f.time_s)

    # ---- output --------------------------------------------------------------------------------------
    def _refresh(self) -> None:
        for source in (self.motor_power.faults.values(), self.pack_health.faults.values(),
                       self.prognosis.faults.values(), self.model_fidelity.faults.values()):
            for f in source:
                if f.key in self._index and self._faults[self._index[f.key]].time_s == f.time_s:
                    self._faults[self._index[f.key]] = f

    @property
    def faults(self) -> list[Fault]:
        """Every fault raised, in order, each in its latest state."""
        self._refresh()
        return list(self._faults)

    def active_faults(self) -> list[Fault]:
        self._refresh()
        return [f for f in self._faults if f.active]

    def report(self) -> dict:
        """Replay summary: faults (with message times), events, the final estimate and counters."""
        self._refresh()
        est = self.estimator.estimate()
        return {
            "faults": [f.to_dict() for f in self._faults],
            "events": list(self.events),
            "estimate": est.to_dict(),
            "frames": self.frames,
            "motor_power": {"samples": self.motor_power.samples, "low_power_skipped": self.motor_power.low_power_skipped},
            "readiness": self.readiness(),
            "pack_health": {n: e.__dict__ for n, e in self.pack_health.latest.items()},
            "prognosis": {"skipped_no_mission": self.prognosis.skipped_no_mission,
                          "latest": None if self.prognosis.latest_prediction is None
                          else self.prognosis.latest_prediction.to_dict()},
        }
