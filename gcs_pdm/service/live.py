"""The live decision loop: frames → estimator → diagnoser → (new fault / deviation) → planner →
upload → confirmation by download, in message time.

Three parts, one file each, composed here:

* :class:`~gcs_pdm.service.telemetry_intake.TelemetryIntake`: the link's frames into the estimator
  and the diagnoser on the telemetry thread (never plans, uploads or fits);
* :class:`~gcs_pdm.service.fault_tracker.FaultTracker`: diagnosed and operator faults, per fault
  id, and the worst per motor (the planner's view);
* :class:`~gcs_pdm.service.plan_executor.PlanExecutor`: plan → approve → upload → readback on one
  decision worker, each upload ending in one :class:`~gcs_pdm.service.plan_executor.UploadOutcome`.

A replan works on a :class:`Snapshot` taken by the telemetry thread at the message time of the
trigger, so what is planned is exactly the state the diagnosis saw. ``LiveLoop`` is the surface
the service and the API use; calls from other threads are handed to the telemetry thread.
"""
from __future__ import annotations

import copy
import logging
import math

import numpy as np

from gcs_pdm import missions as M
from gcs_pdm.diagnosis.faults import Fault
from gcs_pdm.models.powertrain import PowertrainState
from gcs_pdm.service import adapters
from gcs_pdm.service.decision import proposal_gate
from gcs_pdm.service.fault_tracker import FaultTracker
from gcs_pdm.service.live_state import LinkLost
from gcs_pdm.service.plan_executor import MAV_SEVERITY_NOTICE, PlanExecutor, Snapshot, UploadOutcome
from gcs_pdm.service.telemetry_intake import TelemetryIntake
from gcs_pdm.service.vehicle_discovery import AwaitingVehicle, VehicleDiscovery
from gcs_pdm.vehicle.presets import PRESETS

__all__ = ["LinkLost", "LiveLoop", "Snapshot", "UploadOutcome"]

log = logging.getLogger(__name__)


