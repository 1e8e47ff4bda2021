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
from gcs_pdm.estimation.estimator import EstimatorConfig, StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad
from gcs_pdm.frames import AmbientFrame, MotorFrame, PackFrame
from gcs_pdm.models.params import ParameterSet
from gcs_pdm.models.powertrain import Limits
from gcs_pdm.vehicle.description import VehicleDescription
from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

log = logging.getLogger(__name__)

#: the frame types that change the pipeline: the estimator's and the detectors' inputs. A frame of
#: any other type only counts (``consume`` ends in the estimator's ``ignore_frame``), so a replay
#: may pass such frames over and tell ``passed_over`` their number (tests/test_skip_frames.py
#: holds this set to the handlers)
CONSUMED_FRAME_TYPES = frozenset({PackFrame, MotorFrame, AmbientFrame})


def _motor_detector(vehicle: VehicleDescription, estimator: StateEstimator, shaft_config: MotorPowerConfig):
    """The detector of ``vehicle``'s motor power loss, by what its airframe and telemetry show
    (``motor_diagnosis_capability``): motors on one shaft (two, one type: the paper's) by their
    shares of the shaft power; others by the ESCs' imbalance, a multirotor's healthy motors each
    against its own share, learned early in the flight (trim, centre of gravity); else none."""
    diagnosable, _how = motor_diagnosis_capability(vehicle)
    if not diagnosable:
        return NoMotorDiagnosis(len(estimator.motor_names))
    if vehicle.airframe.type == "fixed_wing" and vehicle.airframe.shared_shaft:
        if len(estimator.motor_names) != 2:
            raise ValueError(f"vehicle {vehicle.name!r}: motors on one shaft are diagnosed in pairs; it has "
                             f"{len(estimator.motor_names)} motors (set airframe.shared_shaft false)")
        return MotorPowerLossDetector(estimator.motors.params[0].copy(), shaft_config)  # its own, not a view
    return EscImbalanceDetector(estimator.motor_names, estimator.motors.params,
                                learn_shares=vehicle.airframe.type == "multirotor")


