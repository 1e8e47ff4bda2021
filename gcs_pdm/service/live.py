"""The live decision loop: frames → estimator → diagnoser → (new fault / deviation) → planner →
upload → confirmation by download, in message time.

Threads, and why there are three:

* the link's reader thread hands every frame to :meth:`LiveLoop._on_frame`, which only enqueues
  it (the reader must never wait for us);
* the telemetry thread (:meth:`LiveLoop._run`) feeds the estimator and the diagnoser and updates
  the live state — it never plans, uploads or fits, so telemetry is never held up;
* one decision worker runs planning, uploads and downloads, one at a time (two uploads must never
  interleave on the link). A replan requested while one runs is remembered and runs next.

A replan works on a snapshot taken by the telemetry thread at the message time of the trigger, so
what is planned is exactly the state the diagnosis saw.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from gcs_pdm import missions as M
from gcs_pdm.diagnosis.faults import Fault, motor_faults
from gcs_pdm.frames import AirdataFrame, MissionProgressFrame, PositionFrame, StatusTextFrame
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES
from gcs_pdm.models.powertrain import MotorFault, PowertrainState
from gcs_pdm.service import adapters
from gcs_pdm.service.decision import (Candidate, catalogue_from_items, choose, match_items, remaining_route,
                                      route_of_items, same_mission)

log = logging.getLogger(__name__)

PREDICT_PERIOD_S = 10.0
MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
#: a diagnosed magnitude that changes by this much is a new fault for the planner
MAGNITUDE_STEP = 0.1
STATUS_PERIOD_S = 1.0


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What a replan starts from, taken on the telemetry thread."""

    time_s: float
    state: PowertrainState
    position: tuple[float, float, float]  # lat, lon, altitude above home
    ambient_c: float
    faults: tuple[MotorFault, ...]
    fault_records: tuple[Fault, ...]  # the diagnoser's active faults (operator faults are in ``faults``)
    current_seq: int | None
    soc: tuple[float, ...]


