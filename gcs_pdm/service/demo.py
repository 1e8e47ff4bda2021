"""``gcs-pdm demo``: the simulated vehicle and the service on loopback UDP, the Table III flight.

1. the vehicle (gcs_pdm.sim, hidden true parameters) takes off on waypoints 1..10 in numbered order,
   faster than real time; the aft motor loses 70 % of its power half way from waypoint 2 to 3;
2. the service (policy ``auto``) diagnoses the fault from telemetry, replans over the waypoints not
   yet visited, uploads the new mission, confirms it by download and tells the operator (STATUSTEXT);
3. the terminal shows it as it happens (and the HTTP status page at the printed address);
4. the summary: reward of the current route at the fault's replan on the degraded vehicle versus the replanned one, both
   scored by the vehicle simulator on the true parameters, and what the vehicle actually flew —
   beside the same vehicle flying the original mission without the service.
"""
from __future__ import annotations

import logging
import math
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from gcs_pdm.service.config import load_config, new_token
from gcs_pdm.service.runtime import Service

log = logging.getLogger(__name__)

FAULT_MOTOR = "aft"
FAULT_MAGNITUDE = 0.7


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class DemoResult:
    landed: bool
    failed: bool
    failure: str
    reached: list[int]                                # waypoints the vehicle flew (its truth)
    reward_flown: float
    heard: list[int] = field(default_factory=list)    # waypoints the service heard reached
    original: dict = field(default_factory=dict)      # the same vehicle without the service
    predicted: dict = field(default_factory=dict)     # keep vs replanned, scored on the truth
    plans: int = 0
    uploads: int = 0
    fault_detected_s: float | None = None
    fault_injected_s: float | None = None
    sim_time_s: float = 0.0
    wall_s: float = 0.0
    http: dict = field(default_factory=dict)          # what the HTTP API said at the end of the flight
    landing_soc: list[float] = field(default_factory=list)  # each pack's TRUE SoC at the end (the vehicle's)
    operator_answers: list = field(default_factory=list)    # (plan id, its age, HTTP status) per approval sent


def table3_mission():
    """The original mission (waypoints 1..10 in numbered order, from the ground) and its scenario."""
    from gcs_pdm.planning.mission import plan_to_mission
    from gcs_pdm.planning.plan import make_plan
    from gcs_pdm.planning.simulator import VehicleSimulator, original_order
    from gcs_pdm.planning.table3_scenario import preflight_scenario
    from gcs_pdm.sim.truth import true_parameters

    sc = preflight_scenario(10)
    sim = VehicleSimulator.for_scenario(sc, true_parameters())
    return sc, plan_to_mission(sc, make_plan(sim, original_order(sc), "original"), airborne=False)


def sim_config(scenario, mission, seed: int = 0):
    from gcs_pdm.sim.faults import parse_fault
    from gcs_pdm.sim.model import SimConfig

    ws = mission.waypoint_seq
    fault = parse_fault(f"motor:{FAULT_MOTOR}:{FAULT_MAGNITUDE}@leg:{ws[2]}-{ws[3]}")
    h = scenario.home
    return SimConfig(seed=seed, home_lat_deg=h.lat_deg, home_lon_deg=h.lon_deg, home_alt_m=h.ground_alt_m,
                     ground_temp_c=h.ground_temp_c, faults=(fault,), limits=scenario.limits.kernel_limits(),
                     mission=tuple(mission.items))


def demo_telemetry():
    """1 Hz battery/ESC/position telemetry: what the estimator needs, light enough for x60."""
    from gcs_pdm.sim.telemetry import RECORDING_RATES, TelemetryConfig

    rates = dict(RECORDING_RATES, GLOBAL_POSITION_INT=1.0, VFR_HUD=1.0, MISSION_CURRENT=1.0, HEARTBEAT=1.0)
    # an event's heartbeat is the period's: sent beside the periodic one, the pair was a "duplicate"
    return TelemetryConfig(rates_hz=rates, event_heartbeat_restarts_period=True)