class LiveLoop:
    def __init__(self, service, link, mission_client, *, estimator=None, diagnoser=None, discover: bool = False):
        """``discover``: without a vehicle description (``service.vehicle``), derive a provisional one
        from the first telemetry (service/vehicle_discovery.py) instead of assuming the paper's aircraft."""
        self.service = service
        self.link = link
        self.mc = mission_client
        self.discovery = None
        if diagnoser is None and discover and service.vehicle is None:
            self.discovery = VehicleDiscovery(link, lambda desc, notes: self.telemetry.call_soon(
                lambda: self.adopt_vehicle(desc, notes)))
            diagnoser = AwaitingVehicle(self.discovery.waiting)
            service.describe_vehicle(None, "deriving", waiting=self.discovery.waiting())
        elif service.vehicle is None:
            service.describe_vehicle(PRESETS["edge540"], "default")
        # none given and none to derive: the paper's aircraft, the edge540 preset (``Service.flown_vehicle``)
        vehicle = service.flown_vehicle()
        self.diagnoser = diagnoser if diagnoser is not None else self._make_diagnoser(vehicle)
        shared = adapters.estimator_of(self.diagnoser) if estimator is None else None
        self.estimator = estimator or shared or adapters.make_estimator(vehicle, service.parameter_override(vehicle))
        self.telemetry = TelemetryIntake(service, link, self.estimator, self.diagnoser, feed_estimator=shared is None)
        self._last_reevaluation_s = -math.inf
        self.faults = FaultTracker(service, self.diagnoser)
        self.executor = PlanExecutor(service, link, mission_client, self.telemetry, self.estimator, self.diagnoser)
        self._deferred: str | None = None  # a replan asked for before the estimator had a state
        # flights (service/flights.py): a new one starts with no fault of the last one active and,
        # after a flight ended or a reboot, with fresh filters (only those this loop built itself)
        self._owns_filters = diagnoser is None and estimator is None
        self._flights_begun = 0
        self.telemetry.on_clock = lambda t, armed: service.flights.observe(t, armed)
        self.telemetry.on_pack = service.flights.pack_frame
        self.telemetry.on_silent = lambda silent_s: service.flights.silent(silent_s)
        service.flights.on_begin = self._flight_began
        service.flights.serials.listen(link)
        if self._owns_filters:
            self._start_packs_from_history()
        # wiring (late-bound through self, so a replaced method is the one called)
        self.telemetry.on_reached = self.executor.reached
        self.telemetry.on_tick = self._tick
        self.telemetry.on_message = self.executor.watch
        self.telemetry.motor_faults = lambda: self.faults.motor_faults()
        self.executor.request_replan = lambda reason: self.request_replan(reason)
        self.publish_readiness()

    # --- lifecycle -------------------------------------------------------------------------------

    def start(self) -> "LiveLoop":
        self.telemetry.start()
        self.executor.start()
        if self.discovery is not None:
            self.discovery.start()
        return self

    def stop(self) -> None:
        if self.discovery is not None:
            self.discovery.stop()
        self.telemetry.stop()
        self.executor.stop()
        self.service.flights.serials.close()

    # --- the vehicle description and readiness ----------------------------------------------------

    def _make_diagnoser(self, vehicle):
        """The diagnoser of ``vehicle`` with the service's overrides of its values and limits."""
        svc = self.service
        return adapters.make_diagnoser(vehicle, svc.parameter_override(vehicle), svc.limits_override(vehicle))

    def adopt_vehicle(self, desc, notes: list[str]) -> None:
        """A description derived from the first telemetry: the link maps its packs and motors from
        now on, and the estimator and diagnoser are built from it (on the telemetry thread)."""
        from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping

        self.link.mapper.remap(frame_mapping(desc), envelope(desc))
        self.diagnoser = self._make_diagnoser(desc)
        self.estimator = adapters.estimator_of(self.diagnoser)
        for part in (self.telemetry, self.executor):
            part.estimator, part.diagnoser = self.estimator, self.diagnoser
        self.faults.diagnoser = self.diagnoser
        self.service.adopt_vehicle(desc, "provisional", notes)
        self._start_packs_from_history()
        self.publish_readiness()

    def _flight_began(self, flight_id: int, boundary, kept_fault_ids: set = frozenset()) -> None:
        rebooted = boundary.reason.startswith("vehicle reboot")
        if rebooted:
            self.telemetry.restart_clock()
        if (rebooted or self._flights_begun) and self._owns_filters and self.service.vehicle is not None:
            self.diagnoser = self._make_diagnoser(self.service.vehicle)
            self.estimator = adapters.estimator_of(self.diagnoser)
            for part in (self.telemetry, self.executor):
                part.estimator, part.diagnoser = self.estimator, self.diagnoser
            self.faults.diagnoser = self.diagnoser
            self._start_packs_from_history()
        self._flights_begun += 1
        self.faults.new_flight(kept_fault_ids)

    def _start_packs_from_history(self) -> None:
        """The packs' filters start from each pack's latest health (docs/packs.md), published as
        ``/status.pack_priors``; a failure leaves the description's priors (logged)."""
        from gcs_pdm.packs.priors import start_from_history

        try:
            started = start_from_history(self.estimator, self.service.pack_priors())
        except Exception:  # noqa: BLE001 - the description's priors are still a working start
            log.exception("the packs' filters could not start from their history; the description's priors")
            return
        self.service.state.update(pack_priors=started)

    def readiness(self) -> dict[str, str]:
        """What the service can do now and why not ("ready" or the reason), per capability."""
        fn = getattr(self.diagnoser, "readiness", None) or getattr(self.estimator, "readiness", None)
        out = dict(fn()) if fn is not None else {"state": "ready" if self.estimator.ready() else "not ready"}
        out["replan"] = out.get("prediction", out["state"])
        return out

    def replan_blocker(self) -> str | None:
        """Why a replan cannot run now (the operator's request is refused with it), or None."""
        # the published copy: this runs on HTTP threads, the filters belong to the telemetry thread
        why = (self.service.state.get("readiness") or {}).get("replan", "not known yet")
        return None if why == "ready" else why

    def publish_readiness(self) -> None:
        self.service.state.update(readiness=self.readiness())
        if self.discovery is not None and self.service.vehicle is None:
            self.service.describe_vehicle(None, "deriving", waiting=self.discovery.waiting())

    # --- what the service reads ------------------------------------------------------------------

    @property
    def mission_items(self) -> list[M.MissionItem] | None:
        return self.executor.mission_items

    @property
    def mission_time_s(self) -> float | None:
        return self.executor.mission_time_s

    @property
    def home(self) -> tuple[float, float, float] | None:
        return self.executor.home

    @property
    def visited(self) -> set[int]:
        return self.executor.visited

    # --- telemetry thread ------------------------------------------------------------------------

    def process(self, frame) -> None:
        """One frame, in message time (public so tests and replays can drive it directly)."""
        self.telemetry.process(frame)

    def _tick(self, t: float) -> None:
        self.publish_readiness()
        new_or_grown = self.faults.check(t)
        if new_or_grown:
            self.request_replan("fault: " + ", ".join(f"{f.type} {f.component}" for f in new_or_grown))
        self.executor.check_deviation(t)
        self.executor.check_mission_read(t)
        self._reevaluate(t)
        if self._deferred is not None and self.estimator.ready() and not self.telemetry.link_lost:
            self.request_replan(self._deferred)

    def _reevaluate(self, t: float) -> None:
        """Every ``reevaluate_every_s`` of message time in flight: the current mission's outlook
        from the current state, and a pending proposal re-planned from it (issue 31, part 4)."""
        every = self.service.config.reevaluate_every_s
        if t - self._last_reevaluation_s < every or self.telemetry.link_lost or not self.estimator.ready():
            return
        if not self.telemetry.flight_phase(t).flying:
            return
        if self._last_reevaluation_s == -math.inf:
            # the first evaluation comes one period into the flight: at the take-off roll the
            # estimate has just started (its spread is the prior's) and no decision should rest on it
            self._last_reevaluation_s = t
            return
        self._last_reevaluation_s = t
        self.executor.submit_outlook(self.snapshot())
        pending = self.service.store.plans(status="proposed", limit=1)
        if pending and t - (pending[0].get("time_s") or t) >= every and t - self.executor.last_replan_s >= every:
            self.request_replan(f"re-evaluation of plan {pending[0]['id']} (proposed at t={pending[0]['time_s']:.0f} s)")

    def proposal_gate(self, plan: dict):
        """May the operator decide on ``plan`` now, and is it still the decision (``decision.proposal_gate``)."""
        t = self.telemetry.time_s
        phase = self.telemetry.flight_phase(t) if t is not None else None
        return proposal_gate(plan.get("time_s"), t, reevaluate_every_s=self.service.config.reevaluate_every_s,
                             link_lost=self.telemetry.link_lost_reason if self.telemetry.link_lost else None,
                             failed=self.service.state.get("failed"),
                             # on the ground only when the telemetry says so (no airspeed yet is not "landed")
                             flying=phase is None or phase.flying or phase.reason.startswith("no "),
                             not_flying_reason=phase.reason if phase is not None else "",
                             plan_faults=plan.get("faults") or (),
                             faults_now=self.faults.motor_faults(self.faults.diagnosed()))

    def snapshot(self) -> Snapshot:
        t = self.telemetry.time_s if self.telemetry.time_s is not None else 0.0
        state = self.estimator.powertrain_state()
        state = PowertrainState(pack_state=np.array(state.pack_state, copy=True),
                                motor_temp_c=np.array(state.motor_temp_c, copy=True))
        diagnosed = self.faults.diagnosed()
        amb = self.service.state.get("ambient_c")
        soc = tuple(float(v) for v in self.estimator.estimate().soc) if self.estimator.ready() else ()
        return Snapshot(time_s=t, state=state, position=self.telemetry.position,
                        ambient_c=float(amb) if amb is not None else 20.0,
                        faults=tuple(self.faults.motor_faults(diagnosed)), fault_records=tuple(diagnosed),
                        current_seq=self.service.state.get("mission")["current_seq"], soc=soc,
                        estimator=copy.deepcopy(self.estimator) if self.estimator.ready() else None,
                        wind_en=self.service.state.wind_en())

    # --- operator and triggers (any thread) ------------------------------------------------------

    @property
    def link_lost(self) -> bool:
        return self.telemetry.link_lost

    def require_link(self, action: str) -> None:
        """Refuse ``action`` (raise :class:`LinkLost`, a 409) while the vehicle is not heard."""
        if self.telemetry.link_lost:
            raise LinkLost(f"{action} refused: link lost ({self.telemetry.link_lost_reason})")

    def request_replan(self, reason: str) -> None:
        """Queue a replan from the present state (the snapshot is taken on the telemetry thread)."""
        if self.telemetry.elsewhere():
            self.telemetry.call_soon(lambda: self.request_replan(reason))
            return
        if not self.estimator.ready() or self.telemetry.link_lost:
            # A silent vehicle's state is unknown: plan when it (and its state) is back.
            log.info("replan (%s) deferred: %s", reason, "link lost" if self.telemetry.link_lost
                     else "estimator not ready")
            self._deferred = reason
            return
        self._deferred = None
        self.executor.enqueue(reason, self.snapshot())

    def declare_fault(self, fault: Fault, replan: bool, fault_id: int | None = None) -> None:
        """An operator-declared motor fault (``diagnosis.faults.operator_fault``)."""
        if self.telemetry.elsewhere():
            self.telemetry.call_soon(lambda: self.declare_fault(fault, replan, fault_id))
            return
        self.faults.declare(fault, fault_id)
        if replan:
            self.request_replan(f"operator: {fault.type} {fault.component} {fault.magnitude:.2f}")

    def clear_operator_fault(self, motor: str, fault_id: int | None = None) -> None:
        """Clear one operator fault (by its id; without one, every operator fault on ``motor``)."""
        if self.telemetry.elsewhere():
            self.telemetry.call_soon(lambda: self.clear_operator_fault(motor, fault_id))
            return
        self.faults.clear_operator(motor, fault_id)

    # --- decision worker -------------------------------------------------------------------------

    def approve(self, plan_id: int) -> None:
        self.executor.approve(plan_id)

    def revert(self, upload: dict, note: str) -> int:
        return self.executor.revert(upload, note)

    def request_refresh(self) -> None:
        self.executor.request_refresh()

    def refresh_mission(self) -> list[M.MissionItem]:
        return self.executor.refresh_mission("operator")

    def upload(self, plan_id, items, chosen, snap, current_seq: int = 1) -> bool:
        """Upload a plan's mission now (on the caller's thread); whether it is confirmed on board."""
        return self.executor.upload(plan_id, items, chosen, snap, current_seq).ok

    def statustext(self, text: str, severity: int = MAV_SEVERITY_NOTICE) -> None:
        self.executor.statustext(text, severity)
