"""The service object: configuration, store, events, jobs, live state and (when connected) the
live loop, wired together. The HTTP API and the CLI talk to this, never to the parts directly.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

from gcs_pdm.diagnosis.faults import MOTOR_POWER_LOSS, operator_fault
from gcs_pdm.models.params import ParameterSet
from gcs_pdm.service.config import ServiceConfig, new_token
from gcs_pdm.service.decision import CatalogueWaypoint
from gcs_pdm.service.events import EventBus
from gcs_pdm.service.jobs import JobRunner
from gcs_pdm.service.live_state import LiveState
from gcs_pdm.service.status_report import model_variant_report
from gcs_pdm.service.storage import Conflict, NotFound, Store
from gcs_pdm.vehicle.presets import is_paper_aircraft

log = logging.getLogger(__name__)

#: the repository's recorded flights and scenarios (readable by fit jobs by path)
FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"


#: what activating a parameter set changes while the service runs (told to the operator)
APPLIES_TO = "planning from the next replan; the estimator and diagnoser at the next service start"


class Service:
    def __init__(self, config: ServiceConfig, store: Store | None = None):
        self.config = config
        config.data_path.mkdir(parents=True, exist_ok=True)
        self.store = store or Store(config.database)
        self.token = config.api_token or new_token()
        if not config.api_token:
            log.warning("no api_token configured; this run's token is %s", self.token)
        self.events = EventBus()
        self.state = LiveState(track_window_s=config.track_window_s)
        self.runner = JobRunner(self.store, self.events, workers=config.fit_workers)
        from gcs_pdm.service.fit_jobs import make_fit_job

        self.runner.register("fit", make_fit_job(self))
        self.policy = config.policy
        # The operator's last activation survives a restart; the config names the first one.
        active = self.store.active_parameter_set_name() or config.parameter_set
        self.params: ParameterSet = self.store.activate_parameter_set(active)
        self.index_recorded_tlogs()
        from gcs_pdm.packs.records import PackRecords
        from gcs_pdm.service.flights import FlightRecorder

        #: each pack's health across flights (gcs_pdm.packs; docs/packs.md), in the same database file
        self.packs = PackRecords(config.database if str(config.database) != ":memory:" else ":memory:")
        #: flights as records (service/flights.py); the live loop feeds it
        self.flights = FlightRecorder(self)
        self.catalogue: list[CatalogueWaypoint] | None = None
        #: the planner's limits (gcs_pdm.planning.scenario.PlanLimits); None: the flown
        #: description's (its limits and landing reserve)
        self.limits = None
        self.loop = None
        self.foreign_watch = None  # status_report.ForeignSystemWatcher, once a link is attached
        self.stream_watch = None  # stream_watch.StreamWatch: asks for the streams the vehicle does not send
        self.state.update(policy=self.policy, parameter_set=self.params.name,
                          model_variants=model_variant_report(self.params))
        #: the vehicle description (``vehicle`` in the config); None: the live loop derives a
        #: provisional one from the first telemetry (service/vehicle_discovery.py)
        self.vehicle = None
        if config.vehicle:
            from gcs_pdm.vehicle.presets import resolve

            self.vehicle = resolve(config.vehicle)  # VehicleError: serve says it in one line
            self.describe_vehicle(self.vehicle, "given")

    # --- lifecycle ---------------------------------------------------------------------------------

    def attach_loop(self, loop) -> None:
        from gcs_pdm.service.status_report import ForeignSystemWatcher

        self.loop = loop
        self.state.update(link={"url": self.config.mavlink_url})
        if getattr(loop, "link", None) is not None:
            self.foreign_watch = ForeignSystemWatcher(self, loop.link).start()

    def describe_vehicle(self, desc, source: str, notes: list[str] | tuple = (), waiting: str | None = None) -> None:
        """Say in /status which description is in use (and its packs and motors by name)."""
        from gcs_pdm.service.vehicle_discovery import about_vehicle

        previous = self.state.get("vehicle") or {}
        self.state.update(vehicle=about_vehicle(desc, source, notes, waiting))
        if previous.get("name") != (desc.name if desc is not None else None) or not previous:
            self.state.set_components([p.name for p in desc.packs] if desc is not None else [],
                                      [m.name for m in desc.motors] if desc is not None else [])

    def described_packs(self) -> dict:
        """The packs of the vehicle description the service follows, by slot name (``PackSpec``).
        Empty while it follows none: the live loop is deriving one from the first telemetry
        (service/vehicle_discovery.py), or, built without discovery, flies the paper's aircraft on
        the active parameter set (``vehicle`` None here: the adapters' paper path)."""
        return {p.name: p for p in self.vehicle.packs} if self.vehicle is not None else {}

    def flown_vehicle(self):
        """The description the vehicle is flown as: the one followed, else the paper's aircraft, the
        ``edge540`` preset (a live loop built without discovery flies it on the active set; so does
        the intake while discovery waits for the telemetry to derive one)."""
        from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

        return self.vehicle if self.vehicle is not None else PRESETS[DEFAULT_PRESET]

    # The active parameter set and a scenario's limits are the paper layout's (its four packs by name,
    # one cut-off for 5S packs): they are flown over the paper's aircraft only; any other vehicle
    # flies its description's own values and per-pack limits (a 4S pack would "fail" at 17.5 V).
    # Resolved here, at the service's entry point, so the core below takes one vehicle and overrides.

    def parameter_override(self, vehicle) -> ParameterSet | None:
        """The parameter set to fly over ``vehicle``'s description values: the active one for the
        paper's aircraft (``edge540``), else None (the description's own)."""
        return self.params if is_paper_aircraft(vehicle) else None

    def limits_override(self, vehicle):
        """One ``Limits`` for every pack and motor of ``vehicle``: the kernel's part of
        ``plan_limits_override`` (the loaded scenario's, for the paper's aircraft), else None: the
        description's per pack and motor."""
        plan = self.plan_limits_override(vehicle)
        return plan.kernel_limits() if plan is not None else None

    def plan_limits_override(self, vehicle):
        """The planner's ``PlanLimits`` for every pack and motor of ``vehicle``, the landing reserve
        included: the loaded scenario's for the paper's aircraft, else None (the description's limits
        and reserve). With no scenario loaded the paper's aircraft plans on its description's too
        (edge540: the kernel's limits and a 15 % reserve), the reserve the outlook and its alarm
        judge by: a plan that lands under it would be proposed and then alarmed on."""
        return self.limits if self.limits is not None and is_paper_aircraft(vehicle) else None

    def adopt_vehicle(self, desc, source: str, notes: list[str]) -> None:
        """A description the service now follows (derived from telemetry): said in /status, the log
        and an event, with how to save and correct it."""
        from gcs_pdm.service.vehicle_discovery import about_vehicle

        self.vehicle = desc
        self.describe_vehicle(desc, source, notes)
        about = about_vehicle(desc, source, notes)
        log.warning("no vehicle description given: using a %s one derived from telemetry (%d pack(s) %s, "
                    "%d motor(s) %s); to save and correct it: %s", source, len(desc.packs), about["packs"],
                    len(desc.motors), about["motors"], about.get("save", ""))
        for note in notes:
            log.warning("vehicle description: %s", note)
        self.events.publish("vehicle", **about)

    def close(self) -> None:
        if self.foreign_watch is not None:
            self.foreign_watch.stop()
        if self.stream_watch is not None:
            self.stream_watch.stop()
        if self.loop is not None:
            self.loop.stop()
        self.runner.shutdown()
        if self.flights._pending:  # an ended flight's health points, with the rest heard so far
            self.flights.make_health_points()
        self.packs.close()
        self.store.close()

    def index_recorded_tlogs(self) -> int:
        """Tlogs already in ``<data_dir>/tlogs`` (copied there, or from an older install) join the index."""
        known = {t["path"] for t in self.store.tlogs()}
        new = [p for p in sorted((self.config.data_path / "tlogs").glob("*.tlog")) if str(p) not in known]
        return self.store.index_tlogs(new, note="found at start-up") if new else 0

    # --- mission objectives ------------------------------------------------------------------------

    def load_objectives(self, path: str | Path) -> list[CatalogueWaypoint]:
        """Waypoints with rewards from a scenario JSON (``fixtures/scenarios``; lat/lon or ENU)."""
        from gcs_pdm.planning.scenario import Scenario

        return self.load_objectives_scenario(Scenario.from_json(Path(path).read_text()))

    def load_objectives_scenario(self, sc) -> list[CatalogueWaypoint]:
        from gcs_pdm.geo import geodetic_from_enu

        h = sc.home
        cat = []
        for w in sc.waypoints:
            lat, lon = geodetic_from_enu(w.east_m, w.north_m, h.lat_deg, h.lon_deg)
            cat.append(CatalogueWaypoint(w.number, lat, lon, w.alt_m, w.reward, w.airspeed_mps))
        self.catalogue = cat
        self.limits = sc.limits
        return cat

    # --- operator actions --------------------------------------------------------------------------

    def declare_fault(self, kind: str, motor: str, magnitude: float, note: str, replan: bool = True) -> int:
        t = self.state.get("time_s")
        if kind != MOTOR_POWER_LOSS:
            raise ValueError(f"kind: an operator can declare {MOTOR_POWER_LOSS} only, not {kind!r}")
        motors = list(self.state.get("motors"))
        if motor not in motors:  # the vehicle description's motors (the paper's: fwd, aft)
            raise ValueError(f"motor: no motor {motor!r} on this vehicle; have {', '.join(motors) or 'none yet'}")
        fault = operator_fault(motor, magnitude, t)
        fid = self.store.add_fault(fault, "operator", note)
        self.events.publish("fault", id=fid, time_s=t, kind=kind, target=motor, magnitude=magnitude, source="operator")
        if self.loop is not None:
            self.loop.declare_fault(fault, replan, fault_id=fid)
        return fid

    def pack_priors(self) -> dict[str, dict | None]:
        """What the next flight's estimator should start from, per pack slot of the vehicle
        description: the latest health of the pack in that slot (the operator's assignment, else
        the slot's own name; ``gcs_pdm.packs.trend.estimator_priors``), None where no flight has told.
        The hook for the estimator's priors (docs/packs.md)."""
        from gcs_pdm.packs.identity import identify
        from gcs_pdm.packs.trend import estimator_priors

        assigned = {k: v["pack_id"] for k, v in self.packs.assignments().items()}
        slots = list(self.described_packs()) or sorted(assigned)
        out = {}
        for slot in slots:
            pack_id = identify(slot, self.flights.serials.latest(slot), assigned).pack_id
            priors = estimator_priors(self.packs.points(pack_id))
            out[slot] = None if priors is None else {**priors, "pack_id": pack_id}
        return out

    def carry_over_fault(self, fault_id: int, note: str = "") -> int:
        """The operator carries a motor fault of an earlier flight into the present one (a damaged
        motor stays damaged): declared again, without a replan of its own; the new fault's id."""
        fault = next((f for f in self.store.faults() if f["id"] == fault_id), None)
        if fault is None:
            raise NotFound(f"fault {fault_id}")
        if fault["kind"] != MOTOR_POWER_LOSS or not fault["target"]:
            raise Conflict(f"fault {fault_id} is a {fault['kind']}: only a motor's power loss can be carried over")
        if self.store.current_flight_id is None:
            raise Conflict("no flight is open: a fault is carried into the flight in progress")
        if fault["flight_id"] == self.store.current_flight_id and fault["active"]:
            raise Conflict(f"fault {fault_id} is already active in this flight")
        why = f"carried over from flight {fault['flight_id']} (fault {fault_id})" + (f": {note}" if note else "")
        return self.declare_fault(MOTOR_POWER_LOSS, fault["target"], float(fault["magnitude"]), why, replan=False)

    def clear_fault(self, fault_id: int) -> None:
        fault = next((f for f in self.store.faults() if f["id"] == fault_id), None)
        if fault is None:
            raise NotFound(f"fault {fault_id}")
        self.store.clear_fault(fault_id)
        if self.loop is not None and fault["source"] == "operator" and fault["target"]:
            self.loop.clear_operator_fault(fault["target"], fault_id=fault_id)
        self.events.publish("fault", id=fault_id, cleared=True, source="operator")

    def _proposed(self, plan_id: int) -> dict:
        plan = self.store.plan(plan_id)
        if plan["status"] != "proposed":
            raise Conflict(f"plan {plan_id} is {plan['status']}, not proposed")
        return plan

    def approve(self, plan_id: int, note: str = "") -> None:
        plan = self._proposed(plan_id)
        if self.loop is None:
            raise Conflict("no vehicle link: a plan cannot be uploaded")
        self.loop.require_link(f"approval of plan {plan_id}")
        gate = self.loop.proposal_gate(plan)
        if gate.blocked:
            raise Conflict(f"plan {plan_id} cannot be approved now: {gate.reason}")
        if gate.stale:
            # a decision made from an old state is not uploaded: re-plan from the current one and
            # let the operator decide on that (the old proposal is superseded by it)
            if self.store.transition_plan(plan_id, "proposed", "superseded", f"stale at approval: {gate.reason}"):
                self.events.publish("plan", id=plan_id, status="superseded", by="re-evaluation at approval")
            self.loop.request_replan(f"approval of plan {plan_id}: re-evaluated first ({gate.reason})")
            raise Conflict(f"plan {plan_id} was not uploaded: {gate.reason}; re-planning from the current state, "
                           "decide on the new proposal")
        # conditional: a newer plan may have superseded this one since it was read
        if not self.store.transition_plan(plan_id, "proposed", "approved", note or "operator"):
            raise Conflict(f"plan {plan_id} is {self.store.plan(plan_id)['status']}, not proposed")
        self.events.publish("plan", id=plan_id, status="approved", by="operator")
        self.loop.approve(plan_id)

    def reject(self, plan_id: int, note: str = "") -> None:
        plan = self._proposed(plan_id)
        if self.loop is not None:
            gate = self.loop.proposal_gate(plan)
            if gate.blocked:
                raise Conflict(f"plan {plan_id} cannot be rejected now: {gate.reason}")
        if not self.store.transition_plan(plan_id, "proposed", "rejected", note or "operator"):
            raise Conflict(f"plan {plan_id} is {self.store.plan(plan_id)['status']}, not proposed")
        self.events.publish("plan", id=plan_id, status="rejected", by="operator")

    def request_replan(self, reason: str) -> None:
        if self.loop is None:
            raise Conflict("no vehicle link: nothing to replan")
        self.loop.require_link("replan")
        why = self.loop.replan_blocker()
        if why is not None:  # said now (409), not accepted and then deferred in a log line
            raise Conflict(f"cannot replan now: {why}")
        self.loop.request_replan(reason)

    def revert_upload(self, upload_id: int, note: str = "") -> int:
        """Put back the mission an upload replaced (the operator's explicit choice: not re-planned)."""
        up = next((u for u in self.store.uploads(limit=100000) if u["id"] == upload_id), None)
        if up is None:
            raise NotFound(f"upload {upload_id}")
        if not up.get("previous_items"):
            raise Conflict(f"upload {upload_id} recorded no previous mission")
        if self.loop is None:
            raise Conflict("no vehicle link: a mission cannot be uploaded")
        self.loop.require_link(f"revert of upload {upload_id}")
        return self.loop.revert(up, note)

    def refresh_mission(self) -> None:
        if self.loop is None:
            raise Conflict("no vehicle link: no mission to read")
        self.loop.require_link("mission read")
        self.loop.request_refresh()

    def set_policy(self, policy: str) -> None:
        self.policy = policy
        self.state.update(policy=policy)
        self.events.publish("policy", policy=policy)

    def activate_parameter_set(self, name: str) -> ParameterSet:
        ps = self.store.activate_parameter_set(name)
        self.params = ps
        # same keys every time: LiveState's one-level merge replaces it whole
        self.state.update(parameter_set=name, model_variants=model_variant_report(ps))
        # The live loop's filters keep their state (and the parameters they were built with:
        # rebuilding them mid-flight would throw away the SoC/temperature estimate); its planning
        # reads ``self.params``, so the new set applies from the next replan on. A restart builds
        # the estimator and diagnoser from it.
        self.events.publish("parameter_set", name=name, applies_to=APPLIES_TO)
        return ps

    def current_mission(self) -> dict:
        if self.loop is None or self.loop.mission_items is None:
            return {"items": None, "source": "none", "time_s": None, "waypoints": None}
        from gcs_pdm.missions import item_to_json
        from gcs_pdm.service.decision import catalogue_from_items, match_items

        items = self.loop.mission_items
        # the waypoint numbers plans and routes use: the objectives', else the first mission's order
        catalogue = getattr(self.loop.executor, "catalogue", None) or self.catalogue or catalogue_from_items(items)
        return {"items": [item_to_json(i) for i in items], "source": "download",
                "time_s": self.loop.mission_time_s, "waypoints": match_items(items, catalogue)}

    # --- files -------------------------------------------------------------------------------------

    @property
    def upload_limits(self):
        from gcs_pdm.service.uploads import UploadLimits

        c = self.config
        return UploadLimits(c.max_upload_bytes, c.max_upload_rows, c.tlog_min_mavlink_fraction,
                            max_cells=c.max_upload_cells, max_decoded_bytes=c.max_upload_decoded_bytes)

    @property
    def incoming_dir(self) -> Path:
        """Where uploads are received before they are checked (the data directory's file system,
        so keeping one is a rename)."""
        return self.config.data_path / "uploads" / ".incoming"

    def save_upload(self, filename: str, kind: str, received) -> str:
        """Keep a received and checked upload (gcs_pdm.service.uploads.ReceivedFile) under a safe name."""
        from gcs_pdm.service.uploads import stored_name

        folder = self.config.data_path / "uploads"
        folder.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%dT%H%M%S")
        safe = stored_name(filename)
        path = folder / f"{stamp}_{safe}"
        n = 1
        while path.exists():
            path = folder / f"{stamp}_{n}_{safe}"
            n += 1
        received.path.replace(path)
        received.path = path
        file_id = self.store.add_file(filename, str(path), kind, received.size_bytes)
        if kind == "tlog":
            self.store.close_tlog(self.store.add_tlog(str(path), note=f"uploaded as {filename}"))
        return file_id

    def resolve_flight_ref(self, ref: dict) -> Path:
        if ref.get("file_id"):
            return Path(self.store.file(ref["file_id"])["path"])
        if ref.get("tlog_id") is not None:
            return Path(self.store.tlog(int(ref["tlog_id"]))["path"])
        path = Path(ref["path"]).resolve()
        allowed = [self.config.data_path.resolve(), FIXTURES.resolve()]
        if not any(path.is_relative_to(a) for a in allowed):
            raise PermissionError(f"path {path} is outside the data directory and fixtures/")
        return path

    def check_flight_ref(self, ref) -> str | None:
        """Why a flight reference cannot be used, or None."""
        try:
            path = self.resolve_flight_ref(ref.model_dump() if hasattr(ref, "model_dump") else ref)
        except NotFound as exc:
            return f"not found: {exc.args[0]}"
        except PermissionError as exc:
            return str(exc)
        try:
            if not path.is_file():
                return f"file {path} does not exist or is not a file"
        except (OSError, ValueError) as exc:  # e.g. a name longer than the file system allows
            return f"file {path.name[:80]}...: cannot be read ({exc.strerror if isinstance(exc, OSError) else exc})"
        return None