def flown_waypoints(items, scenario, tolerance_m: float = 5.0) -> tuple[list[int], float]:
    """The scenario's waypoint numbers of the mission items a vehicle reached (its truth: the items
    as they were when reached, matched by position, so every upload's numbering agrees), each
    counted once, and their reward."""
    from gcs_pdm.geo import enu_from_geodetic
    from gcs_pdm.missions import MAV_CMD_NAV_WAYPOINT

    h = scenario.home
    nums: list[int] = []
    for item in items:
        if item.command != MAV_CMD_NAV_WAYPOINT:
            continue
        e, n = enu_from_geodetic(item.lat_deg, item.lon_deg, h.lat_deg, h.lon_deg)
        w = min(scenario.waypoints, key=lambda w: math.hypot(w.east_m - e, w.north_m - n))
        if math.hypot(w.east_m - e, w.north_m - n) <= tolerance_m and w.number not in nums:
            nums.append(w.number)
    reward = {w.number: w.reward for w in scenario.waypoints}
    return nums, float(sum(reward[n] for n in nums))


def reward_of(reached_seqs, mission, scenario) -> tuple[list[int], float]:
    number_of = {seq: n for n, seq in mission.waypoint_seq.items()}
    reward = {w.number: w.reward for w in scenario.waypoints}
    nums = [number_of[s] for s in reached_seqs if s in number_of]
    return nums, float(sum(reward[n] for n in nums))


def export_tryout(folder: str | Path) -> dict[str, str]:
    """The Table III mission (QGroundControl .plan, for the simulated vehicle or a GCS) and the
    objectives (scenario JSON with rewards and limits, for ``gcs-pdm serve --objectives``)."""
    from gcs_pdm.mavlink.mission_files import write_plan

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sc, m = table3_mission()
    h = sc.home
    write_plan(folder / "table3_mission.plan", m.items, home=(h.lat_deg, h.lon_deg, h.ground_alt_m))
    (folder / "table3_objectives.json").write_text(sc.to_json(indent=1))
    ws = m.waypoint_seq
    return {"mission": str(folder / "table3_mission.plan"), "objectives": str(folder / "table3_objectives.json"),
            "fault": f"motor:{FAULT_MOTOR}:{FAULT_MAGNITUDE}@leg:{ws[2]}-{ws[3]}"}


def fly_without_service(config, max_sim_s: float = 4 * 3600.0) -> dict:
    """The same vehicle, seed and fault, flying its original mission with nobody replanning
    (the steppable model, no network: as fast as the CPU allows)."""
    from gcs_pdm.sim.model import VehicleModel

    model = VehicleModel(config)
    while not model.finished and model.time_s < max_sim_s:
        model.step()
    s = model.state()
    return {"landed": bool(s.landed and not s.failed), "failed": bool(s.failed), "failure": s.failure,
            "reached_seqs": [seq for seq, _t in model.reached_log], "time_s": float(s.time_s)}


class _Background:
    """A daemon thread running ``self._run`` until ``stop()``."""

    JOIN_S = 2.0

    def __init__(self, name: str):
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def _run(self) -> None:
        raise NotImplementedError

    def start(self):
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=self.JOIN_S)


