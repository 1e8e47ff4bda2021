"""The plan executor: plan → (approve) → upload → readback, on one decision worker.

One worker runs planning, uploads and downloads, one at a time (two uploads must never interleave
on the link). A replan asked for while one runs is remembered (the latest one) and runs next.

An upload ends in exactly one :class:`UploadOutcome`; what each outcome records (upload status,
plan status, the operator's notice) is in that table, and the upload's bookkeeping is written once
for all of them (:meth:`PlanExecutor.upload`).

The executor also owns what is known of the vehicle's mission (its items, home, the waypoints
visited and the reward collected) and the chosen plan's prediction, which the deviation check
compares with the estimate (the paper's second replan trigger).
"""
from __future__ import annotations

import dataclasses
import enum
import logging
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np

from gcs_pdm import missions as M
from gcs_pdm.diagnosis.faults import Fault
from gcs_pdm.mavlink.autopilots import AutopilotRules, missions_equivalent, rules_for
from gcs_pdm.mavlink.mission_client import MissionError
from gcs_pdm.mavlink.mission_watch import MissionWatcher
from gcs_pdm.models.powertrain import MotorFault, PowertrainState
from gcs_pdm.service import adapters
from gcs_pdm.service.decision import (Candidate, catalogue_from_items, choose, match_items, outlook_alarm, outlook_line,
                                      remaining_route, route_of_items)

log = logging.getLogger(__name__)

MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """What a replan starts from, taken on the telemetry thread at the trigger's message time."""

    time_s: float
    state: PowertrainState
    position: tuple[float, float, float]  # lat, lon, altitude above home
    ambient_c: float
    faults: tuple[MotorFault, ...]        # the planner's view: diagnosed and operator, worst per motor
    fault_records: tuple[Fault, ...]      # the diagnoser's active faults, as stored with the plan
    current_seq: int | None
    soc: tuple[float, ...]
    #: a frozen copy of the estimator (None before it is ready): the plans' Monte Carlo risk runs
    #: from it on the worker while the live filters move on
    estimator: Any = None
    #: the wind (the air's velocity east, north, m/s) the plan is flown in; None while unknown
    wind_en: tuple[float, float] | None = None


class UploadOutcome(enum.Enum):
    """How an upload ended: (upload record status, plan status, STATUSTEXT to the operator)."""

    CONFIRMED = ("confirmed", "uploaded", "PDM: new mission uploaded, wp {route}")
    #: uploaded and made current; confirmation by download is switched off
    SENT = ("sent", "uploaded", "PDM: new mission uploaded, wp {route}")
    #: the vehicle accepted the mission but its current item (or the readback) is not confirmed
    UPLOADED_UNCONFIRMED = ("uploaded_unconfirmed", "uploaded_unconfirmed",
                            "PDM: mission sent, wp {current_seq} unconfirmed: CHECK")
    #: what the vehicle holds is not the plan
    UPLOAD_MISMATCH = ("mismatch", "upload_mismatch", "PDM: mission readback differs: CHECK")
    FAILED = ("failed", "upload_failed", "PDM: upload of plan {plan_id} failed")

    def __init__(self, record_status: str, plan_status: str, notice: str):
        self.record_status = record_status
        self.plan_status = plan_status
        self.notice = notice

    @property
    def ok(self) -> bool:
        return self in (UploadOutcome.CONFIRMED, UploadOutcome.SENT)


@dataclasses.dataclass(frozen=True)
class _Transfer:
    outcome: UploadOutcome
    on_board: list[M.MissionItem] | None  # what the vehicle now holds as far as we know (None: unknown)
    source: str                           # how we know: "upload" or "download"
    error: str | None = None
    stats: Any = None
    readback: str | None = None           # the read-back's comparison with what was sent, in words