class LiveLoop:
    def __init__(self, service, link, mission_client, *, estimator=None, diagnoser=None):
        self.service = service
        self.link = link
        self.mc = mission_client
        self.params = service.params
        self.diagnoser = diagnoser if diagnoser is not None else adapters.make_diagnoser(
            self.params, service.limits.kernel_limits() if service.limits is not None else None)
        shared = adapters.estimator_of(self.diagnoser) if estimator is None else None
        self.estimator = estimator or shared or adapters.make_estimator(self.params)
        # The pipeline feeds its own estimator; feeding it twice would double-count every frame.
        self._feed_estimator = shared is None
        self._frames: queue.Queue = queue.Queue(maxsize=50_000)
        self.frames_dropped = 0
        self.frames_seen = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="decide")
        # Predictions have their own worker: a long plan must not freeze the status page's numbers.
        self._predictor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="predict")
        self._predicting = False
        self._last_predict_s = -math.inf
        self._airdata: tuple[float, float] | None = None
        self._lock = threading.Lock()
        self._busy = False
        self._pending: tuple[str, Snapshot] | None = None
        # mission knowledge
        self.mission_items: list[M.MissionItem] | None = None
        self.mission_time_s: float | None = None
        self.catalogue = list(service.catalogue) if service.catalogue else None
        self.home: tuple[float, float, float] | None = None
        self.visited: set[int] = set()
        self.reward_collected = 0.0
        # diagnosis bookkeeping
        self._fault_ids: dict[tuple[str, str], tuple[int, float]] = {}
        # operator faults by fault id (or by motor when declared without one)
        self._operator_faults: dict[object, Fault] = {}
        self._last_status_s = -math.inf
        self._last_replan_s = -math.inf
        self._expectation: dict | None = None
        self._deferred: str | None = None  # a replan asked for before the estimator had a state
        self._loads: dict[int, tuple] = {}  # plan id -> (FutureLoad of its route, message time)
        self._time_s: float | None = None
        self._ground_alt_amsl: float | None = None
        self._position = (math.nan, math.nan, math.nan)

    # --- lifecycle -------------------------------------------------------------------------------

    def start(self) -> "LiveLoop":
        self.link.add_frame_listener(self._on_frame)
        self._thread = threading.Thread(target=self._run, name="telemetry", daemon=True)
        self._thread.start()
        self._worker.submit(self._guard, self._initial_download)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._worker.shutdown(wait=True, cancel_futures=True)
        self._predictor.shutdown(wait=True, cancel_futures=True)

    def _guard(self, fn, *args) -> Any:
        try:
            return fn(*args)
        except Exception:  # noqa: BLE001 - the worker must survive any one failure
            log.exception("decision worker: %s failed", getattr(fn, "__name__", fn))
            return None

    # --- telemetry thread --------------------------------------------------------------------------

    def _on_frame(self, frame) -> None:
        try:
            self._frames.put_nowait(frame)
        except queue.Full:
            self.frames_dropped += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self._frames.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                if callable(frame):  # work handed over by the decision worker (see _on_telemetry_thread)
                    frame()
                else:
                    self.process(frame)
            except Exception:  # noqa: BLE001 - one bad frame must not stop the loop
                log.exception("frame %r could not be processed", frame)

    def _on_telemetry_thread(self, fn) -> None:
        """Run ``fn`` between two frames on the telemetry thread (the filters are not thread-safe);
        driven directly, before the next :meth:`process`."""
        self._frames.put(fn)

    def process(self, frame) -> None:
        """One frame, in message time (public so tests and replays can drive it directly)."""
        if self._thread is None:  # driven directly: run the work handed over since the last frame
            while True:
                try:
                    fn = self._frames.get_nowait()
                except queue.Empty:
                    break
                if callable(fn):
                    fn()
        self.frames_seen += 1
        st = self.service.state
        st.apply_frame(frame)
        t = frame.time_s
        self._time_s = t if self._time_s is None else max(self._time_s, t)
        if isinstance(frame, PositionFrame) and frame.lat_deg is not None:
            self._position = (frame.lat_deg, frame.lon_deg, frame.relative_alt_m or 0.0)
            if self._ground_alt_amsl is None and frame.alt_m is not None and frame.relative_alt_m is not None:
                self._ground_alt_amsl = frame.alt_m - frame.relative_alt_m
        elif isinstance(frame, AirdataFrame) and frame.airspeed is not None:
            self._airdata = (frame.airspeed, frame.climb_rate or 0.0)
        elif isinstance(frame, MissionProgressFrame) and frame.reached_seq is not None:
            self._reached(frame.reached_seq, t)
        elif isinstance(frame, StatusTextFrame):
            self.service.events.publish("statustext", time_s=t, severity=frame.severity, text=frame.text)
            if frame.severity <= 2:
                st.update(failed=frame.text)
        if self._feed_estimator:
            self.estimator.consume(frame)
        self.diagnoser.consume(frame)
        if t - self._last_status_s >= STATUS_PERIOD_S:
            self._last_status_s = t
            self._tick(t)

    def _reached(self, seq: int, t: float) -> None:
        if not self.mission_items or not self.catalogue:
            return
        number = match_items(self.mission_items, self.catalogue).get(seq)
        if number is not None and number not in self.visited:
            self.visited.add(number)
            reward = next(w.reward for w in self.catalogue if w.number == number)
            self.reward_collected += reward
            self.service.events.publish("mission", time_s=t, reached_seq=seq, waypoint=number, reward=reward,
                                        reward_collected=self.reward_collected)

    def _tick(self, t: float) -> None:
        st = self.service.state
        if self.estimator.ready():
            est = self.estimator.estimate()
            for i, n in enumerate(PACK_NAMES):
                st.update_nested("packs", n, soc=float(est.soc[i]), soc_sd=float(est.soc_sd[i]),
                                 temperature_c=float(est.pack_temp_c[i]), temperature_sd=float(est.pack_temp_sd[i]))
            for i, n in enumerate(MOTOR_NAMES):
                st.update_nested("motors", n, temperature_c=float(est.motor_temp_c[i]),
                                 temperature_sd=float(est.motor_temp_sd[i]))
        st.update(link={"connected": True, "received": self.link.received, "frames": self.frames_seen,
                        "frames_dropped": self.frames_dropped,
                        "vehicle": [self.link.target_system, self.link.target_component]})
        self._check_faults(t)
        self._check_deviation(t)
        if self._deferred is not None and self.estimator.ready():
            self.request_replan(self._deferred)
        if t - self._last_predict_s >= PREDICT_PERIOD_S:
            self._last_predict_s = t
            self._predict(t)

    def _predict(self, t: float) -> None:
        """Time to each pack's cut-off at the present load (Monte Carlo), off the telemetry thread."""
        from gcs_pdm.models.powertrain import air_density, shaft_power

        if self._predicting or self._airdata is None or not self.estimator.ready():
            return
        airspeed, climb = self._airdata
        if airspeed < 5.0:  # on the ground: no flight load to extrapolate
            return
        alt = (self._ground_alt_amsl or 0.0) + (self._position[2] if math.isfinite(self._position[2]) else 0.0)
        power = float(shaft_power(airspeed, climb, air_density(alt)))
        amb = self.service.state.get("ambient_c")
        limits = self.service.limits.kernel_limits() if self.service.limits is not None else None
        job = adapters.prediction_job(self.estimator, power, float(amb) if amb is not None else 20.0,
                                      self._all_motor_faults(), limits, seed=int(t))
        self._predicting = True

        def run() -> None:
            try:
                pred = job()
                st = self.service.state
                for i, n in enumerate(PACK_NAMES):
                    q05, q50, q95 = (float(v) for v in pred.pack_time_to_cutoff_s[i])
                    sd = (q95 - q05) / 3.29 if math.isfinite(q95) and math.isfinite(q05) else None
                    st.update_nested("packs", n, time_to_cutoff_s=q50 if math.isfinite(q50) else None, time_to_cutoff_sd=sd)
                st.update(prediction={"time_s": t, "shaft_power_w": power, **pred.to_dict()})
            except Exception:  # noqa: BLE001 - a failed prediction only leaves the old numbers
                log.exception("prediction failed")
            finally:
                self._predicting = False

        self._predictor.submit(run)

    def _check_faults(self, t: float) -> None:
        current = {f.key: f for f in adapters.active_faults(self.diagnoser)}
        new_or_grown = []
        for key, f in current.items():
            known = self._fault_ids.get(key)
            if known is None or abs(f.magnitude - known[1]) >= MAGNITUDE_STEP:
                if known is not None:
                    self.service.store.clear_fault(known[0])
                fid = self.service.store.add_fault(f, "diagnoser")
                self._fault_ids[key] = (fid, f.magnitude)
                new_or_grown.append(f)
                self.service.events.publish("fault", id=fid, time_s=t, kind=f.type, target=f.component,
                                            magnitude=f.magnitude, confidence=f.confidence, source="diagnoser")
                log.info("fault at t=%.1f s: %s %s magnitude %.2f", t, f.type, f.component, f.magnitude)
        for key in [k for k in self._fault_ids if k not in current]:
            fid, _ = self._fault_ids.pop(key)
            self.service.store.clear_fault(fid)
            self.service.events.publish("fault", id=fid, time_s=t, kind=key[0], target=key[1], cleared=True)
        self._update_motor_health(list(current.values()))
        if new_or_grown:
            self.request_replan("fault: " + ", ".join(f"{f.type} {f.component}" for f in new_or_grown))

    def _update_motor_health(self, diagnosed: list[Fault] | None) -> None:
        faults = self._all_motor_faults(diagnosed)
        for n in MOTOR_NAMES:
            f = next((x for x in faults if x.motor == n), None)
            self.service.state.update_nested("motors", n, health=1.0 - (f.magnitude if f else 0.0),
                                             fault={"kind": f.kind, "magnitude": f.magnitude} if f else None)

    def _all_motor_faults(self, diagnosed: list[Fault] | None = None) -> list[MotorFault]:
        """The planner's view of the diagnosed (default: the diagnoser's active ones) and the
        operator's faults together: the worst per motor."""
        if diagnosed is None:
            diagnosed = adapters.active_faults(self.diagnoser)
        return motor_faults([*diagnosed, *self._operator_faults.values()])

    def _check_deviation(self, t: float) -> None:
        """A significant deviation of observed from predicted discharge (the paper's second trigger)."""
        exp = self._expectation
        if exp is None or not self.estimator.ready() or t - self._last_replan_s < self.service.config.replan_cooldown_s:
            return
        frac = min(max((t - exp["t0"]) / max(exp["duration_s"], 1.0), 0.0), 1.0)
        expected = np.asarray(exp["soc0"]) + frac * (np.asarray(exp["soc1"]) - np.asarray(exp["soc0"]))
        observed = np.asarray(self.estimator.estimate().soc)
        dev = float(np.max(expected - observed))
        if dev > self.service.config.deviation_soc:
            self.service.events.publish("fault", time_s=t, kind="soc_deviation", target="vehicle", magnitude=dev,
                                        source="decision")
            self._expectation = None
            self.request_replan(f"deviation: SoC {dev:.3f} below the plan's prediction")

    # --- triggering ------------------------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        t = self._time_s if self._time_s is not None else 0.0
        state = self.estimator.powertrain_state()
        state = PowertrainState(pack_state=np.array(state.pack_state, copy=True),
                                motor_temp_c=np.array(state.motor_temp_c, copy=True))
        diagnosed = adapters.active_faults(self.diagnoser)
        amb = self.service.state.get("ambient_c")
        soc = tuple(float(v) for v in self.estimator.estimate().soc) if self.estimator.ready() else ()
        return Snapshot(time_s=t, state=state, position=self._position,
                        ambient_c=float(amb) if amb is not None else 20.0,
                        faults=tuple(self._all_motor_faults(diagnosed)), fault_records=tuple(diagnosed),
                        current_seq=self.service.state.get("mission")["current_seq"], soc=soc)

    def _elsewhere(self) -> bool:
        """Called from another thread than the running telemetry thread (e.g. an HTTP handler)? The
        estimator and diagnoser are not thread-safe: such calls are handed to the telemetry thread.
        Driven directly (no thread started, tests and replays) the caller is the telemetry thread."""
        return self._thread is not None and threading.current_thread() is not self._thread

    def request_replan(self, reason: str) -> None:
        """Queue a replan from the present state (any thread: the snapshot is taken on the telemetry thread)."""
        if self._elsewhere():
            self._on_telemetry_thread(lambda: self.request_replan(reason))
            return
        if not self.estimator.ready():
            log.info("replan (%s) deferred: estimator not ready", reason)
            self._deferred = reason
            return
        self._deferred = None
        snap = self.snapshot()
        self._last_replan_s = snap.time_s
        with self._lock:
            if self._busy:
                self._pending = (reason, snap)
                return
            self._busy = True
        self._worker.submit(self._plan_then_next, reason, snap)

    def declare_fault(self, fault: Fault, replan: bool, fault_id: int | None = None) -> None:
        """An operator-declared motor fault (``diagnosis.faults.operator_fault``), kept by its fault id
        (without one, by motor: a second declaration on that motor replaces the first)."""
        if self._elsewhere():
            self._on_telemetry_thread(lambda: self.declare_fault(fault, replan, fault_id))
            return
        self._operator_faults[fault_id if fault_id is not None else ("motor", fault.component)] = fault
        self._update_motor_health(None)
        if replan:
            self.request_replan(f"operator: {fault.type} {fault.component} {fault.magnitude:.2f}")

    def clear_operator_fault(self, motor: str, fault_id: int | None = None) -> None:
        """Clear one operator fault (by its id; without one, every operator fault on ``motor``)."""
        if self._elsewhere():
            self._on_telemetry_thread(lambda: self.clear_operator_fault(motor, fault_id))
            return
        if fault_id is not None:
            self._operator_faults.pop(fault_id, None)
        else:
            for key in [k for k, f in self._operator_faults.items() if f.component == motor]:
                del self._operator_faults[key]
        self._update_motor_health(None)

    def _plan_then_next(self, reason: str, snap: Snapshot) -> None:
        while True:
            try:
                self._plan(reason, snap)
            except Exception as exc:  # noqa: BLE001 - recorded for the operator; the loop goes on
                log.exception("replan (%s) failed", reason)
                self.service.events.publish("plan", status="failed", time_s=snap.time_s, reason=reason,
                                            error=f"{type(exc).__name__}: {exc}")
            with self._lock:
                if self._pending is None:
                    self._busy = False
                    return
                reason, snap = self._pending
                self._pending = None

    # --- decision worker -----------------------------------------------------------------------

    def _initial_download(self) -> None:
        """Wait (however long) for the vehicle's first heartbeat, then read its mission."""
        while not self._stop.is_set():
            try:
                self.link.wait_for_vehicle(timeout=1.0)
                break
            except TimeoutError:
                continue
        else:
            return
        self.service.events.publish("link", connected=True, vehicle=[self.link.target_system, self.link.target_component])
        self.refresh_mission()

    def request_refresh(self) -> None:
        """Read the vehicle's mission again (e.g. after the ground station changed it), on the worker."""
        self._worker.submit(self._guard, self.refresh_mission)

    def refresh_mission(self) -> list[M.MissionItem]:
        items = self.mc.download()
        self._set_mission(items, source="download")
        return items

    def _set_mission(self, items: list[M.MissionItem], source: str) -> None:
        self.mission_items = list(items)
        self.mission_time_s = self._time_s
        if items:
            # Home (seq 0) is the vehicle's: it moves when the vehicle re-homes (e.g. at arming), so
            # every mission read refreshes it. (0, 0) is a vehicle without a GPS fix, never a home.
            h = items[0]
            absolute = h.frame in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT)
            if math.isfinite(h.lat_deg) and math.isfinite(h.lon_deg) and not (h.lat_deg == 0.0 and h.lon_deg == 0.0):
                self.home = (h.lat_deg, h.lon_deg, float(h.z) if absolute else 0.0)
            else:
                log.warning("the vehicle's home item is (%s, %s): no GPS fix yet; home %s", h.lat_deg, h.lon_deg,
                            "unknown" if self.home is None else "kept from an earlier read")
        if self.catalogue is None and items:
            self.catalogue = catalogue_from_items(items, reward=1.0)
            log.info("no mission objectives configured: each of the %d waypoints is worth 1", len(self.catalogue))
        self.service.state.update(mission={"count": len(items)})
        route = route_of_items(items, self.catalogue or [])
        self.service.events.publish("mission", time_s=self._time_s, source=source, count=len(items), route=route)

    def _plan(self, reason: str, snap: Snapshot) -> None:
        svc = self.service
        cfg = svc.config
        if self.mission_items is None:
            self.refresh_mission()
        if not self.catalogue or self.home is None:
            log.warning("replan (%s) skipped: no mission on the vehicle to plan from", reason)
            return
        keep = remaining_route(self.mission_items, snap.current_seq, self.catalogue, self.visited)
        svc.events.publish("plan", status="planning", time_s=snap.time_s, reason=reason,
                           faults=[dataclasses.asdict(f) for f in snap.faults])
        home = (self.home[0], self.home[1], self.home[2] or self._ground_alt_amsl or 0.0)
        cands, info = adapters.plan_candidates(
            self.params, snap.state, snap.faults, self.catalogue, home, snap.ambient_c, snap.position, keep,
            planner=cfg.planner, particles=cfg.particles, seed=cfg.planner_seed, deadline_s=cfg.planner_deadline_s,
            time_s=snap.time_s, visited=sorted(self.visited), reward_collected=self.reward_collected,
            limits=svc.limits)
        chosen, why = choose(cands)
        load = (info["loads"].get(chosen.name), snap.time_s)
        body = {"reason": reason, "policy": svc.policy, "parameter_set": self.params.name,
                "faults": [dataclasses.asdict(f) for f in snap.faults], "fault_records": [f.to_dict() for f in snap.fault_records],
                "candidates": [c.to_dict() for c in cands], "chosen": chosen.to_dict(), "why": why,
                "previous_items": [M.item_to_json(i) for i in self.mission_items],
                "previous_route": keep, "plan_time_s": info["plan_time_s"], "planner": info["planner"],
                "scenario": info["scenario"], "visited": sorted(self.visited)}
        if chosen.name == "keep":
            pid = svc.store.add_plan(body, reason, "kept", snap.time_s)
            self._supersede_proposals(pid)
            self._loads[pid] = load
            self._expect(snap, chosen, pid)
            svc.events.publish("plan", id=pid, status="kept", time_s=snap.time_s, why=why, chosen=chosen.to_dict(),
                               operator_decision_needed=not chosen.feasible)
            if not chosen.feasible:
                # Nothing gets home, and the current mission reaches the most before it fails: there
                # is nothing better to upload, but the operator must hear it now, not find it later.
                self.statustext("PDM: no route gets home, mission kept: DECIDE", MAV_SEVERITY_CRITICAL)
            return
        mission = chosen.extra["mission"]
        items = [M.item_from_json(d) for d in mission["items"]]
        body["items"] = mission["items"]
        body["current_seq"] = mission["current_seq"]
        auto = svc.policy == "auto" and chosen.feasible
        pid = svc.store.add_plan(body, reason, "approved" if auto else "proposed", snap.time_s)
        self._loads[pid] = load
        svc.events.publish("plan", id=pid, status="approved" if auto else "proposed", time_s=snap.time_s, why=why,
                           chosen=chosen.to_dict(), keep=next((c.to_dict() for c in cands if c.name == "keep"), None))
        self._supersede_proposals(pid)
        if auto:
            self.upload(pid, items, chosen, snap, mission["current_seq"])
        else:
            self.statustext(f"PDM: plan {pid} proposed, reward {chosen.reward:g}; approve on gcs-pdm",
                            MAV_SEVERITY_WARNING)

    def _supersede_proposals(self, pid: int) -> None:
        """A newer plan (kept, proposed or approved) makes every older proposal stale."""
        for old in self.service.store.plans(status="proposed", limit=100000):
            if old["id"] != pid and self.service.store.transition_plan(old["id"], "proposed", "superseded",
                                                                       f"by plan {pid}"):
                self.service.events.publish("plan", id=old["id"], status="superseded", by=pid)

    def _expect(self, snap: Snapshot | None, chosen: Candidate, plan_id: int) -> None:
        """What the chosen plan predicts, for the deviation check and the diagnoser's prognosis."""
        load, start = self._loads.pop(plan_id, (None, None))
        if load is not None and chosen.name != "home":
            self._on_telemetry_thread(lambda: adapters.set_mission_load(self.diagnoser, load, start))
        # the previous plan's prediction no longer describes the mission on board
        self._expectation = None
        if snap is None:
            return
        if snap.soc and chosen.extra.get("final_soc"):
            self._expectation = {"t0": snap.time_s, "soc0": list(snap.soc), "soc1": chosen.extra["final_soc"],
                                 "duration_s": chosen.extra.get("flight_time_s", 0.0)}

    def approve(self, plan_id: int) -> None:
        """Upload an operator-approved plan (runs on the decision worker)."""
        plan = self.service.store.plan(plan_id)
        items = [M.item_from_json(d) for d in plan["items"]]
        chosen = plan["chosen"]
        cand = Candidate(chosen["name"], tuple(chosen["route"]), chosen["feasible"], chosen["reward"],
                         chosen["reward_reached"], chosen["objective"], chosen.get("cause"),
                         {k: chosen[k] for k in ("final_soc", "flight_time_s") if k in chosen})
        self._worker.submit(self._guard, self.upload, plan_id, items, cand, None, plan.get("current_seq", 1))

    def revert(self, upload: dict, note: str) -> int:
        """A plan that restores ``upload``'s previous mission, uploaded on the worker; its id."""
        items = [M.item_from_json(d) for d in upload["previous_items"]]
        route = tuple(route_of_items(items, self.catalogue or []))
        current = self.service.state.get("mission")["current_seq"]
        # resume where the restored mission would have the vehicle: its first unvisited waypoint
        seq_of = {n: s for s, n in match_items(items, self.catalogue or []).items()}
        todo = [seq_of[n] for n in route if n not in self.visited and n in seq_of]
        current_seq = min(todo) if todo else max(len(items) - 1, 1)
        chosen = Candidate("revert", route, True, 0.0, 0.0, 0.0, None, {})
        body = {"reason": f"operator: revert upload {upload['id']}", "policy": self.service.policy,
                "parameter_set": self.params.name, "chosen": chosen.to_dict(), "why": note or "operator revert",
                "candidates": [], "items": [M.item_to_json(i) for i in items], "current_seq": current_seq,
                "previous_items": [M.item_to_json(i) for i in (self.mission_items or [])], "vehicle_item_before": current}
        pid = self.service.store.add_plan(body, body["reason"], "approved", self._time_s)
        self.service.events.publish("plan", id=pid, status="approved", time_s=self._time_s, reason=body["reason"],
                                    chosen=chosen.to_dict())
        self._worker.submit(self._guard, self.upload, pid, items, chosen, None, current_seq)
        return pid

    def upload(self, plan_id: int, items: list[M.MissionItem], chosen: Candidate, snap: Snapshot | None,
               current_seq: int = 1) -> bool:
        svc = self.service
        previous = list(self.mission_items or [])
        svc.events.publish("upload", plan_id=plan_id, status="uploading", count=len(items), time_s=self._time_s)
        from gcs_pdm.mavlink.mission_client import MissionError

        try:
            stats = self.mc.upload(items)
        except (MissionError, OSError) as exc:
            # Usually the vehicle keeps its mission; but if only the final MISSION_ACK was lost it
            # may hold the new one: read back what is really on board when the link allows.
            on_board = self._readback()
            uid = svc.store.add_upload(plan_id, "failed", {"error": str(exc), "items": [M.item_to_json(i) for i in items],
                                                           "previous_items": [M.item_to_json(i) for i in previous]})
            svc.store.set_plan_status(plan_id, "upload_failed", str(exc))
            if on_board is not None:
                self._set_mission(on_board, source="download")
            svc.events.publish("upload", id=uid, plan_id=plan_id, status="failed", error=str(exc), time_s=self._time_s)
            log.error("upload of plan %d failed (%s); mission on board: %s", plan_id, exc,
                      "unknown" if on_board is None else f"{len(on_board)} items read back")
            self.statustext(f"PDM: upload of plan {plan_id} failed", MAV_SEVERITY_WARNING)
            return False
        try:
            # An airborne vehicle heads for the first item of the new route, never the take-off
            # (gcs_pdm.planning.mission documents the layout).
            self.mc.set_current(current_seq)
            svc.state.update(mission={"current_seq": current_seq})
            confirmed = None
            if svc.config.confirm_download:
                back = self.mc.download()
                confirmed = same_mission(items, back)
                items_on_vehicle = back
            else:
                items_on_vehicle = items
        except (MissionError, OSError) as exc:
            # The vehicle accepted the new mission, but its current item (or the readback) is not
            # confirmed: an airborne vehicle might head for the take-off item. Tell the operator.
            on_board = self._readback()
            uid = svc.store.add_upload(plan_id, "uploaded_unconfirmed", {
                "error": str(exc), "items": [M.item_to_json(i) for i in items],
                "previous_items": [M.item_to_json(i) for i in previous], "route": list(chosen.route),
                "time_s": self._time_s, "current_seq": current_seq,
                "stats": dataclasses.asdict(stats) if dataclasses.is_dataclass(stats) else None})
            svc.store.set_plan_status(plan_id, "uploaded_unconfirmed", str(exc))
            self._loads.pop(plan_id, None)
            self._set_mission(on_board if on_board is not None else items,
                              source="download" if on_board is not None else "upload")
            self._expectation = None
            svc.events.publish("upload", id=uid, plan_id=plan_id, status="uploaded_unconfirmed", error=str(exc),
                               route=list(chosen.route), time_s=self._time_s)
            log.error("plan %d uploaded but not confirmed (%s): check the vehicle's mission and current item",
                      plan_id, exc)
            self.statustext(f"PDM: mission sent, wp {current_seq} unconfirmed: CHECK", MAV_SEVERITY_WARNING)
            return False
        status = "confirmed" if confirmed else ("sent" if confirmed is None else "mismatch")
        uid = svc.store.add_upload(plan_id, status, {
            "items": [M.item_to_json(i) for i in items], "previous_items": [M.item_to_json(i) for i in previous],
            "route": list(chosen.route), "time_s": self._time_s,
            "stats": dataclasses.asdict(stats) if dataclasses.is_dataclass(stats) else None})
        self._set_mission(items_on_vehicle, source="upload")
        if status == "mismatch":
            # What the vehicle holds is not the plan: no prediction of ours describes it.
            svc.store.set_plan_status(plan_id, "upload_mismatch", "mission readback differs from the plan")
            self._loads.pop(plan_id, None)
            self._expectation = None
            svc.events.publish("upload", id=uid, plan_id=plan_id, status=status, route=list(chosen.route),
                               reward=chosen.reward, time_s=self._time_s)
            log.error("plan %d: the mission read back differs from the one uploaded", plan_id)
            self.statustext("PDM: mission readback differs: CHECK", MAV_SEVERITY_WARNING)
            return False
        svc.store.set_plan_status(plan_id, "uploaded", status)
        self._expect(snap, chosen, plan_id)
        svc.events.publish("upload", id=uid, plan_id=plan_id, status=status, route=list(chosen.route),
                           reward=chosen.reward, time_s=self._time_s)
        self.statustext(f"PDM: new mission uploaded, wp {','.join(map(str, chosen.route)) or 'home'}", MAV_SEVERITY_NOTICE)
        return True

    def _readback(self) -> list[M.MissionItem] | None:
        """The vehicle's mission as downloaded now, or None if it cannot be read."""
        try:
            return self.mc.download()
        except Exception as exc:  # noqa: BLE001 - the caller records what it knows without it
            log.warning("mission readback failed: %s", exc)
            return None

    def statustext(self, text: str, severity: int = MAV_SEVERITY_NOTICE) -> None:
        """Tell the operator through the ground station (STATUSTEXT, 50 characters)."""
        try:
            self.link.send(self.link.mav.statustext_encode(severity, text.encode("ascii", "replace")[:50]))
        except Exception as exc:  # noqa: BLE001 - a lost notice must not fail the upload
            log.warning("STATUSTEXT not sent: %s", exc)
        self.service.events.publish("statustext", severity=severity, text=text, sent=True, time_s=self._time_s)