class TerminalPrinter(_Background):
    """Prints the service's events as they happen (fault, plan, upload, mission progress, texts)."""

    def __init__(self, service: Service, out=print):
        super().__init__("demo-printer")
        self.service = service
        self.out = out
        self.seq = 0

    def stop(self) -> None:
        super().stop()
        for ev in self.service.events.since(self.seq):
            self._print(ev)

    def _run(self) -> None:
        while not self._stop.is_set():
            for ev in self.service.events.wait(self.seq, 0.5):
                self.seq = ev.seq
                self._print(ev)

    def _print(self, ev) -> None:
        d = ev.data
        t = d.get("time_s")
        stamp = f"[t={t:7.1f} s]" if isinstance(t, (int, float)) else "[         ]"
        k = ev.kind
        if k == "fault" and not d.get("cleared"):
            self.out(f"{stamp} FAULT    {d.get('kind')} {d.get('target')} magnitude {d.get('magnitude', 0):.2f}"
                     f" ({d.get('source')})")
        elif k == "plan":
            status = d.get("status")
            if status == "planning":
                self.out(f"{stamp} REPLAN   {d.get('reason')}")
            else:
                c = d.get("chosen") or {}
                keep = d.get("keep") or {}
                self.out(f"{stamp} PLAN     {status}: route {c.get('route')} predicted reward {c.get('reward', 0):g}"
                         f" ({'feasible' if c.get('feasible') else 'infeasible'}); current mission "
                         f"{keep.get('route', '-')} predicted {'to fail: ' + str(keep.get('cause')) if keep and not keep.get('feasible') else 'ok'}")
        elif k == "upload":
            self.out(f"{stamp} UPLOAD   plan {d.get('plan_id')}: {d.get('status')}"
                     + (f", route {d.get('route')}" if d.get("route") else "") + (f" ({d.get('error')})" if d.get("error") else ""))
        elif k == "mission" and d.get("waypoint") is not None:
            self.out(f"{stamp} REACHED  waypoint {d['waypoint']} (+{d['reward']:g}, total {d['reward_collected']:g})")
        elif k == "mission" and d.get("source"):
            self.out(f"{stamp} MISSION  {d['source']}: {d.get('count')} items, waypoints {d.get('route')}")
        elif k == "statustext":
            who = "GCS-PDM ->" if d.get("sent") else "VEHICLE  "
            self.out(f"{stamp} {who} STATUSTEXT '{d.get('text')}'")


def http_json(base_url: str, path: str, body: dict | None = None, token: str | None = None) -> tuple[int, object]:
    """One JSON request with the standard library (the demo needs no HTTP client package)."""
    import json
    import urllib.error
    import urllib.request

    req = urllib.request.Request(base_url + path, method="GET" if body is None else "POST",
                                 data=None if body is None else json.dumps(body).encode())
    req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=5.0) as resp:
            return resp.status, json.loads(resp.read() or b"null")
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b"null")


class Operator(_Background):
    """In ``advise`` mode, an operator at the HTTP API who approves every feasible proposal.

    ``late_s``: the first proposal is approved only once it is that old in the vehicle's time (the
    gate's ``age_s``): the try-out of docs/operations.md with a late operator, whose approval the
    service refuses as stale and re-plans first; every later proposal is approved at once."""

    JOIN_S = 5.0

    def __init__(self, base_url: str, token: str, out=print, late_s: float = 0.0):
        super().__init__("demo-operator")
        self.base_url = base_url
        self.token = token
        self.out = out
        self.late_s = float(late_s)
        self.approved: list[int] = []
        #: every approval sent: (plan id, the proposal's age in vehicle seconds, HTTP status)
        self.answers: list[tuple[int, float | None, int]] = []

    def _run(self) -> None:
        while not self._stop.wait(0.1):
            try:
                for plan in http_json(self.base_url, "/missions/proposed")[1]:
                    if not plan["chosen"]["feasible"] or plan["id"] in self.approved:
                        continue
                    age = (plan.get("gate") or {}).get("age_s")
                    if not self.approved and self.late_s > 0 and (age is None or age < self.late_s):
                        continue  # the late operator has not looked yet
                    code, _ = http_json(self.base_url, f"/missions/plans/{plan['id']}/approve",
                                        {"note": "demo operator"}, self.token)
                    self.approved.append(plan["id"])
                    self.answers.append((plan["id"], age, code))
                    self.out(f"[         ] OPERATOR approves plan {plan['id']} over HTTP: {code}")
            except Exception as exc:  # noqa: BLE001 - the operator retries
                log.debug("operator: %s", exc)