class PlanExecutor:
    def __init__(self, service, link, mission_client, telemetry, estimator, diagnoser):
        self.service = service
        self.link = link
        self.mc = mission_client
        self.telemetry = telemetry
        self.estimator = estimator
        self.diagnoser = diagnoser
        self._stop = threading.Event()
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="decide")
        self._lock = threading.Lock()
        self._busy = False
        self._pending: tuple[str, Snapshot] | None = None
        self._queued = 0  # tasks submitted to the worker and not finished
        #: wired by the live loop: how a replan is asked for (the deviation check's trigger)
        self.request_replan: Callable[[str], None] = lambda reason: None
        self.last_replan_s = -math.inf
        self._alarm_on = False  # the outlook's alarm is raised (said once per crossing)
        # mission knowledge
        self.mission_items: list[M.MissionItem] | None = None
        self.mission_time_s: float | None = None
        self.catalogue = list(service.catalogue) if service.catalogue else None
        self.home: tuple[float, float, float] | None = None
        self.visited: set[int] = set()
        self.reward_collected = 0.0
        # the chosen plan's prediction (deviation check) and each plan's load (diagnoser's prognosis)
        self.expectation: dict | None = None
        self.loads: dict[int, tuple] = {}  # plan id -> (FutureLoad of its route, message time)
        # when to read the vehicle's mission again, and its autopilot (whose storage rules decide
        # whether a read-back is the mission sent); fed by the telemetry thread, read by the worker
        self.watcher = MissionWatcher(getattr(getattr(link, "mav", None), "srcSystem", 255),
                                      getattr(getattr(link, "mav", None), "srcComponent", 190))
        self._watch_lock = threading.Lock()
        #: uploads interrupted by the last stop, waiting for a read of what the vehicle holds
        self._interrupted: list[tuple[int, int | None, dict]] = []

    # --- lifecycle -------------------------------------------------------------------------------

    def start(self) -> None:
        self.recover_interrupted()
        # not counted in ``working``: it may wait for the vehicle's first heartbeat for ever
        self._worker.submit(self._guard, self.initial_download, counted=False)

    def stop(self) -> None:
        self._stop.set()
        self._worker.shutdown(wait=True, cancel_futures=True)

    @property
    def busy(self) -> bool:
        """A plan is running or waiting to run."""
        return self._busy or self._pending is not None

    @property
    def working(self) -> bool:
        """Anything (plan, upload, mission read) is running or queued on the worker."""
        return self._queued > 0 or self.busy

    def _submit(self, fn, *args) -> None:
        with self._lock:
            self._queued += 1
        self._worker.submit(self._guard, fn, *args)

    def _guard(self, fn, *args, counted: bool = True) -> Any:
        try:
            return fn(*args)
        except Exception:  # noqa: BLE001 - the worker must survive any one failure
            log.exception("decision worker: %s failed", getattr(fn, "__name__", fn))
            return None
        finally:
            if counted:
                with self._lock:
                    self._queued -= 1

    def _now(self) -> float | None:
        return self.telemetry.time_s

    def rules(self) -> AutopilotRules:
        """How the vehicle's autopilot stores mission items (from its HEARTBEAT; generic before)."""
        with self._watch_lock:
            return rules_for(self.watcher.autopilot, self.watcher.vehicle_type)

    # --- the vehicle's mission -------------------------------------------------------------------

    def initial_download(self) -> None:
        """Wait (however long) for the vehicle's first heartbeat, then read its mission."""
        while not self._stop.is_set():
            try:
                self.link.wait_for_vehicle(timeout=1.0)
                break
            except TimeoutError:
                continue
        else:
            return
        self.service.events.publish("link", status="connected", connected=True, vehicle=[self.link.target_system, self.link.target_component])
        self.refresh_mission()

    def request_refresh(self) -> None:
        """Read the vehicle's mission again (e.g. after the ground station changed it), on the worker."""
        self._submit(self.refresh_mission)

    def refresh_mission(self, reason: str | None = None) -> list[M.MissionItem]:
        """Read the vehicle's mission now (on the caller's thread) and make it the plan baseline."""
        with self._watch_lock:
            if not self.watcher.reading:
                self.watcher.read_started(self._now() or 0.0)
        try:
            items = self.mc.download()
        except BaseException:
            with self._watch_lock:
                self.watcher.read_failed(self._now() or 0.0)
            raise
        with self._watch_lock:
            self.watcher.read_done(len(items), self._now() or 0.0)
            home_known = self.watcher.home is not None
        if self._interrupted and (items or home_known):  # ArduPilot reads 0 items before home: not yet
            self._record_interrupted(items)
        if self.mission_items is not None and not missions_equivalent(self.mission_items, items, self.rules()):
            # Changed on board (e.g. by the ground station): the chosen plan's prediction no
            # longer describes the mission being flown.
            self.expectation = None
        self.set_mission(items, source="download", reason=reason)
        return items

    # --- recovery of uploads the last stop interrupted ---------------------------------------------

    def recover_interrupted(self) -> None:
        """At start, before anything is uploaded: an upload intent without an outcome (the service
        stopped mid-transfer) is ``interrupted`` and its plan ``upload_interrupted``; a plan left
        ``approved`` with no upload at all (stopped before the transfer began) too, since nothing
        will upload it now. What the vehicle holds is added at the first mission read."""
        store = self.service.store
        intents = store.unfinished_uploads()
        for up in intents:
            body = {k: v for k, v in up.items() if k not in ("id", "plan_id", "status", "created_at")}
            body["error"] = "the service stopped during the transfer"
            store.finish_upload(up["id"], "interrupted", body)
            self._interrupted.append((up["id"], up["plan_id"], body))
            if up["plan_id"] is not None:
                store.transition_plan(up["plan_id"], "approved", "upload_interrupted",
                                      f"upload {up['id']} interrupted: the service stopped during the transfer")
            log.warning("upload %d of plan %s was interrupted by the last stop; the vehicle's mission will be read "
                        "and recorded with it", up["id"], up["plan_id"])
            self.service.events.publish("upload", id=up["id"], plan_id=up["plan_id"], status="interrupted")
        for plan in store.plans(status="approved", limit=100000):
            store.transition_plan(plan["id"], "approved", "upload_interrupted",
                                  "the service stopped before its upload began")
            log.warning("plan %d was approved but never uploaded before the last stop", plan["id"])
            self.service.events.publish("plan", id=plan["id"], status="upload_interrupted")

    def _record_interrupted(self, on_board: list[M.MissionItem]) -> None:
        """What the vehicle holds, recorded with each interrupted upload (did the plan get there?)."""
        rules = self.rules()
        for uid, plan_id, body in self._interrupted:
            sent = [M.item_from_json(d) for d in body["items"]]
            comparison = missions_equivalent(sent, on_board, rules)
            body.update(vehicle_items=[M.item_to_json(i) for i in on_board], vehicle_read_time_s=self._now(),
                        readback=comparison.summary(), vehicle_holds_plan=comparison.equivalent)
            # the plan's note first: whoever sees the upload's read-back finds its plan's note too
            if plan_id is not None:
                held = "holds" if comparison.equivalent else "does not hold"
                self.service.store.set_plan_status(plan_id, "upload_interrupted",
                                                   f"read at restart: the vehicle {held} this plan's mission")
            self.service.store.finish_upload(uid, "interrupted", body)
            self.service.events.publish("upload", id=uid, plan_id=plan_id, status="interrupted",
                                        vehicle_holds_plan=comparison.equivalent, time_s=self._now())
        self._interrupted = []

    # --- following the vehicle's mission -----------------------------------------------------------

    def watch(self, msg, time_s: float) -> None:
        """One of the vehicle's messages, at its message time, for the mission watcher (telemetry thread)."""
        with self._watch_lock:
            self.watcher.on_message(msg, time_s)

    def check_mission_read(self, time_s: float) -> None:
        """Start a read of the vehicle's mission on the worker when the watcher says one is due
        (telemetry thread): home set, the mission changed on board, or an earlier read to retry."""
        if self.telemetry.link_lost:
            return
        with self._watch_lock:
            due = self.watcher.due(time_s)
            if due is None:
                return
            self.watcher.read_started(time_s)
        log.info("reading the vehicle's mission: %s", due.reason)
        self._submit(self.refresh_mission, due.reason)

    def set_mission(self, items: list[M.MissionItem], source: str, reason: str | None = None) -> None:
        self.mission_items = list(items)
        self.mission_time_s = self._now()
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
        # not only at the first read: one before any mission was uploaded (home alone) gives no waypoint
        if not self.catalogue and items:
            self.catalogue = catalogue_from_items(items, reward=1.0)
            log.info("no mission objectives configured: each of the %d waypoints is worth 1", len(self.catalogue))
        self.service.state.update(mission={"count": len(items)})
        route = route_of_items(items, self.catalogue or [])
        self.service.events.publish("mission", time_s=self._now(), source=source, count=len(items), route=route,
                                    **({"reason": reason} if reason else {}))

    def reached(self, seq: int, t: float) -> None:
        """The vehicle reached mission item ``seq`` (telemetry thread): collect its waypoint's reward."""
        if not self.mission_items or not self.catalogue:
            return
        number = match_items(self.mission_items, self.catalogue).get(seq)
        if number is not None and number not in self.visited:
            self.visited.add(number)
            reward = next(w.reward for w in self.catalogue if w.number == number)
            self.reward_collected += reward
            self.service.events.publish("mission", time_s=t, reached_seq=seq, waypoint=number, reward=reward,
                                        reward_collected=self.reward_collected)

    # --- the chosen plan's prediction --------------------------------------------------------------

    def check_deviation(self, t: float) -> None:
        """A significant deviation of observed from predicted discharge (telemetry thread)."""
        exp = self.expectation
        cfg = self.service.config
        if exp is None or not self.estimator.ready() or t - self.last_replan_s < cfg.replan_cooldown_s:
            return
        frac = min(max((t - exp["t0"]) / max(exp["duration_s"], 1.0), 0.0), 1.0)
        expected = np.asarray(exp["soc0"]) + frac * (np.asarray(exp["soc1"]) - np.asarray(exp["soc0"]))
        observed = np.asarray(self.estimator.estimate().soc)
        dev = float(np.max(expected - observed))
        if dev > cfg.deviation_soc:
            self.service.events.publish("fault", time_s=t, kind="soc_deviation", target="vehicle", magnitude=dev,
                                        source="decision")
            self.expectation = None
            self.request_replan(f"deviation: SoC {dev:.3f} below the plan's prediction")

    def _expect(self, snap: Snapshot | None, chosen: Candidate, plan_id: int) -> None:
        """What the chosen plan predicts, for the deviation check and the diagnoser's prognosis."""
        load, start = self.loads.pop(plan_id, (None, None))
        if load is not None and chosen.name != "home":
            self.telemetry.call_soon(lambda: adapters.set_mission_load(self.diagnoser, load, start))
        # the previous plan's prediction no longer describes the mission on board
        self.expectation = None
        if snap is None:
            return
        if snap.soc and chosen.extra.get("final_soc"):
            self.expectation = {"t0": snap.time_s, "soc0": list(snap.soc), "soc1": chosen.extra["final_soc"],
                                "duration_s": chosen.extra.get("flight_time_s", 0.0)}

    # --- planning ----------------------------------------------------------------------------------

    def enqueue(self, reason: str, snap: Snapshot) -> None:
        """Plan from ``snap`` on the worker; while one plan runs, the latest request waits for it."""
        self.last_replan_s = snap.time_s
        with self._lock:
            if self._busy:
                self._pending = (reason, snap)
                return
            self._busy = True
        self._submit(self._plan_then_next, reason, snap)

    def _plan_then_next(self, reason: str, snap: Snapshot) -> None:
        while True:
            try:
                self.plan(reason, snap)
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

    def plan(self, reason: str, snap: Snapshot) -> None:
        """Plan, choose, record; keep, propose or (policy auto, feasible) upload. On the worker."""
        svc = self.service
        cfg = svc.config
        if self.mission_items is None:
            self.refresh_mission()
        if not self.catalogue or self.home is None:
            log.warning("replan (%s) skipped: no mission on the vehicle to plan from", reason)
            return
        keep = remaining_route(self.mission_items, snap.current_seq, self.catalogue, self.visited)
        faults = [dataclasses.asdict(f) for f in snap.faults]
        svc.events.publish("plan", status="planning", time_s=snap.time_s, reason=reason, faults=faults)
        home = (self.home[0], self.home[1], self.home[2] or self.telemetry.ground_alt_amsl or 0.0)
        cands, info = adapters.plan_candidates(
            snap.state, snap.faults, self.catalogue, home, snap.ambient_c, snap.position, keep,
            planner=cfg.planner, particles=cfg.particles, seed=cfg.planner_seed, deadline_s=cfg.planner_deadline_s,
            time_s=snap.time_s, visited=sorted(self.visited), reward_collected=self.reward_collected,
            **self._flown(), wind_en=snap.wind_en,
            max_failure_probability=cfg.max_failure_probability, risk_samples=cfg.risk_samples,
            estimator=snap.estimator)
        chosen, why = choose(cands)
        cands, chosen = self._assess_risk(snap, cands, chosen, info["loads"])
        load = (info["loads"].get(chosen.name), snap.time_s)
        body = {"reason": reason, "policy": svc.policy, "parameter_set": svc.params.name,
                "faults": faults, "fault_records": [f.to_dict() for f in snap.fault_records],
                "candidates": [c.to_dict() for c in cands], "chosen": chosen.to_dict(), "why": why,
                "previous_items": [M.item_to_json(i) for i in self.mission_items],
                "previous_route": keep, "plan_time_s": info["plan_time_s"], "planner": info["planner"],
                "scenario": info["scenario"], "visited": sorted(self.visited)}
        if chosen.name == "keep":
            pid = svc.store.add_plan(body, reason, "kept", snap.time_s)
            self._supersede_proposals(pid)
            self.loads[pid] = load
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
        now = self._now()
        if auto and now is not None and now - snap.time_s > cfg.reevaluate_every_s:
            # the vehicle flew on while this was planned: its start is no longer where the vehicle is,
            # so it is not uploaded (issue 31: never act on a state the service cannot support); plan
            # again from the current state
            pid = svc.store.add_plan(body, reason, "superseded", snap.time_s)
            note = (f"stale: planned from t={snap.time_s:.0f} s, done at t={now:.0f} s "
                    f"(> reevaluate_every_s {cfg.reevaluate_every_s:g} s); re-planned from the current state")
            svc.events.publish("plan", id=pid, status="superseded", time_s=now, why=note, chosen=chosen.to_dict())
            log.warning("plan %d not uploaded: %s", pid, note)
            self.request_replan(f"plan {pid} went stale while planning")
            return
        pid = svc.store.add_plan(body, reason, "approved" if auto else "proposed", snap.time_s)
        self.loads[pid] = load
        svc.events.publish("plan", id=pid, status="approved" if auto else "proposed", time_s=snap.time_s, why=why,
                           chosen=chosen.to_dict(), keep=next((c.to_dict() for c in cands if c.name == "keep"), None))
        self._supersede_proposals(pid)
        if auto:
            self.upload(pid, items, chosen, snap, mission["current_seq"])
        else:
            self.statustext(f"PDM: plan {pid} proposed, reward {chosen.reward:g}; approve on gcs-pdm",
                            MAV_SEVERITY_WARNING)

    def _flown(self) -> dict:
        """The vehicle the planner flies (the service's ``flown_vehicle``: the description followed,
        else ``edge540``, as the estimator's count-down and the route risk) with the service's
        overrides of its values and limits, as ``plan_candidates``' keywords."""
        svc = self.service
        vehicle = svc.flown_vehicle()
        return {"vehicle": vehicle, "params": svc.parameter_override(vehicle),
                "limits": svc.plan_limits_override(vehicle)}

    def _assess_risk(self, snap: Snapshot, cands: list[Candidate], chosen: Candidate, loads: dict
                     ) -> tuple[list[Candidate], Candidate]:
        """The chosen route's and the current mission's Monte Carlo probability of failure and
        landing SoC (``adapters.route_risk``), added to those candidates; on the worker. The
        planner's verdict stays the decision: this is what the operator weighs it with. Any vehicle:
        the snapshot's estimator flies the description's packs and motors (its faults by the
        description's motor names, its limits). Without an estimate or a route load a candidate
        gets ``risk_unknown`` with the reason instead."""
        limits = self.service.limits_override(self.service.flown_vehicle())
        out, new_chosen = [], chosen
        for c in cands:
            if c.name not in (chosen.name, "keep"):
                out.append(c)
                continue
            if snap.estimator is None:
                risk = {"risk_unknown": "no state estimate when the plan was made"}
            elif loads.get(c.name) is None:
                risk = {"risk_unknown": "no load profile for this route"}
            else:
                try:
                    # one seed for every route of this plan: the same samples, so the difference is the route's
                    risk = adapters.route_risk(snap.estimator, loads[c.name], snap.faults, limits,
                                               seed=self.service.config.planner_seed + int(snap.time_s))
                except Exception as exc:  # noqa: BLE001 - the plan stands on the planner's verdict
                    log.exception("risk of route %s failed", c.name)
                    risk = {"risk_unknown": f"{type(exc).__name__}: {exc}"}
            assessed = dataclasses.replace(c, extra={**c.extra, **risk})
            out.append(assessed)
            if c is chosen:
                new_chosen = assessed
        return out, new_chosen

    def _supersede_proposals(self, pid: int) -> None:
        """A newer plan (kept, proposed or approved) makes every older proposal stale."""
        for old in self.service.store.plans(status="proposed", limit=100000):
            if old["id"] != pid and self.service.store.transition_plan(old["id"], "proposed", "superseded",
                                                                       f"by plan {pid}"):
                self.service.events.publish("plan", id=old["id"], status="superseded", by=pid)

    # --- the outlook: the current mission re-evaluated from the current state ---------------------------

    def submit_outlook(self, snap: Snapshot) -> None:
        self._submit(self.evaluate_outlook, snap)

    def evaluate_outlook(self, snap: Snapshot) -> None:
        """The current mission's P(failure) and landing SoC from ``snap`` over the risk draws
        (``/status.outlook``: the console's vehicle-level line); when the landing forecast crosses the
        reserve or P(failure) rises above ε: an alarm (the banner, a STATUSTEXT) and a replan, once
        per crossing. On the worker."""
        svc, cfg = self.service, self.service.config
        reserve = float(getattr(svc.limits, "landing_reserve_soc", 0.15)) if svc.limits is not None else 0.15
        why = None
        if cfg.max_failure_probability is None:
            why = "risk-bounded planning is off (max_failure_probability is null)"
        elif snap.estimator is None:
            why = "no state estimate yet"
        elif self.mission_items is None or not self.catalogue or self.home is None:
            why = "no mission on the vehicle to evaluate"
        if why is None:
            keep = remaining_route(self.mission_items, snap.current_seq, self.catalogue, self.visited)
            home = (self.home[0], self.home[1], self.home[2] or self.telemetry.ground_alt_amsl or 0.0)
            cands, _info = adapters.plan_candidates(
                snap.state, snap.faults, self.catalogue, home, snap.ambient_c, snap.position, keep,
                planner=None, particles=cfg.particles, seed=cfg.planner_seed, deadline_s=cfg.planner_deadline_s,
                time_s=snap.time_s, visited=sorted(self.visited), reward_collected=self.reward_collected,
                **self._flown(), wind_en=snap.wind_en,
                max_failure_probability=cfg.max_failure_probability, risk_samples=cfg.risk_samples,
                estimator=snap.estimator)
            risk = cands[0].extra.get("risk")
            if risk is None:
                why = "the planner gave the current mission no risk figures"
        if why is not None:
            svc.state.replace(outlook={"unknown": why, "time_s": snap.time_s, "line": outlook_line({"unknown": why})})
            return
        q = risk["landing_soc_quantiles"]["soc"]
        outlook = {"time_s": snap.time_s, "route": list(cands[0].route), "p_failure": risk["p_failure"],
                   "landing_soc_p05": q[0], "landing_soc_p50": q[1], "landing_soc_p95": q[2],
                   "samples": risk["samples"], "max_failure_probability": cfg.max_failure_probability,
                   "reserve_soc": reserve, "wind_known": snap.wind_en is not None}
        alarm = outlook_alarm(outlook, max_failure_probability=cfg.max_failure_probability, reserve_soc=reserve)
        outlook["line"] = outlook_line(outlook)
        outlook["alarm"] = alarm
        svc.state.replace(outlook=outlook)
        if alarm is None:
            self._alarm_on = False
            return
        if self._alarm_on:
            return
        self._alarm_on = True
        svc.events.publish("alarm", time_s=snap.time_s, kind=alarm["kind"], level=alarm["level"], text=alarm["text"])
        self.statustext(alarm["statustext"], MAV_SEVERITY_WARNING if alarm.get("severity") == "warning"
                        else MAV_SEVERITY_CRITICAL)
        self.enqueue(f"alarm: {alarm['title'].lower()}", snap)

    # --- operator decisions ------------------------------------------------------------------------

    def approve(self, plan_id: int) -> None:
        """Upload an operator-approved plan (on the worker)."""
        plan = self.service.store.plan(plan_id)
        items = [M.item_from_json(d) for d in plan["items"]]
        chosen = plan["chosen"]
        cand = Candidate(chosen["name"], tuple(chosen["route"]), chosen["feasible"], chosen["reward"],
                         chosen["reward_reached"], chosen["objective"], chosen.get("cause"),
                         {k: chosen[k] for k in ("final_soc", "flight_time_s") if k in chosen})
        self._submit(self.upload, plan_id, items, cand, None, plan.get("current_seq", 1))

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
                "parameter_set": self.service.params.name, "chosen": chosen.to_dict(), "why": note or "operator revert",
                "candidates": [], "items": [M.item_to_json(i) for i in items], "current_seq": current_seq,
                "previous_items": [M.item_to_json(i) for i in (self.mission_items or [])],
                "vehicle_item_before": current}
        pid = self.service.store.add_plan(body, body["reason"], "approved", self._now())
        self.service.events.publish("plan", id=pid, status="approved", time_s=self._now(), reason=body["reason"],
                                    chosen=chosen.to_dict())
        self._submit(self.upload, pid, items, chosen, None, current_seq)
        return pid

    # --- upload ------------------------------------------------------------------------------------

    def _transfer(self, items: list[M.MissionItem], current_seq: int) -> _Transfer:
        """Upload, make ``current_seq`` current, read back: which outcome, and what is on board."""
        if self.telemetry.link_lost:
            # Never spend minutes retrying a transfer to a vehicle that is not heard.
            return _Transfer(UploadOutcome.FAILED, None, "upload", f"link lost ({self.telemetry.link_lost_reason})")
        try:
            stats = self.mc.upload(items)
        except (MissionError, OSError) as exc:
            # Usually the vehicle keeps its mission; but if only the final MISSION_ACK was lost it
            # may hold the new one: read back what is really on board when the link allows.
            return _Transfer(UploadOutcome.FAILED, self._readback(), "download", str(exc))
        with self._watch_lock:  # our own change: the vehicle's new mission id needs no read
            self.watcher.uploaded(len(items))
        try:
            # An airborne vehicle heads for the first item of the new route, never the take-off
            # (gcs_pdm.planning.mission documents the layout).
            self.mc.set_current(current_seq)
            self.service.state.update(mission={"current_seq": current_seq})
            if not self.service.config.confirm_download:
                return _Transfer(UploadOutcome.SENT, items, "upload", stats=stats)
            back = self.mc.download()
        except (MissionError, OSError) as exc:
            # Accepted, but the current item (or the readback) is not confirmed: an airborne vehicle
            # might head for the take-off item.
            on_board = self._readback()
            return _Transfer(UploadOutcome.UPLOADED_UNCONFIRMED, on_board if on_board is not None else items,
                             "download" if on_board is not None else "upload", str(exc), stats)
        # By meaning, not bytes: the autopilot stores items normalised (frames, NaN, item 0 as home).
        comparison = missions_equivalent(items, back, self.rules())
        outcome = UploadOutcome.CONFIRMED if comparison.equivalent else UploadOutcome.UPLOAD_MISMATCH
        return _Transfer(outcome, back, "download", stats=stats, readback=comparison.summary())

    def upload(self, plan_id: int, items: list[M.MissionItem], chosen: Candidate, snap: Snapshot | None,
               current_seq: int = 1) -> UploadOutcome:
        """Upload a plan's mission and record how it ended (one record per outcome, written once)."""
        svc = self.service
        previous = list(self.mission_items or [])
        # The intent first: if the service dies mid-transfer, the next start finds it (see
        # recover_interrupted) instead of an approved plan with no trace of an upload.
        intent = {"items": [M.item_to_json(i) for i in items], "previous_items": [M.item_to_json(i) for i in previous],
                  "route": list(chosen.route), "started_time_s": self._now(), "current_seq": current_seq}
        uid = svc.store.begin_upload(plan_id, intent)
        svc.events.publish("upload", id=uid, plan_id=plan_id, status="uploading", count=len(items), time_s=self._now())
        tr = self._transfer(items, current_seq)
        out = tr.outcome
        body = {**intent, "time_s": self._now(),
                "stats": dataclasses.asdict(tr.stats) if dataclasses.is_dataclass(tr.stats) else None}
        if tr.error is not None:
            body["error"] = tr.error
        if tr.readback is not None:
            body["readback"] = tr.readback
        svc.store.finish_upload(uid, out.record_status, body)
        note = tr.error or (f"mission readback differs from the plan: {tr.readback}"
                            if out is UploadOutcome.UPLOAD_MISMATCH else out.record_status)
        svc.store.set_plan_status(plan_id, out.plan_status, note)
        if tr.on_board is not None:
            self.set_mission(tr.on_board, source=tr.source)
        if out.ok:
            self._expect(snap, chosen, plan_id)
        else:
            self.loads.pop(plan_id, None)
            if out is not UploadOutcome.FAILED:
                # What the vehicle holds is not (known to be) the plan: no prediction of ours describes it.
                self.expectation = None
            log.error("upload of plan %d: %s%s; mission on board: %s", plan_id, out.record_status,
                      f" ({tr.error})" if tr.error else "",
                      "unknown" if tr.on_board is None else f"{len(tr.on_board)} items ({tr.source})")
        extra = {"error": tr.error} if tr.error is not None else {"reward": chosen.reward}
        svc.events.publish("upload", id=uid, plan_id=plan_id, status=out.record_status, route=list(chosen.route),
                           time_s=self._now(), **extra)
        route = ",".join(map(str, chosen.route)) or "home"
        self.statustext(out.notice.format(plan_id=plan_id, current_seq=current_seq, route=route),
                        MAV_SEVERITY_NOTICE if out.ok else MAV_SEVERITY_WARNING)
        return out

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
        self.service.events.publish("statustext", severity=severity, text=text, sent=True, time_s=self._now())
