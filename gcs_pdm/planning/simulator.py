"""The vehicle simulator (VS): candidate routes → reward, health cost, power cost, failure.

A route is an ordered list of waypoint indices (positions in ``scenario.waypoints``) flown from the
vehicle's current position and always closed by the return to the landing site. Each leg is
flown at constant airspeed and climb rate, so its shaft power (``powertrain.shaft_power``) is
constant; the leg is cut into equal samples of at most ``dt_s`` seconds and all candidate routes
are flown through ``topology.simulate_vehicle`` together in one call (profiles padded with
zero-length samples, which the kernel treats as no-ops).

Two ways in, one physics:

* :meth:`VehicleSimulator.evaluate` flies whole routes from the start (used for verdicts,
  local search and the brute-force cross-check);
* :meth:`VehicleSimulator.advance` / :meth:`VehicleSimulator.home` fly one more leg from carried
  prefix states (:class:`FlightState`), which is what makes the particle filter and the exact
  search cheap: a prefix is simulated once, not once per extension. Because every leg is sampled
  the same way in both, the two give identical numbers (tested).

Scoring: ``reward_reached`` sums the rewards of waypoints reached before the first failure;
``reward`` is that sum only for routes that get home inside every limit (and keep the landing
reserve), and 0 otherwise — a route that cannot get home scores as a failure. The health cost
``C_h`` is the worst thermal stress (peak rise over the ground ambient as a fraction of the
allowed rise, packs and motors) plus the depth of discharge of the most drained pack; the power
cost ``C_p`` is the electrical energy drawn, in MJ.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from gcs_pdm.models import kernel
from gcs_pdm.models.params import ParameterSet
from gcs_pdm.models.powertrain import PowertrainState, air_density, ambient_temperature
from gcs_pdm.models.topology import simulate_vehicle
from gcs_pdm.models.wind import ground_speed
from gcs_pdm.planning.scenario import PlanLimits, Scenario
from gcs_pdm.vehicle.description import VehicleDescription
from gcs_pdm.vehicle.model_inputs import model_inputs, powertrain_airframe, shaft_power_model

#: safety margins on the verdicts of coarse (> 1 s) planning steps; see _set_verdict_limits
VERDICT_MARGIN_SOC = 0.001
VERDICT_MARGIN_V = 0.02
VERDICT_MARGIN_C = 0.1

#: a leg the wind makes unflyable at its airspeed (ground speed below MIN_GROUND_SPEED_MPS) is one
#: short sample at a power no motor delivers: the kernel fails it ("motors cannot deliver the power")
UNFLYABLE_LEG_S = 1.0
UNFLYABLE_POWER_W = 1e9

#: failure code for a route that lands with a pack below the landing reserve
FAIL_RESERVE = 6
FAILURE_NAMES = {**kernel.FAILURE_NAMES, FAIL_RESERVE: "landing reserve not kept"}

DEFAULT_DT_S = 10.0
#: Θ of the objective Θᵀ{R, −C_h, −C_p}: reward first, costs break ties
DEFAULT_THETA = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class LegTable:
    """Every leg between the scenario's places, sampled: rows/cols are waypoints 0..n-1, the start
    (n) and the landing site (n+1)."""

    dt: np.ndarray          # (M, M, L) sample lengths, zero-padded
    power: np.ndarray       # (M, M, L) shaft power, W
    ambient: np.ndarray     # (M, M, L) ambient temperature, °C
    steps: np.ndarray       # (M, M) samples actually used
    duration_s: np.ndarray  # (M, M)
    distance_m: np.ndarray  # (M, M) horizontal
    airspeed: np.ndarray    # (M, M) airspeed flown on the leg, m/s


@dataclass(frozen=True)
class FlightState:
    """A batch of B vehicles part-way along their routes (the carried prefix state)."""

    x: np.ndarray            # (B, 4, 4) pack states
    motor_temp: np.ndarray   # (B, 2)
    node: np.ndarray         # (B,) where each vehicle is (LegTable index)
    reward: np.ndarray       # (B,) reward of waypoints reached so far
    energy_j: np.ndarray     # (B,)
    time_s: np.ndarray       # (B,)
    peak_pack_c: np.ndarray  # (B,)
    peak_motor_c: np.ndarray  # (B,)

    def __len__(self) -> int:
        return int(self.node.shape[0])

    def take(self, idx: np.ndarray) -> "FlightState":
        return FlightState(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))

    @staticmethod
    def concat(states: Sequence["FlightState"]) -> "FlightState":
        return FlightState(*(np.concatenate([getattr(s, f) for s in states]) for f in FlightState.__dataclass_fields__))


@dataclass(frozen=True)
class Outcome:
    """Per-vehicle verdict of a flight that ends with the landing (arrays of length B)."""

    feasible: np.ndarray      # (B,) bool: got home inside every limit with the reserve kept
    cause: np.ndarray         # (B,) FAIL_* code (FAIL_RESERVE for a missed reserve)
    reward: np.ndarray        # (B,) scored reward (0 when infeasible)
    reward_reached: np.ndarray  # (B,) rewards of waypoints reached before any failure
    health_cost: np.ndarray   # (B,)
    power_cost: np.ndarray    # (B,) MJ
    final_soc: np.ndarray     # (B, 4)
    final_pack_temp: np.ndarray  # (B, 4)
    final_motor_temp: np.ndarray  # (B, 2)
    flight_time_s: np.ndarray  # (B,) from the start to landing (or failure)

    def objective(self, theta: Sequence[float] = DEFAULT_THETA) -> np.ndarray:
        t = np.asarray(theta, dtype=np.float64)
        return t[0] * self.reward - t[1] * self.health_cost - t[2] * self.power_cost


@dataclass(frozen=True)
class RouteEvaluation(Outcome):
    """Outcome of whole routes plus where each one failed."""

    fail_leg: np.ndarray = None  # (B,) index of the leg that failed (len(route) = the way home), -1 if none
    reached: np.ndarray = None   # (B,) number of route waypoints reached


def _sampled_legs(info: np.ndarray, dt_s: float) -> LegTable:
    """Legs (m, m, [duration, distance, power, ambient, airspeed]) cut into equal samples of at most
    ``dt_s``, padded to the longest leg."""
    m = info.shape[0]
    steps = np.where(info[..., 0] > 0, np.ceil(info[..., 0] / dt_s - 1e-9), 0).astype(np.int64)
    L = max(int(steps.max()), 1)
    dt = np.zeros((m, m, L))
    power = np.zeros((m, m, L))
    amb = np.zeros((m, m, L))
    for i in range(m):
        for j in range(m):
            k = steps[i, j]
            if k:
                dt[i, j, :k] = info[i, j, 0] / k
                power[i, j, :k] = info[i, j, 2]
                amb[i, j, :k] = info[i, j, 3]
    return LegTable(dt, power, amb, steps, info[..., 0], info[..., 1], info[..., 4])


class VehicleSimulator:
    """Flies candidate routes of one scenario on one vehicle (the planner's model)."""

    def __init__(self, scenario: Scenario, vehicle: VehicleDescription, *, params: ParameterSet | None = None,
                 state: PowertrainState | None = None, motor_faults: Mapping[str, float] | None = None,
                 limits: PlanLimits | None = None, dt_s: float = DEFAULT_DT_S, optimise_airspeed: bool = False,
                 airspeed_candidates: Sequence[float] | None = None) -> None:
        """Fly ``vehicle`` (a ``VehicleDescription``: its packs, motors and topology,
        ``models.topology``; its airframe's power model) over the scenario's places.

        ``params``: a parameter set flown over the description's values (its packs by name,
        ``model_inputs``), None for the description's own; ``state``: its powertrain now (None:
        full packs at the ground temperature); ``motor_faults``: power losses by its motor names
        ({"m2": 0.3}); ``limits`` (a ``PlanLimits``): one cut-off and temperature limit for every
        pack and motor plus the landing reserve, None for the description's. ``pack_names`` /
        ``motor_names`` say what the rows of its states are, in order. The scenario's waypoints and
        airspeeds are used as they are (they must suit the vehicle); a scenario file's own vehicle
        (the paper's aircraft, from its start, faults and limits) is :meth:`for_scenario`."""
        if not isinstance(vehicle, VehicleDescription):
            raise TypeError(f"vehicle: expected a VehicleDescription, got {type(vehicle).__name__} (a scenario's own "
                            f"vehicle on a parameter set: VehicleSimulator.for_scenario(scenario, params))")
        if dt_s <= 0:
            raise ValueError(f"dt_s: must be > 0, got {dt_s}")
        self.scenario = scenario
        self.vehicle = vehicle
        self.params = params
        self.dt_s = float(dt_s)
        self.n = len(scenario.waypoints)
        self.start_node = self.n
        self.landing_node = self.n + 1
        self.rewards = np.array([w.reward for w in scenario.waypoints] + [0.0, 0.0])
        self._t_ground = scenario.home.ground_temp_c
        inputs = model_inputs(vehicle, params)
        faults = dict(motor_faults or {})
        unknown = set(faults) - set(inputs.motor_names)
        if unknown:
            raise ValueError(f"motor_faults: no motor {sorted(unknown)[0]!r}; have {', '.join(inputs.motor_names)}")
        self._pp = inputs.pack_matrix[None]
        self._motor_rows = inputs.motor_matrix[None]
        self._fault = np.array([[float(faults.get(n, 0.0)) for n in inputs.motor_names]])
        self._free_topology = inputs.topology.with_limits(-np.inf, np.inf, np.inf)
        if limits is None:
            self._limit_topology, self._base_reserve = inputs.topology, vehicle.landing_reserve
        else:
            self._limit_topology = inputs.topology.with_limits(*limits.kernel_limits().as_tuple())
            self._base_reserve = limits.landing_reserve_soc
        if state is None:
            t0 = self._t_ground
            state = PowertrainState(kernel.initial_pack_state(inputs.pack_matrix, 1.0, t0),
                                    np.full(inputs.n_motors, float(t0)))
        self.initial = state
        self.airframe = powertrain_airframe(vehicle)
        self._vehicle_power = shaft_power_model(vehicle)
        self.pack_names, self.motor_names = inputs.pack_names, inputs.motor_names
        self._multirotor = vehicle.airframe.type == "multirotor"
        self._set_verdict_limits()
        self.legs = self._leg_table(optimise_airspeed, airspeed_candidates)

    @classmethod
    def for_scenario(cls, scenario: Scenario, params: ParameterSet | None = None, **kw) -> "VehicleSimulator":
        """The scenario file's own vehicle (``Scenario.flown_vehicle``: the ``edge540`` preset from
        its start, with its faults and limits) on ``params`` (default the scenario's set)."""
        return cls(scenario, **scenario.flown_vehicle(params).simulator_args(), **kw)

    def _default_airspeeds(self) -> np.ndarray:
        """The airspeeds the optimisation tries by default: a multirotor's from 2 m/s to its maximum;
        a fixed wing's from well above the stall (at least 16 m/s) to its maximum (at most 32 m/s)."""
        af = self.airframe
        if self._multirotor:
            return np.arange(2.0, af.max_airspeed + 1e-9, 2.0)
        return np.arange(max(af.stall_airspeed + 4.0, 16.0), min(af.max_airspeed, 32.0) + 1e-9, 2.0)

    def _shaft_power(self, airspeed: float, climb: float, rho: float) -> float:
        """The airframe's power model: the drag polar, or momentum theory for a multirotor."""
        return float(self._vehicle_power(airspeed, climb, rho))

    def _simulate(self, x: np.ndarray, motor_temp: np.ndarray, dt: np.ndarray, power: np.ndarray,
                  ambient: np.ndarray, *, verdict: bool) -> kernel.PowertrainRun:
        """One batched kernel call; ``verdict``: with the verdict limits, stopping at a failure."""
        topo = self._topology if verdict else self._free_topology
        return simulate_vehicle(topo, self._pp, self._motor_rows, x, motor_temp, dt, power, ambient, self._fault,
                                max_dt=self.dt_s, stop_on_failure=verdict)

    def _set_verdict_limits(self) -> None:
        # A constant-power load takes its current from the voltage at each step's start, so coarse
        # steps under-count a little (<= 0.00023 SoC and 0.006 °C over whole Table III routes at
        # 10 s vs 1 s). A plan must never be feasible at the planning step yet fail at fine steps:
        # coarse verdicts get a margin of several times that bias.
        coarse = self.dt_s > 1.0
        topo = self._limit_topology
        self._topology = replace(topo, pack_cutoff_v=topo.pack_cutoff_v + (VERDICT_MARGIN_V if coarse else 0.0),
                                 pack_max_temp_c=topo.pack_max_temp_c - (VERDICT_MARGIN_C if coarse else 0.0),
                                 motor_max_temp_c=topo.motor_max_temp_c - (VERDICT_MARGIN_C if coarse else 0.0))
        self._reserve = self._base_reserve + (VERDICT_MARGIN_SOC if coarse else 0.0)

    # ---- legs -----------------------------------------------------------------------------------
    def _places(self) -> np.ndarray:
        sc = self.scenario
        pts = [(w.east_m, w.north_m, w.alt_m) for w in sc.waypoints]
        pts.append((sc.start.east_m, sc.start.north_m, sc.start.alt_m))
        pts.append((sc.home.landing_east_m, sc.home.landing_north_m, 0.0))
        return np.array(pts, dtype=np.float64)

    def _leg_profile(self, a: np.ndarray, b: np.ndarray, airspeed: float) -> tuple[float, float, float, float, float]:
        """(duration, distance, shaft power, ambient, airspeed) of the straight leg a→b."""
        sc = self.scenario
        dist = float(np.hypot(*(b[:2] - a[:2])))
        dz = float(b[2] - a[2])
        if dist > 0.0 and sc.wind_en_mps != (0.0, 0.0):
            # the wind triangle: the aircraft crabs to hold the track, the along-track wind adds
            vg = float(ground_speed((b[0] - a[0]) / dist, (b[1] - a[1]) / dist, airspeed, sc.wind_en_mps))
            if not np.isfinite(vg):
                return UNFLYABLE_LEG_S, dist, UNFLYABLE_POWER_W, 20.0, airspeed
            t = dist / vg
        else:
            t = dist / airspeed
        # too steep to fly straight: climb or descend in a spiral at the vehicle's climb rate
        t = max(t, abs(dz) / sc.max_climb_rate_mps)
        climb = dz / t if t > 0 else 0.0
        mid_alt = sc.home.ground_alt_m + 0.5 * (a[2] + b[2])
        rho = float(air_density(mid_alt, sc.home.ground_temp_c))
        p = self._shaft_power(airspeed, climb, rho)
        amb = float(ambient_temperature(mid_alt, sc.home.ground_temp_c, sc.home.ground_alt_m))
        return t, dist, p, amb, airspeed

    def _leg_table(self, optimise: bool, candidates: Sequence[float] | None) -> LegTable:
        places = self._places()
        m = len(places)
        sc = self.scenario
        if candidates is None:
            candidates = self._default_airspeeds()
        info = np.zeros((m, m, 5))
        for i in range(m):
            for j in range(m):
                if i == j or i == self.landing_node or j == self.start_node:
                    continue
                nominal = sc.return_airspeed_mps if j == self.landing_node else sc.waypoints[j].airspeed_mps
                info[i, j] = self._leg_profile(places[i], places[j], nominal)
        if optimise:
            info = self._optimise_airspeeds(places, info, np.asarray(candidates, dtype=np.float64))
        return _sampled_legs(info, self.dt_s)

    def _optimise_airspeeds(self, places: np.ndarray, info: np.ndarray, candidates: np.ndarray) -> np.ndarray:
        """Per leg, the candidate airspeed that draws the least electrical energy from the start
        state under the present faults (one batched kernel call over legs × candidates)."""
        m = len(places)
        pairs = [(i, j) for i in range(m) for j in range(m) if info[i, j, 0] > 0]
        rows = [(i, j, v) for (i, j) in pairs for v in candidates]
        prof = [self._leg_profile(places[i], places[j], float(v)) for (i, j, v) in rows]
        steps = [max(1, int(np.ceil(p[0] / self.dt_s - 1e-9))) for p in prof]
        L = max(steps)
        dt = np.zeros((len(rows), L))
        pw = np.zeros((len(rows), L))
        am = np.zeros((len(rows), L))
        for r, (p, k) in enumerate(zip(prof, steps)):
            dt[r, :k] = p[0] / k
            pw[r, :k] = p[2]
            am[r, :k] = p[3]
        x0 = np.broadcast_to(self.initial.pack_state, (len(rows),) + np.shape(self.initial.pack_state))
        tm0 = np.broadcast_to(self.initial.motor_temp_c, (len(rows), np.size(self.initial.motor_temp_c)))
        run = self._simulate(x0, tm0, dt, pw, am, verdict=False)
        # a candidate the wind makes unflyable on its leg is never the cheapest
        flyable = np.array([p[2] < UNFLYABLE_POWER_W for p in prof])
        energy = np.where(flyable, run.energy_j, np.inf).reshape(len(pairs), len(candidates))
        out = info.copy()
        for r, (i, j) in enumerate(pairs):
            out[i, j] = prof[r * len(candidates) + int(np.argmin(energy[r]))]
        return out

    # ---- incremental flight ------------------------------------------------------------------
    def start_state(self, batch: int = 1) -> FlightState:
        st = self.initial
        return FlightState(
            x=np.repeat(st.pack_state[None], batch, axis=0),
            motor_temp=np.repeat(np.asarray(st.motor_temp_c, dtype=np.float64)[None], batch, axis=0),
            node=np.full(batch, self.start_node, dtype=np.int64), reward=np.zeros(batch),
            energy_j=np.zeros(batch), time_s=np.zeros(batch),
            peak_pack_c=np.full(batch, float(np.max(st.pack_state[:, kernel.S_T]))),
            peak_motor_c=np.full(batch, float(np.max(st.motor_temp_c))))

    def _fly(self, state: FlightState, to: np.ndarray) -> tuple[FlightState, kernel.PowertrainRun]:
        to = np.asarray(to, dtype=np.int64)
        frm = state.node
        used = int(self.legs.steps[frm, to].max()) if len(to) else 0
        used = max(used, 1)
        dt = self.legs.dt[frm, to, :used]
        run = self._simulate(state.x, state.motor_temp, dt, self.legs.power[frm, to, :used],
                             self.legs.ambient[frm, to, :used], verdict=True)
        ok = ~run.failed
        new = FlightState(
            x=run.final_pack_state, motor_temp=run.final_motor_temp, node=to,
            reward=state.reward + np.where(ok, self.rewards[to], 0.0),
            energy_j=state.energy_j + run.energy_j, time_s=state.time_s + run.elapsed_s,
            peak_pack_c=np.maximum(state.peak_pack_c, run.max_pack_temp.max(axis=1)),
            peak_motor_c=np.maximum(state.peak_motor_c, run.max_motor_temp.max(axis=1)))
        return new, run

    def advance(self, state: FlightState, to: np.ndarray) -> tuple[FlightState, np.ndarray]:
        """Fly each vehicle of the batch to waypoint ``to[b]``; returns the new states and
        whether each arrived without failing (a failed one's state is where it failed)."""
        if len(state) == 0:
            return state, np.zeros(0, dtype=bool)
        new, run = self._fly(state, to)
        return new, ~run.failed

    def home(self, state: FlightState) -> Outcome:
        """Fly each vehicle of the batch home and land; the verdict of its whole route."""
        if len(state) == 0:
            return self._outcome(state, np.zeros(0, dtype=np.int64), state.reward)
        new, run = self._fly(state, np.full(len(state), self.landing_node, dtype=np.int64))
        return self._outcome(new, run.fail_cause, state.reward)

    def cost_lower_bound(self, state: FlightState) -> tuple[np.ndarray, np.ndarray]:
        """(C_h, C_p) that every route continuing from ``state`` will at least have: peaks only
        rise, charge only falls, energy only grows."""
        soc = kernel.state_of_charge(self._pp, state.x).min(axis=1)
        return self._stress(state) + (1.0 - soc), state.energy_j / 1e6

    def _stress(self, state: FlightState) -> np.ndarray:
        pack_max = float(self._limit_topology.pack_max_temp_c.min())
        motor_max = float(self._limit_topology.motor_max_temp_c.min())
        t0 = self._t_ground
        stress = np.maximum((state.peak_pack_c - t0) / max(pack_max - t0, 1e-6),
                            (state.peak_motor_c - t0) / max(motor_max - t0, 1e-6))
        return np.maximum(stress, 0.0)

    def _outcome(self, final: FlightState, cause: np.ndarray, reward_reached: np.ndarray) -> Outcome:
        soc = kernel.state_of_charge(self._pp, final.x)
        cause = np.asarray(cause, dtype=np.int64).copy()
        short = (cause == kernel.FAIL_NONE) & (soc.min(axis=1) < self._reserve) if len(cause) else cause.astype(bool)
        cause[short] = FAIL_RESERVE
        feasible = cause == kernel.FAIL_NONE
        health = self._stress(final) + (1.0 - soc.min(axis=1) if len(cause) else 0.0)
        return Outcome(feasible=feasible, cause=cause, reward=np.where(feasible, reward_reached, 0.0),
                       reward_reached=np.asarray(reward_reached, dtype=np.float64),
                       health_cost=np.asarray(health, dtype=np.float64), power_cost=final.energy_j / 1e6,
                       final_soc=soc, final_pack_temp=final.x[..., kernel.S_T], final_motor_temp=final.motor_temp,
                       flight_time_s=final.time_s)

    # ---- whole routes in one call ----------------------------------------------------------------
    def evaluate(self, routes: Sequence[Sequence[int]], *, dt_s: float | None = None) -> RouteEvaluation:
        """Fly whole routes from the start, each closed by the landing, in ONE kernel call.

        ``dt_s`` overrides the sampling (e.g. 1 s to check the coarse planning step)."""
        sim = self if dt_s is None or dt_s == self.dt_s else self.resampled(dt_s)
        return sim._evaluate(routes)

    def resampled(self, dt_s: float) -> "VehicleSimulator":
        """The same simulator (same legs and airspeeds) sampled at another step."""
        other = object.__new__(VehicleSimulator)
        other.__dict__.update(self.__dict__)
        other.dt_s = float(dt_s)
        other._set_verdict_limits()
        info = np.stack([self.legs.duration_s, self.legs.distance_m, self.legs.power[..., 0],
                         self.legs.ambient[..., 0], self.legs.airspeed], axis=-1)
        other.legs = _sampled_legs(info, other.dt_s)
        return other

    def _evaluate(self, routes: Sequence[Sequence[int]]) -> RouteEvaluation:
        legs = self.legs
        B = len(routes)
        if B == 0:
            z = np.zeros(0)
            n_packs, n_motors = self._pp.shape[1], np.size(self.initial.motor_temp_c)
            return RouteEvaluation(z.astype(bool), z.astype(np.int64), z, z, z, z, np.zeros((0, n_packs)),
                                   np.zeros((0, n_packs)), np.zeros((0, n_motors)), z, fail_leg=z.astype(np.int64),
                                   reached=z.astype(np.int64))
        # routes as a node matrix: start, waypoints, landing, then landing again as padding (a
        # landing→landing leg has no samples)
        lens = np.fromiter((len(r) for r in routes), dtype=np.int64, count=B)
        flat = np.fromiter((int(v) for r in routes for v in r), dtype=np.int64, count=int(lens.sum()))
        row = np.repeat(np.arange(B), lens)
        if len(flat):
            bad = (flat < 0) | (flat >= self.n)
            if not bad.any():
                count = np.zeros((B, self.n), dtype=np.int64)
                np.add.at(count, (row, flat), 1)
                bad = count[row, flat] > 1
            if bad.any():
                b = int(row[np.flatnonzero(bad)[0]])
                raise ValueError(f"route {list(routes[b])}: expected distinct waypoint indices in [0, {self.n})")
        width = int(lens.max()) + 2
        nodes = np.full((B, width), self.landing_node, dtype=np.int64)
        nodes[:, 0] = self.start_node
        nodes[row, 1 + np.arange(len(flat)) - np.repeat(np.cumsum(lens) - lens, lens)] = flat
        frm, to = nodes[:, :-1], nodes[:, 1:]
        steps = legs.steps[frm, to]                       # (B, legs)
        n = max(int(steps.sum(axis=1).max()), 1)
        # left-align every route's samples (legs back to back), zero-padded at the end
        mask = (np.arange(legs.dt.shape[2])[None, None, :] < steps[:, :, None]).reshape(B, -1)
        bi, ki = np.nonzero(mask)
        pos = (np.cumsum(mask, axis=1) - 1)[bi, ki]
        dt = np.zeros((B, n))
        pw = np.zeros((B, n))
        am = np.zeros((B, n))
        dt[bi, pos] = legs.dt[frm, to].reshape(B, -1)[bi, ki]
        pw[bi, pos] = legs.power[frm, to].reshape(B, -1)[bi, ki]
        am[bi, pos] = legs.ambient[frm, to].reshape(B, -1)[bi, ki]
        st = self.start_state(B)
        run = self._simulate(st.x, st.motor_temp, dt, pw, am, verdict=True)
        failed = run.fail_step >= 0
        ends = np.cumsum(steps, axis=1)                   # sample index just past each leg
        fail_leg = np.where(failed, (ends <= run.fail_step[:, None]).sum(axis=1), -1)
        reached = np.where(failed, np.minimum(fail_leg, lens), lens)
        gain = self.rewards[to] * (np.arange(width - 1)[None, :] < reached[:, None])
        reward_reached = gain.sum(axis=1)
        final = FlightState(
            x=run.final_pack_state, motor_temp=run.final_motor_temp, node=np.full(B, self.landing_node),
            reward=reward_reached, energy_j=run.energy_j, time_s=run.elapsed_s,
            peak_pack_c=np.maximum(st.peak_pack_c, run.max_pack_temp.max(axis=1)),
            peak_motor_c=np.maximum(st.peak_motor_c, run.max_motor_temp.max(axis=1)))
        out = self._outcome(final, run.fail_cause, reward_reached)
        return RouteEvaluation(**{f: getattr(out, f) for f in Outcome.__dataclass_fields__},
                               fail_leg=fail_leg, reached=reached)


def original_order(scenario: Scenario) -> list[int]:
    """The route as planned before the fault: the waypoints in their numbered order."""
    return sorted(range(len(scenario.waypoints)), key=lambda i: scenario.waypoints[i].number)


__all__ = ["DEFAULT_DT_S", "DEFAULT_THETA", "FAIL_RESERVE", "FAILURE_NAMES", "FlightState", "LegTable", "Outcome",
           "RouteEvaluation", "VehicleSimulator", "original_order"]