def summarise_predictions(service: Service) -> dict:
    """The first replan after the fault was diagnosed (else the first replan): its current-mission and
    replanned routes, re-scored on the TRUE parameters and the TRUE fault. A plan made before the
    fault (the landing-forecast alarm re-plans at take-off) did not know of it, so scoring it with the
    fault would say gcs-pdm's route fails where the flown one did not."""
    from gcs_pdm.planning.plan import make_plan
    from gcs_pdm.planning.scenario import Scenario
    from gcs_pdm.planning.simulator import VehicleSimulator
    from gcs_pdm.sim.truth import true_parameters

    plans = [p for p in reversed(service.store.plans()) if p["status"] in ("uploaded", "kept", "proposed")]
    if not plans:
        return {}
    diagnosed = min((f["time_s"] for f in service.store.faults() if f["kind"] == "motor_power_loss"), default=None)
    after_fault = [p for p in plans if diagnosed is not None and p["time_s"] >= diagnosed]
    plan = (after_fault or plans)[0]
    import dataclasses

    import numpy as np

    from gcs_pdm.models import kernel
    from gcs_pdm.models.params import ParameterSet
    from gcs_pdm.models.powertrain import MotorFault

    sc = Scenario.from_dict(plan["scenario"])
    truth = true_parameters()
    # Score from what the service estimated (SoC, temperatures) at the replan, but with the TRUE
    # parameters and the TRUE fault. The estimator's kernel state belongs to the service's own
    # parameter set, so the truth starts from the same SoC rather than from that state vector.
    x = np.asarray(sc.start.pack_state)
    soc = kernel.state_of_charge(ParameterSet.from_dict(sc.params).pack_matrix(), x)
    start = dataclasses.replace(sc.start, pack_state=None, pack_soc=tuple(float(min(max(v, 0.0), 1.0)) for v in soc))
    sc = dataclasses.replace(sc, start=start, faults=(MotorFault(FAULT_MOTOR, FAULT_MAGNITUDE),))
    sim = VehicleSimulator.for_scenario(sc, truth)
    index = {w.number: i for i, w in enumerate(sc.waypoints)}
    out = {"at_time_s": plan["time_s"], "collected_before": plan["scenario"].get("reward_collected", 0.0)}
    for c in plan["candidates"]:
        p = make_plan(sim, [index[n] for n in c["route"]], c["name"])
        out[c["name"]] = {"route": c["route"], "reward_on_truth": p.reward, "feasible_on_truth": p.feasible,
                          "failure_on_truth": p.failure, "reward_predicted": c["reward"]}
    return out


def uploaded_promise(history: list[dict], uploads: list[dict]) -> dict | None:
    """What the last confirmed upload promised (``/missions/history``, ``/missions/uploads``): its
    plan's chosen route, the risk draws' p05/p50/p95 of the lowest pack's landing SoC (the
    console's "gets home with X % (p05–p95)"), its P(failure) and the landing reserve it planned
    for. None when nothing was uploaded or
    its plan carries no risk figures (a deterministic plan)."""
    confirmed = [u for u in uploads if u.get("status") == "confirmed" and u.get("plan_id") is not None]
    if not confirmed:
        return None
    upload = max(confirmed, key=lambda u: u["id"])
    plan = next((p for p in history if p["id"] == upload["plan_id"]), None)
    risk = ((plan or {}).get("chosen") or {}).get("risk")
    if risk is None:
        return None
    return {"plan_id": plan["id"], "time_s": plan["time_s"], "route": plan["chosen"]["route"],
            "landing_soc_p05_p50_p95": risk["landing_soc_quantiles"]["soc"], "p_failure": risk["p_failure"],
            "reserve_soc": plan["scenario"]["limits"]["landing_reserve_soc"]}


LEARNED_SET = Path(__file__).resolve().parents[2] / "fixtures" / "params" / "learned_sim.json"


def use_parameter_set(service: Service, which: str) -> str:
    """``learned``: the set the fitting package learned from the simulated vehicle's recorded flights
    (``fixtures/params/learned_sim.json``), imported with its provenance; else a stored set's name."""
    if which != "learned":
        service.activate_parameter_set(which)
        return which
    from gcs_pdm.models.params import ParameterSet

    ps = ParameterSet.from_json(LEARNED_SET.read_text())
    service.store.save_parameter_set(ps, provenance={"source": str(LEARNED_SET.name)}, overwrite=True)
    service.activate_parameter_set(ps.name)
    return ps.name