class DiagnosisPipeline:
    def __init__(self, params: ParameterSet | None = None, *, limits: Limits | None = None,
                 estimator_config: EstimatorConfig = EstimatorConfig(),
                 motor_config: MotorPowerConfig = MotorPowerConfig(),
                 pack_config: PackHealthConfig = PackHealthConfig(),
                 prognosis_config: PrognosisConfig = PrognosisConfig(), seed: int = 0,
                 pair_within_s: float = 0.6, voltage_fresh_s: float = 3.0,
                 vehicle: VehicleDescription = PRESETS[DEFAULT_PRESET]):
        """``vehicle``: the ``VehicleDescription`` diagnosed (its packs and motors; the paper's
        aircraft is the ``edge540`` preset); ``params``: a parameter set flown over its values
        (``StateEstimator``); ``limits``: one limit for every pack and motor in the prognosis (a
        scenario's) instead of the description's. Motor power loss: motors on one shaft by their
        shares of the shaft power, others by the ESCs' imbalance, where the telemetry shows it."""
        self.vehicle = vehicle
        self.params = params
        self.estimator = StateEstimator(params, estimator_config, vehicle=vehicle)
        self.motor_power = _motor_detector(vehicle, self.estimator, motor_config)
        self.motor_diagnosis = motor_diagnosis_capability(vehicle)[1]
        est = self.estimator
        self.pack_health = PackHealthMonitor(est.packs.params.copy(), pack_config, names=est.pack_names)
        self.prognosis = PrognosisMonitor(limits, prognosis_config, seed=seed)
        self.model_fidelity = ModelMismatchMonitor(est.pack_names)
        self.pair_within_s = pair_within_s
        self.voltage_fresh_s = voltage_fresh_s
        # the latest measured voltage of each pack and its message time (Python floats: read per frame)
        self._pack_v = [math.nan] * len(est.pack_names)
        self._pack_v_time = [-math.inf] * len(est.pack_names)
        self._pack_index = {name: b for b, name in enumerate(est.pack_names)}
        self._motor_set_of = set(est.motor_names)
        # the motor detector runs at a set of ESC readings (a description's motors only where their
        # telemetry can show a power loss)
        self._motor_diagnosed = not isinstance(self.motor_power, NoMotorDiagnosis)
        self._handlers: dict[type, object] = {}
        self._health_add = self.pack_health.add
        self._fidelity_idle = self.model_fidelity.idle
        topo = est.topology
        self._packs_of_bus = [[int(b) for b in np.flatnonzero(topo.bus_of_pack == k)]
                              for k in range(len(topo.bus_parallel))]
        self._bus_parallel = [bool(x) for x in topo.bus_parallel]
        self._bus_of_motor = [int(k) for k in topo.bus_of_motor]
        self._buses = list(zip(self._packs_of_bus, self._bus_parallel))
        self._faults: list[Fault] = []
        self._index: dict[tuple[str, str], int] = {}
        self.events: list[dict] = []
        self.frames = 0
        self._adopted: dict[str, tuple[float, float]] = {}

    # ---- input ---------------------------------------------------------------------------------------
    def set_mission(self, load: FutureLoad, start_s: float | None = None) -> None:
        """The shaft-power load of the rest of the mission from message time ``start_s`` (default: now)."""
        self.prognosis.set_mission(load, self.estimator.time_s if start_s is None else start_s)

    #: what a replay must hand over (``gcs_pdm.mavlink.replay``: the other frames are only counted)
    consumed_frame_types = CONSUMED_FRAME_TYPES

    def passed_over(self, count: int) -> None:
        """``count`` frames of types outside ``consumed_frame_types`` went by without being handed
        over: counted as ``consume`` would count them (it would do nothing else with them)."""
        self.frames += count

    def consume(self, frame) -> None:
        self.frames += 1
        handler = self._handlers.get(type(frame))
        if handler is None:
            handler = self._handlers[type(frame)] = self._handler_for(frame)
        handler(frame)

    def _handler_for(self, frame):
        """The handler of a frame's type. A frame that changes nothing the estimator or a detector
        uses (position, air data, status, mission progress: two thirds of a log) ends there."""
        if isinstance(frame, PackFrame):
            return self._pack_frame
        if isinstance(frame, MotorFrame):
            return self._motor_frame
        # ambient: the estimator's alone, no check follows; anything else: ``ignore_frame``
        return self.estimator.handler_for(frame)

    def _pack_frame(self, frame: PackFrame) -> None:
        # every BATTERY_STATUS frame (a quarter of a log): the estimator's pack step called directly,
        # the model-fidelity monitor only when its pack's test is raised or a debounce is pending
        est = self.estimator
        b = est._pack(frame)  # the pack's index, -1: unknown
        t = float(frame.time_s)
        if b >= 0:
            v = frame.voltage_v
            # a frame older than the pack's last (the estimator skipped it as out of order) must not
            # put its older voltage and time back in the ESC detector's bus voltage
            if v is not None and t >= self._pack_v_time[b]:
                if math.isfinite(v):
                    self._pack_v[b] = v
                    self._pack_v_time[b] = t
                if est.packs.initialised[b]:
                    self._health_add(b, t, float(est.latest_pack_current(b)), float(v), est.ambient_c)
            if est.mismatch_active(b) or not self._fidelity_idle[b]:
                events = self.model_fidelity.update(t, est, frame.pack)
                if events:
                    self._record(events)
        self._checks(t)

    def _motor_frame(self, frame: MotorFrame) -> None:
        # every ESC frame (a tenth of a log): the estimator's motor step called directly
        if self.estimator._motor(frame) >= 0:  # the motor's index, -1: unknown
            t = float(frame.time_s)
            if self._motor_diagnosed:
                self._motors(t)
            self._checks(t)

    def _checks(self, t: float) -> None:
        """The periodic checks, after a pack or motor frame: the pack-health fits (every
        ``check_every_s``) and the prognosis (when due). The estimator's adopted pack degradation
        follows the pack-health faults, which change only when a check runs."""
        health = self.pack_health
        if health.due(t):
            pack_events = health.check(t)
            self._record(pack_events)
            if pack_events or health.faults:
                self._adopt_pack_degradation()
        if self.prognosis.due(t):
            self._record(self.prognosis.check(t, self.estimator, self.motor_power.fault_vector()))

    #: a pipeline is itself a frame consumer (``replay_tlog(frame_consumer=pipeline)`` then finds ``report``)
    def __call__(self, frame) -> None:
        self.consume(frame)

    def _motors(self, t: float) -> None:
        """Once per set of ESC readings, on its last frame with every current fresh: each motor's
        current against its bus voltage (the string of packs feeding it; the mean of a parallel bus).
        Plain Python floats: this runs at every motor frame and the vectors are two to eight long."""
        est = self.estimator
        tc, currents, rpms = est.motor_readings()
        latest = max(tc)
        if latest - min(tc) > self.pair_within_s or t < latest:
            return
        bus = []
        v_filter = None  # the filter's voltages only if a reading is stale (rare: spare the einsum)
        pack_v, pack_v_time, fresh_s = self._pack_v, self._pack_v_time, self.voltage_fresh_s
        for packs, parallel in self._buses:
            total = 0.0
            for b in packs:
                if t - pack_v_time[b] <= fresh_s:
                    total += pack_v[b]
                else:
                    if v_filter is None:
                        v_filter = est.packs.voltage()[0].tolist()
                    total += v_filter[b]
            bus.append(total if not parallel else total / len(packs) if packs else math.nan)
        bus_of_motor = [bus[k] for k in self._bus_of_motor]
        isfinite = math.isfinite
        if not all(map(isfinite, bus_of_motor)):
            return
        if isinstance(self.motor_power, MotorPowerLossDetector):  # motors on one shaft: their shares
            heard = [r for r in rpms if isfinite(r)]  # np.nanmean, without its warnings
            rpm = sum(heard) / len(heard) if heard else math.nan
            self._record(self.motor_power.update(t, currents[0], currents[1], bus_of_motor[0], bus_of_motor[1], rpm))
        elif all(map(isfinite, currents)):
            # the estimator's list is its own: the detector keeps a copy (its latest evidence)
            events = self.motor_power.update_floats(t, currents.copy(), bus_of_motor)
            if events:
                self._record(events)

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
            "prognosis": self.prognosis.status(self.estimator.time_s),
        }
