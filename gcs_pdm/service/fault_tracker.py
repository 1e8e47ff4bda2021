"""The fault tracker: the diagnoser's faults and the operator's, kept in step with the store.

* each diagnosed fault (one per ``Fault.key``: type and component) is one stored fault; a magnitude
  that moves by ``MAGNITUDE_STEP`` or more is a new fault for the planner (the old one is cleared);
* operator faults are kept by their fault id, so clearing one leaves another on the same motor;
* the planner's view (:meth:`FaultTracker.motor_faults`) is the worst power loss per motor over
  both, and the status page's motor health follows it;
* faults belong to a flight (service/flights.py): a new flight starts with none active
  (:meth:`FaultTracker.new_flight`).

Runs on the telemetry thread (it reads the diagnoser, which is not thread-safe).
"""
from __future__ import annotations

import logging

from gcs_pdm.diagnosis.faults import ADVISORY_TYPES, Fault, motor_faults
from gcs_pdm.models.params import MOTOR_NAMES
from gcs_pdm.models.powertrain import MotorFault
from gcs_pdm.service import adapters

log = logging.getLogger(__name__)

#: a diagnosed magnitude that changes by this much is a new fault for the planner
MAGNITUDE_STEP = 0.1


class FaultTracker:
    def __init__(self, service, diagnoser):
        self.service = service
        self.diagnoser = diagnoser
        self._stored: dict[tuple[str, str], tuple[int, float]] = {}  # fault key -> (fault id, magnitude)
        # operator faults by fault id (or by motor when declared without one)
        self._operator: dict[object, Fault] = {}

    def diagnosed(self) -> list[Fault]:
        """The diagnoser's active faults."""
        return adapters.active_faults(self.diagnoser)

    def check(self, t: float) -> list[Fault]:
        """Bring the store up to date with the diagnoser at message time ``t``; the faults that are
        new or have grown (each one a reason to replan)."""
        store, events = self.service.store, self.service.events
        current = {f.key: f for f in self.diagnosed()}
        new_or_grown = []
        for key, f in current.items():
            known = self._stored.get(key)
            if known is None or abs(f.magnitude - known[1]) >= MAGNITUDE_STEP:
                if known is not None:
                    store.clear_fault(known[0])
                fid = store.add_fault(f, "diagnoser")
                self._stored[key] = (fid, f.magnitude)
                if f.type not in ADVISORY_TYPES:  # an advisory is told, not planned around
                    new_or_grown.append(f)
                events.publish("fault", id=fid, time_s=t, kind=f.type, target=f.component, magnitude=f.magnitude,
                               confidence=f.confidence, source="diagnoser")
                log.info("fault at t=%.1f s: %s %s magnitude %.2f", t, f.type, f.component, f.magnitude)
        for key in [k for k in self._stored if k not in current]:
            fid, _ = self._stored.pop(key)
            store.clear_fault(fid)
            events.publish("fault", id=fid, time_s=t, kind=key[0], target=key[1], cleared=True)
        self.update_motor_health(list(current.values()))
        return new_or_grown

    def new_flight(self, kept_fault_ids: set = frozenset()) -> None:
        """A flight began: nothing of the previous one is active (the store closed its faults, they
        stay in that flight's history); an operator carries one over explicitly
        (Service.carry_over_fault). ``kept_fault_ids``: the operator's faults declared on the ground
        since, which join the new flight."""
        self._stored.clear()
        self._operator = {k: f for k, f in self._operator.items() if k in kept_fault_ids}
        self.update_motor_health([])

    def declare(self, fault: Fault, fault_id: int | None = None) -> None:
        """An operator fault, kept by ``fault_id`` (without one, by motor: it replaces the last one)."""
        self._operator[fault_id if fault_id is not None else ("motor", fault.component)] = fault
        self.update_motor_health()

    def clear_operator(self, motor: str, fault_id: int | None = None) -> None:
        """Clear one operator fault (by its id; without one, every operator fault on ``motor``)."""
        if fault_id is not None:
            self._operator.pop(fault_id, None)
        else:
            for key in [k for k, f in self._operator.items() if f.component == motor]:
                del self._operator[key]
        self.update_motor_health()

    def motor_faults(self, diagnosed: list[Fault] | None = None) -> list[MotorFault]:
        """The planner's view of the diagnosed (default: the diagnoser's active ones) and the
        operator's faults together: the worst per motor."""
        if diagnosed is None:
            diagnosed = self.diagnosed()
        return motor_faults([*diagnosed, *self._operator.values()])

    def update_motor_health(self, diagnosed: list[Fault] | None = None) -> None:
        faults = self.motor_faults(diagnosed)
        for n in getattr(adapters.estimator_of(self.diagnoser), "motor_names", MOTOR_NAMES):
            f = next((x for x in faults if x.motor == n), None)
            self.service.state.update_nested("motors", n, health=1.0 - (f.magnitude if f else 0.0),
                                             fault={"kind": f.kind, "magnitude": f.magnitude} if f else None)