def start_status_page(service: Service, out=print):
    """The HTTP API on the configured port (a free one when it is taken); its address said."""
    from gcs_pdm.service.server import HttpServer

    config = service.config
    try:
        http = HttpServer(service, config.http_host, config.http_port).start()
    except RuntimeError:
        out(f"port {config.http_port} is taken; the status page goes on a free port")
        http = HttpServer(service, config.http_host, 0).start()
    out(f"gcs-pdm demo: status page {http.url}/  (API docs {http.url}/docs, token {service.token})")
    return http


def fly_until_on_ground(vehicle, wall0: float, timeout_s: float, out=print, every_s: float = 120.0) -> None:
    """Until the simulated vehicle is down and disarmed (or the wall-clock limit), a line every ``every_s``."""
    last_status = -math.inf
    while time.monotonic() - wall0 < timeout_s:
        s = vehicle.state
        if s.time_s - last_status >= every_s:
            last_status = s.time_s
            soc = ", ".join(f"{v:.2f}" for v in s.pack_soc)
            temps = "/".join(f"{t:.0f}" for t in s.motor_temp_c)
            out(f"[t={s.time_s:7.1f} s] vehicle  {s.mode:5s} alt {s.alt_m:5.0f} m  item {s.current_seq:2d}  "
                f"SoC [{soc}]  motors {temps} °C")
        if (s.landed or s.failed) and s.on_ground and not s.armed:
            break
        time.sleep(0.2)
    time.sleep(0.5)


class DecisionHold:
    """Holds the simulated vehicle's clock while the service is deciding, so when its answer
    arrives in flight time does not depend on how loaded the machine is (the tests' mode; ``gcs-pdm
    demo`` flies on at its speed-up like a real aircraft).

    Held while: the service's telemetry is more than ``lag_s`` of message time behind the vehicle
    (it has not seen what the vehicle did yet), the decision worker plans, uploads or reads the
    mission, or a proposal waits for the operator (policy advise)."""

    LAG_S = 3.0
    PROPOSALS_EVERY_S = 0.05  # wall seconds between two looks at the store
    #: wall seconds a proposal may hold the clock: the demo's operator answers within a tenth of a
    #: second or never (it approves only feasible proposals), and an aircraft does not wait forever
    OPERATOR_WAIT_S = 15.0
    #: wall seconds the service's telemetry time may stand still behind the vehicle's before the hold
    #: lets the vehicle fly on: a forward step the service's clock waits to confirm (the simulation
    #: resynchronising on a loaded machine) is confirmed only by the vehicle's later messages, which a
    #: held vehicle never sends (measured: test_risk_every_preset[edge540] stalled 120 s at load 7-12)
    LAG_STALL_S = 15.0

    def __init__(self, service: Service):
        self.service = service
        self.vehicle = None  # set once started
        self._proposals = (0.0, False)
        self._seen: dict[int, float] = {}  # proposal id -> when the hold first saw it (monotonic)
        self._lag = (None, 0.0)  # (the service's telemetry time while lagging, since when: monotonic)

    def __call__(self) -> bool:
        loop, vehicle = self.service.loop, self.vehicle
        if loop is None or vehicle is None:
            return False
        seen = loop.telemetry.time_s
        if seen is not None and vehicle.core.time_s - seen > self.LAG_S and not self._lag_stalled(seen):
            return True
        return loop.executor.working or self._proposal_waiting()

    def _lag_stalled(self, seen: float) -> bool:
        now = time.monotonic()
        if self._lag[0] != seen:
            self._lag = (seen, now)
        return now - self._lag[1] >= self.LAG_STALL_S

    def _proposal_waiting(self) -> bool:
        at, waiting = self._proposals
        now = time.monotonic()
        if now - at > self.PROPOSALS_EVERY_S:
            proposed = self.service.store.plans(status="proposed", limit=1)
            waiting = bool(proposed) and now - self._first_seen(proposed[0]["id"], now) < self.OPERATOR_WAIT_S
            self._proposals = (now, waiting)
        return waiting

    def _first_seen(self, plan_id: int, now: float) -> float:
        return self._seen.setdefault(plan_id, now)


def reevaluate_every_s(speedup: float) -> float:
    """The re-evaluation period (s of the vehicle's time) at a speed-up: a plan takes seconds of wall
    time, minutes of flight at x60, so above x10 the period grows with the speed-up."""
    return 30.0 * max(1.0, speedup / 10.0)


def demo_config(data_dir: str | None, *, policy: str, http_port: int, hold_while_deciding: bool, **settings):
    """A demo's service configuration: ``data_dir`` or a scratch directory (``tmp``, removed by
    :func:`close_demo`), a free loopback UDP port for the simulated vehicle and a fresh token.
    Returns ``(config, tmp, port, token)``."""
    tmp = None
    if data_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="gcs-pdm-demo-")
        data_dir = tmp.name
    port = free_udp_port()
    token = new_token()
    # A held vehicle is silent: the link may only be declared lost after the longest decision.
    held = {"link_lost_after_s": 600.0} if hold_while_deciding else {}
    config = load_config(env={}, data_dir=data_dir, api_token=token, policy=policy, http_port=http_port,
                         mavlink_url=f"udpin:127.0.0.1:{port}", **held, **settings)
    return config, tmp, port, token


def close_demo(http, service, tmp) -> None:
    http.stop()
    service.close()
    if tmp is not None:
        tmp.cleanup()


def run_demo(speedup: float = 60.0, http_port: int = 8000, data_dir: str | None = None, seed: int = 0,
             timeout_s: float = 170.0, out=print, compare: bool = True, params: str = "learned",
             policy: str = "auto", hold_while_deciding: bool = False, prepare: bool = True,
             approve_late_s: float = 0.0) -> DemoResult:
    """The demo; ``hold_while_deciding`` stops the vehicle's clock while the service decides
    (:class:`DecisionHold`: deterministic under load; ``gcs-pdm demo`` holds unless ``--real-time``).
    ``prepare``: compile what the service and the vehicle will run before the vehicle exists
    (``gcs_pdm.compiled``), so no thread compiles in flight; ``timeout_s`` counts from then.
    ``approve_late_s`` (policy advise): the operator approves the first proposal that late
    (:class:`Operator`; the held clock would wait for it, so combine with ``hold_while_deciding=False``)."""
    from gcs_pdm.service.adapters import start_sim_vehicle
    from gcs_pdm.service.server import start_mavlink, stop_mavlink

    if prepare:
        from gcs_pdm.compiled import prepare as prepare_compiled
        from gcs_pdm.service.warm_up import DEMO_GROUPS

        prepare_compiled(DEMO_GROUPS, out)
    wall0 = time.monotonic()
    scenario, mission = table3_mission()
    cfg_sim = sim_config(scenario, mission, seed)
    config, tmp, port, token = demo_config(data_dir, policy=policy, http_port=http_port,
                                           hold_while_deciding=hold_while_deciding, replan_cooldown_s=120.0,
                                           vehicle="edge540",
                                           reevaluate_every_s=reevaluate_every_s(speedup))
    service = Service(config)
    if params == "learned" and not LEARNED_SET.exists():
        params = "paper_si"
    params_name = use_parameter_set(service, params)
    service.load_objectives_scenario(scenario)
    http = start_status_page(service, out)
    out(f"  vehicle: simulated Edge 540, hidden true parameters, x{speedup:g} real time, MAVLink udp 127.0.0.1:{port}")
    out(f"  service: policy {policy}, parameter set {params_name!r} (the vehicle's true parameters stay hidden)")
    out(f"  mission: waypoints 1..10 in numbered order; the {FAULT_MOTOR} motor will lose "
        f"{FAULT_MAGNITUDE:.0%} of its power half way from waypoint 2 to 3")
    if hold_while_deciding:
        out("  clock: the vehicle's clock waits while the service catches up with its telemetry or decides "
            "(--real-time: it never waits)")
    printer = TerminalPrinter(service, out).start()
    operator = Operator(http.url, token, out, late_s=approve_late_s).start() if policy == "advise" else None
    start_mavlink(service)
    hold = DecisionHold(service) if hold_while_deciding else None
    vehicle = start_sim_vehicle(cfg_sim, f"udpout:127.0.0.1:{port}", speedup, demo_telemetry(), hold=hold)
    if hold is not None:
        hold.vehicle = vehicle
    try:
        fly_until_on_ground(vehicle, wall0, timeout_s, out, every_s=120.0)
    finally:
        vehicle.stop()
        if operator is not None:
            operator.stop()
        stop_mavlink(service)
        printer.stop()
    s = vehicle.state
    # What the vehicle flew (its truth: the items it reached, as they were then), beside what the
    # service heard (the waypoints it matched from MISSION_ITEM_REACHED; a lagging link hears fewer).
    reached, reward = flown_waypoints(vehicle.model.reached_items, scenario)
    heard = [e.data["waypoint"] for e in service.events.since(0)
             if e.kind == "mission" and e.data.get("waypoint") is not None]
    faults = service.store.faults()
    fault_log = vehicle.fault_log
    injected = fault_log[0]["time_s"] if fault_log else None
    result = DemoResult(landed=bool(s.landed and not s.failed), failed=bool(s.failed), failure=s.failure,
                        reached=reached, reward_flown=reward, heard=heard, plans=len(service.store.plans()),
                        uploads=len([u for u in service.store.uploads() if u["status"] == "confirmed"]),
                        fault_detected_s=next((f["time_s"] for f in faults if f["kind"] == "motor_power_loss"), None),
                        fault_injected_s=injected, sim_time_s=float(s.time_s),
                        landing_soc=[float(v) for v in s.pack_soc],
                        operator_answers=list(operator.answers) if operator is not None else [])
    result.predicted = summarise_predictions(service)
    try:
        result.http = {path: http_json(http.url, path)[1] for path in ("/status", "/faults", "/missions/history",
                                                                        "/missions/uploads", "/missions/current")}
    except Exception as exc:  # noqa: BLE001 - the summary does not depend on it
        log.warning("could not read the HTTP API at the end: %s", exc)
    if compare:
        out("flying the same vehicle, seed and fault without gcs-pdm, for comparison ...")
        orig = fly_without_service(cfg_sim)
        nums, rew = reward_of(orig["reached_seqs"], mission, scenario)
        result.original = {**orig, "reached": nums, "reward": rew}
    result.wall_s = time.monotonic() - wall0
    close_demo(http, service, tmp)
    return result


def print_summary(r: DemoResult, out=print) -> None:
    out("")
    out("=== summary ===")
    if r.fault_injected_s is not None:
        out(f"fault injected at t={r.fault_injected_s:.1f} s, diagnosed at t={r.fault_detected_s}")
    p = r.predicted
    if p:
        k, n = p.get("keep", {}), p.get("planner", {})
        out(f"the replan at t={p['at_time_s']:.1f} s, scored by the vehicle simulator on the TRUE parameters and fault "
            f"(reward {p['collected_before']:g} already collected):")
        out(f"  current route  {k.get('route')}: reward {k.get('reward_on_truth', 0):g}"
            f" ({'gets home' if k.get('feasible_on_truth') else 'fails: ' + str(k.get('failure_on_truth'))})")
        out(f"  replanned      {n.get('route')}: reward {n.get('reward_on_truth', 0):g}"
            f" ({'gets home' if n.get('feasible_on_truth') else 'fails: ' + str(n.get('failure_on_truth'))})")
    if r.original:
        o = r.original
        out(f"flown without gcs-pdm: waypoints {o['reached']} (reward {o['reward']:g} reached, "
            f"{o['reward'] if o['landed'] else 0:g} scored), "
            + ("landed" if o["landed"] else f"FAILED: {o['failure']}") + f" at t={o['time_s']:.0f} s")
    out(f"flown with gcs-pdm:    waypoints {r.reached} (reward {r.reward_flown:g} reached, "
        f"{r.reward_flown if r.landed else 0:g} scored), "
        + ("landed safely" if r.landed else (f"FAILED: {r.failure}" if r.failed else "still flying (timeout)"))
        + f" at t={r.sim_time_s:.0f} s")
    if r.heard != r.reached:
        out(f"  (the service heard waypoints {r.heard} reached)")
    out(f"{r.plans} plan(s), {r.uploads} confirmed upload(s); {r.wall_s:.0f} s wall time")
