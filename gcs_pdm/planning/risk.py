"""Risk-bounded planning: candidate routes flown on common random draws of what is uncertain.

The deterministic vehicle simulator flies each route once, on the nominal model. Here each route is
flown on the same S draws (common random numbers, so two routes differ by the route, not by luck)
of the start state (SoC and temperatures), the parameters (log-normal, as the prediction draws
them; in the service spread as the estimator knows them, ``spread_from_estimator``: a
self-calibrated pack's capacity and resistance from its posterior, the rest at the prior), the
fault's magnitude and the wind; routes × samples go through the one kernel in one
call per leg. A route's verdict is then a risk verdict:

* P(failure) — the share of draws that fail in the air (cut-off voltage, depleted pack, over
  temperature, power) — must be at most ε (``max_failure_probability``, default 0.02);
* the landing reserve must be met at the ``reserve_quantile`` (default 0.05) of the lowest pack's
  landing SoC over the draws (a failed draw counts as landing empty);
* the reward is the **expected** reward: the route's reward times the share of draws that get home
  with the reserve kept (a draw that does not scores 0, as on the truth).

:class:`RiskSimulator` offers the deterministic simulator's interface (``start_state``, ``advance``,
``home``, ``evaluate``, ``cost_lower_bound``), so Algorithm 1 and the exact search run on it
unchanged and get the risk-aware objective. The exact search's pruning stays valid: per draw,
flying further never leaves the vehicle better off, so P(failure) and the landing-SoC quantile only
get worse along a route, and the nominal reward plus the reachable rewards bounds the expected reward.

Any vehicle: the simulator's own packs, motors and topology (a vehicle description's, or the
paper's aircraft as ``VehicleSimulator`` flies it), its limits and landing reserve. Motors of one
type (the same parameter vector) share one draw of it, as the paper's two motors do: the spread is
the model's uncertainty about that motor type, not a difference between two of its motors.

Approximation, named: a sampled wind changes each leg's duration (the wind triangle at the leg's
nominal airspeed) but the leg keeps its nominal shaft power (the climb rate of a leg with a height
change is the nominal one; level legs are exact).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from gcs_pdm.estimation.parallel import available_threads, thread_map
from gcs_pdm.estimation.prediction import restate, sample_parameters
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.wind import ground_speed
from gcs_pdm.planning.plan import Plan, make_plan, rank
from gcs_pdm.planning.simulator import (DEFAULT_THETA, FAIL_RESERVE, UNFLYABLE_LEG_S, UNFLYABLE_POWER_W, Outcome,
                                        RouteEvaluation, VehicleSimulator)

DEFAULT_MAX_FAILURE_PROBABILITY = 0.02
DEFAULT_RESERVE_QUANTILE = 0.05
DEFAULT_SAMPLES = 200
#: the search of ``plan_risk_bounded`` runs on this many of the draws at this step; the finalists
#: are then flown on all the draws at the planning step (what decides)
DEFAULT_SEARCH_SAMPLES = 50
DEFAULT_SEARCH_DT_S = 30.0


@dataclass(frozen=True)
class Uncertainty:
    """1-sigma spreads of what a plan cannot know exactly (a scenario's; the service draws the
    state and the parameters as its estimator knows them instead: ``ParameterSpread``)."""

    soc_sd: float = 0.02            # per pack, absolute SoC
    temp_sd_c: float = 1.0          # packs and motors
    param_rel_sigma: float = 0.05   # log-normal, every parameter (``prediction.sample_parameters``)
    fault_sd: float = 0.08          # absolute, on each fault present (clipped to [0, 1])
    wind_sd_mps: float = 1.5        # per component, about the scenario's wind


#: the log-normal spread of a parameter nothing has narrowed: a parameter set's value against the
#: real vehicle's (the paper aircraft's set, a pack described as fitted, every motor). The
#: prediction's own ``param_rel_sigma`` (``predict``): one prior for both Monte Carlos, measured to
#: hold its intervals against truths up to 15 % off the set (docs/intervals.md)
PRIOR_PARAM_REL_SIGMA = 0.08
#: pack parameters a self-calibrated pack's posterior speaks for: its capacity (the calibrator's
#: inverse capacity scale g moves C_b, q_max and C_max together) and its series resistance (R₀:
#: R_s and R_cp0, as ``StateEstimator.adopt_pack_scales`` moves them)
CAPACITY_PARAMS = (kernel.I_CB, kernel.I_QMAX, kernel.I_CMAX)
RESISTANCE_PARAMS = (kernel.I_RS, kernel.I_RCP0)


@dataclass(frozen=True)
class ParameterSpread:
    """What is known of each parameter: the draws are log-normal about ``pack_scale`` × the
    simulator's values with log-σ ``pack_log_sd`` (both (P, 12)); the motors' log-σ is one number
    (nothing in flight narrows a motor's parameters). ``learned`` (P,): the pack's capacity and
    resistance are from its calibrator's posterior (re-based on the prior), not the prior alone."""

    pack_log_sd: np.ndarray
    pack_scale: np.ndarray
    motor_log_sd: float = PRIOR_PARAM_REL_SIGMA
    learned: tuple[bool, ...] = ()


def prior_spread(n_packs: int) -> ParameterSpread:
    """Every parameter at the prior spread about its set's value (nothing learned)."""
    return ParameterSpread(np.full((n_packs, kernel.N_PACK_PARAMS), PRIOR_PARAM_REL_SIGMA),
                           np.ones((n_packs, kernel.N_PACK_PARAMS)), learned=(False,) * n_packs)


def spread_from_estimator(estimator) -> ParameterSpread:
    """The spread of what ``estimator`` (a ``StateEstimator``) knows. A self-calibrated pack's
    capacity and series resistance: what its calibrator learned, on the prior every other parameter
    gets — the calibrator starts deliberately loose (capacity σ 0.25, resistance σ 1.0: it must
    learn a mislabelled pack within a flight), and drawn at that looseness a pack nothing has been
    learned about yet cuts off in the draws at take-off. So its posterior is re-based (``_rebased``):
    its prior's σ is replaced by ``PRIOR_PARAM_REL_SIGMA`` where that is tighter (a pack history's
    tighter prior is kept), which leaves what the flight taught it (the likelihood) as it is.
    Centred where that puts them (× the description's), log-σ their relative σ (as the prior's). Every
    other parameter, and every pack without a calibrator (the paper aircraft's set, a pack described
    as fitted), at the prior."""
    from gcs_pdm.estimation import calibration as cal_state

    calibrators = list(getattr(estimator, "calib", None) or [None] * len(estimator.pack_names))
    spread = prior_spread(len(calibrators))
    log_sd, scale, learned = spread.pack_log_sd, spread.pack_scale, []
    for b, cal in enumerate(calibrators):
        learned.append(cal is not None and cal.initialised)
        if not learned[-1]:
            continue
        var = np.maximum(np.diag(cal.P), 0.0)
        # inverse capacity scale g (1: the prior's capacity q0) and R0 (its prior r0p), each re-based
        g, g_var = _rebased(float(cal.x[cal_state.I_G]), float(var[cal_state.I_G]), 1.0, cal.prior.capacity_rel_sd)
        r0, r0_var = _rebased(float(cal.x[cal_state.I_R0]), float(var[cal_state.I_R0]), cal.r0p,
                              cal.prior.r0_rel_sd * cal.r0p)
        capacity = cal.q0 / g / float(estimator.packs.params[b, kernel.I_CMAX])
        for params, centre, cv in ((CAPACITY_PARAMS, capacity, np.sqrt(g_var) / g),
                                   (RESISTANCE_PARAMS, r0 / cal.r0p, np.sqrt(r0_var) / r0)):
            scale[b, list(params)] = centre
            log_sd[b, list(params)] = cv
    return ParameterSpread(log_sd, scale, learned=tuple(learned))


def _rebased(mean: float, var: float, prior_mean: float, prior_sd: float) -> tuple[float, float]:
    """A Gaussian posterior (``mean``, ``var``) from a prior (``prior_mean``, ``prior_sd``), re-based
    on the same prior with its σ at most ``PRIOR_PARAM_REL_SIGMA`` × ``prior_mean``: precisions add,
    so the likelihood's precision is the posterior's less the old prior's (floored at 0: a
    posterior no tighter than its prior learned nothing), and the new prior's is added back."""
    new_sd = min(prior_sd, PRIOR_PARAM_REL_SIGMA * abs(prior_mean))
    old_precision, new_precision = 1.0 / prior_sd ** 2, 1.0 / new_sd ** 2
    learned = max(1.0 / max(var, 1e-300) - old_precision, 0.0)
    precision = new_precision + learned
    # the likelihood's information about the mean: posterior's less the old prior's
    info = (mean / max(var, 1e-300) - prior_mean * old_precision) if learned > 0 else 0.0
    return (prior_mean * new_precision + info) / precision, 1.0 / precision


@dataclass(frozen=True)
class Draws:
    """S draws of everything uncertain; row s of each array is one possible vehicle."""

    x0: np.ndarray            # (S, P, 4) pack states (under the draw's own parameters)
    motor_temp: np.ndarray    # (S, M)
    pack_params: np.ndarray   # (S, P, 12)
    motor_params: np.ndarray  # (S, M, 5)
    fault: np.ndarray         # (S, M) power-loss magnitudes, the simulator's motor order
    wind_en: np.ndarray       # (S, 2) the air's velocity east, north

    def __len__(self) -> int:
        return int(self.x0.shape[0])


def draw(sim: VehicleSimulator, n: int = DEFAULT_SAMPLES, *, uncertainty: Uncertainty = Uncertainty(),
         seed: int | np.random.Generator = 0, pack_mean: np.ndarray | None = None,
         pack_cov: np.ndarray | None = None, motor_sd: np.ndarray | None = None,
         spread: ParameterSpread | None = None) -> Draws:
    """``n`` draws about ``sim``'s start (its state, pack and motor parameters, motor faults and
    its scenario's wind), for any vehicle the simulator flies (P packs, M motors).

    ``pack_mean``/``pack_cov`` (P, 4) / (P, 4, 4): an estimator's pack state and covariance to draw
    the start from instead of the simulator's state with ``uncertainty.soc_sd``/``temp_sd_c``;
    ``motor_sd`` (M,): its motor temperatures' spread. ``spread``: what is known of each parameter
    (``spread_from_estimator``); None: every parameter at ``uncertainty.param_rel_sigma`` about the
    simulator's values (a scenario's stated spread)."""
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    pp0 = sim._pp[0]
    # one draw per motor type (for the paper's aircraft: one vector for both motors, as drawn so far)
    motor_types, type_of_motor = np.unique(sim._motor_rows[0], axis=0, return_inverse=True)
    if spread is None:
        pp, mp = sample_parameters((pp0, motor_types), n, rng, uncertainty.param_rel_sigma)
    else:
        if spread.pack_log_sd.shape != pp0.shape:
            raise ValueError(f"spread: {spread.pack_log_sd.shape[0]} packs, the simulator flies {pp0.shape[0]}")
        # centred on what was learned; the start state, estimated under pp0, is restated below
        pp, mp = sample_parameters((pp0 * spread.pack_scale, motor_types), n, rng, spread.pack_log_sd,
                                   spread.motor_log_sd)
    mp = mp[:, np.asarray(type_of_motor).reshape(-1)]
    if pack_mean is not None:
        cov = np.asarray(pack_cov, dtype=np.float64)
        chol = np.linalg.cholesky(cov + 1e-9 * np.eye(cov.shape[-1]))
        x = np.asarray(pack_mean, dtype=np.float64)[None] + np.einsum("bij,nbj->nbi", chol,
                                                                       rng.standard_normal((n,) + np.shape(pack_mean)))
    else:
        x = np.repeat(np.asarray(sim.initial.pack_state, dtype=np.float64)[None], n, axis=0)
        x[..., kernel.S_QB] += rng.normal(0.0, uncertainty.soc_sd, size=(n, x.shape[1])) * pp0[:, kernel.I_CMAX]
        x[..., kernel.S_T] += rng.normal(0.0, uncertainty.temp_sd_c, size=(n, x.shape[1]))
    x[..., kernel.S_QB] = np.minimum(x[..., kernel.S_QB], pp0[:, kernel.I_QMAX])
    x = restate(pp0, x, pp)
    tm0 = np.asarray(sim.initial.motor_temp_c, dtype=np.float64)
    sd = uncertainty.temp_sd_c if motor_sd is None else np.asarray(motor_sd, dtype=np.float64)
    tm = tm0[None] + sd * rng.standard_normal((n, tm0.size))
    f0 = np.asarray(sim._fault[0], dtype=np.float64)
    fault = np.clip(f0[None] + np.where(f0 > 0, 1.0, 0.0)[None] * rng.normal(0.0, uncertainty.fault_sd, (n, f0.size)),
                    0.0, 1.0)
    wind = np.asarray(sim.scenario.wind_en_mps)[None] + rng.normal(0.0, uncertainty.wind_sd_mps, (n, 2))
    return Draws(x, tm, pp, mp, fault, wind)


@dataclass(frozen=True)
class RiskState:
    """B routes part-way, each on all S draws (the carried prefix state of the risk simulator)."""

    x: np.ndarray            # (B, S, P, 4)
    motor_temp: np.ndarray   # (B, S, M)
    node: np.ndarray         # (B,)
    reward: np.ndarray       # (B,) nominal reward of the waypoints visited so far
    energy_j: np.ndarray     # (B, S)
    time_s: np.ndarray       # (B, S)
    peak_pack_c: np.ndarray  # (B, S)
    peak_motor_c: np.ndarray  # (B, S)
    failed: np.ndarray       # (B, S) the draw failed in the air (its state is where it failed)
    cause: np.ndarray        # (B, S) its FAIL_* code
    route: np.ndarray        # (B,) object: the waypoints flown so far, a tuple (the memo's key)

    def __len__(self) -> int:
        return int(self.node.shape[0])

    def take(self, idx: np.ndarray) -> "RiskState":
        return RiskState(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))

    @staticmethod
    def concat(states: Sequence["RiskState"]) -> "RiskState":
        return RiskState(*(np.concatenate([getattr(s, f) for s in states]) for f in RiskState.__dataclass_fields__))


@dataclass(frozen=True)
class RiskOutcome(Outcome):
    """An Outcome whose verdict is the risk verdict; per route also its risk figures."""

    p_failure: np.ndarray = None        # (B,) share of draws failing in the air
    p_success: np.ndarray = None        # (B,) share landing with the reserve kept
    landing_soc_q: np.ndarray = None    # (B, 3) p05, p50, p95 of the lowest pack's landing SoC (failed = 0)
    nominal_reward: np.ndarray = None   # (B,) the route's reward if everything goes as drawn


class RiskSimulator:
    """Routes × draws through the kernel; the deterministic simulator's interface, risk verdicts."""

    def __init__(self, base: VehicleSimulator, draws: Draws, *,
                 max_failure_probability: float = DEFAULT_MAX_FAILURE_PROBABILITY,
                 reserve_quantile: float = DEFAULT_RESERVE_QUANTILE) -> None:
        if not 0.0 <= max_failure_probability < 1.0:
            raise ValueError(f"max_failure_probability: must be within [0, 1), got {max_failure_probability}")
        if not 0.0 < reserve_quantile < 1.0:
            raise ValueError(f"reserve_quantile: must be within (0, 1), got {reserve_quantile}")
        self.base = base
        self.draws = draws
        self.eps = float(max_failure_probability)
        self.reserve_quantile = float(reserve_quantile)
        self.scenario, self.vehicle, self.params = base.scenario, base.vehicle, base.params
        self.pack_names, self.motor_names = base.pack_names, base.motor_names
        self.n, self.start_node, self.landing_node = base.n, base.start_node, base.landing_node
        self.rewards, self.dt_s = base.rewards, base.dt_s
        self.legs = base.legs  # nominal: the airspeeds flown (the mission's), distances
        self.S = len(draws)
        self._memo = _FlownRoutes()
        #: every distinct route closed by the landing so far: route -> (feasible, expected reward, objective)
        self.seen: dict[tuple, tuple[bool, float, float]] = {}
        self._reserve = base._reserve
        # the vehicle's topology with the verdict's limits (margins of a coarse step included)
        self._topology = base._topology
        self._sample_legs()

    # ---- per-draw legs: the wind triangle at each leg's airspeed ---------------------------------
    def _sample_legs(self) -> None:
        legs, sc = self.base.legs, self.scenario
        places = self.base._places()
        d = places[None, :, :2] - places[:, None, :2]                       # (M, M, 2) a→b
        dist = legs.distance_m
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = np.where(dist[..., None] > 0, d / np.where(dist > 0, dist, 1.0)[..., None], 0.0)
        used = legs.steps > 0
        M = dist.shape[0]
        power = np.broadcast_to(legs.power[..., 0], (self.S, M, M)).copy()
        dz = np.abs(places[None, :, 2] - places[:, None, 2])
        we = self.draws.wind_en[:, 0, None, None]
        wn = self.draws.wind_en[:, 1, None, None]
        vg = ground_speed(unit[..., 0], unit[..., 1], legs.airspeed, (we, wn))       # (S, M, M)
        with np.errstate(invalid="ignore", divide="ignore"):
            ts = np.maximum(dist / vg, dz / sc.max_climb_rate_mps)
        bad = used & ~np.isfinite(ts) & (dist > 0)
        ts = np.where(used & (dist > 0), ts, legs.duration_s)
        ts[bad] = UNFLYABLE_LEG_S
        power[bad] = UNFLYABLE_POWER_W
        t = np.where(used, ts, 0.0)
        steps = np.where(used, np.ceil(t / self.dt_s - 1e-9), 0).astype(np.int64)
        # a leg is flown in equal steps at a constant power and ambient: per draw and leg, its
        # number of steps, their length and its power (the kernel's rows are built per call)
        self._steps = steps                                                  # (S, M, M)
        self._step_s = np.where(used, t / np.maximum(steps, 1), 0.0)         # (S, M, M)
        self._power = power                                                  # (S, M, M)
        self._ambient = legs.ambient[..., 0]                                 # (M, M)

    # ---- flying ----------------------------------------------------------------------------------
    def start_state(self, batch: int = 1) -> RiskState:
        dr, S = self.draws, self.S
        x = np.repeat(dr.x0[None], batch, axis=0)
        tm = np.repeat(dr.motor_temp[None], batch, axis=0)
        z = np.zeros((batch, S))
        return RiskState(x=x, motor_temp=tm, node=np.full(batch, self.start_node, dtype=np.int64),
                         reward=np.zeros(batch), energy_j=z.copy(), time_s=z.copy(),
                         peak_pack_c=x[..., kernel.S_T].max(axis=2), peak_motor_c=tm.max(axis=2),
                         failed=np.zeros((batch, S), dtype=bool), cause=np.zeros((batch, S), dtype=np.int64),
                         route=_routes([()] * batch))

    def _fly(self, state: RiskState, to: np.ndarray) -> RiskState:
        """Fly each route of the batch on to ``to[b]`` on every draw. Only the draws that still fly
        and have a leg to fly go through the kernel, grouped by their number of steps
        (``_step_groups``): the kernel steps every row of a call as often as its longest one, and a
        padding step (no time passes) costs about half a flown one."""
        B, S = len(state), self.S
        to = np.asarray(to, dtype=np.int64)
        frm = state.node
        n_steps = self._steps[:, frm, to].T.reshape(-1)                        # (B·S,)
        rows = np.flatnonzero((n_steps > 0) & ~state.failed.reshape(-1))
        x = state.x.reshape(B * S, *state.x.shape[2:]).copy()
        tm = state.motor_temp.reshape(B * S, -1).copy()
        energy, elapsed = np.zeros(B * S), np.zeros(B * S)
        peak_pack, peak_motor = state.peak_pack_c.reshape(-1).copy(), state.peak_motor_c.reshape(-1).copy()
        new_fail = np.zeros(B * S, dtype=bool)
        cause = state.cause.reshape(-1).copy()
        dr = self.draws

        def fly(group: np.ndarray):
            used = int(n_steps[group].max())
            b, s = group // S, group % S
            leg = (s, frm[b], to[b])
            on = np.arange(used)[None, :] < n_steps[group][:, None]          # the padding flies no time
            return topology.simulate_vehicle(self._topology, dr.pack_params[s], dr.motor_params[s], x[group],
                                             tm[group], np.where(on, self._step_s[leg][:, None], 0.0),
                                             np.where(on, self._power[leg][:, None], 0.0),
                                             np.where(on, self._ambient[leg[1:]][:, None], 0.0), dr.fault[s],
                                             fault_drag=0.1, max_dt=self.dt_s, stop_on_failure=True)

        # the kernel releases the GIL: a large call is split over the threads available (rows are
        # independent, so the numbers are one thread's)
        calls = [piece for group in _step_groups(rows, n_steps[rows])
                 for piece in np.array_split(group, _pieces(group.size * int(n_steps[group[-1]])))]
        for group, run in zip(calls, thread_map(fly, calls)):
            x[group], tm[group] = run.final_pack_state, run.final_motor_temp
            energy[group], elapsed[group] = run.energy_j, run.elapsed_s
            peak_pack[group] = np.maximum(peak_pack[group], run.max_pack_temp.max(axis=1))
            peak_motor[group] = np.maximum(peak_motor[group], run.max_motor_temp.max(axis=1))
            new_fail[group] = run.failed
            cause[group] = np.where(run.failed, run.fail_cause, cause[group])
        return RiskState(
            x=x.reshape(state.x.shape), motor_temp=tm.reshape(state.motor_temp.shape),
            node=to, reward=state.reward + self.rewards[to],
            energy_j=state.energy_j + energy.reshape(B, S), time_s=state.time_s + elapsed.reshape(B, S),
            peak_pack_c=peak_pack.reshape(B, S), peak_motor_c=peak_motor.reshape(B, S),
            failed=state.failed | new_fail.reshape(B, S), cause=cause.reshape(B, S),
            route=_routes([r + (int(w),) for r, w in zip(state.route, to)]))

    def _fly_memo(self, state: RiskState, to: np.ndarray) -> RiskState:
        """``_fly``, once per distinct route: a prefix's state depends on nothing but the route (the
        draws are fixed), and a particle filter's resampled particles repeat prefixes many times."""
        keys = [r + (int(w),) for r, w in zip(state.route, to)]
        missing: dict[tuple, int] = {}
        for b, k in enumerate(keys):
            if k not in self._memo and k not in missing:
                missing[k] = b
        if missing:
            if len(self._memo) + len(missing) > MEMO_LIMIT:
                self._memo.clear()
            rows = np.fromiter(missing.values(), dtype=np.int64, count=len(missing))
            self._memo.add(list(missing), self._fly(state.take(rows), np.asarray(to, dtype=np.int64)[rows]))
        return self._memo.get(keys)

    def advance(self, state: RiskState, to: np.ndarray) -> tuple[RiskState, np.ndarray]:
        """Fly each route of the batch on to waypoint ``to[b]`` on every draw; ``ok``: its
        P(failure) so far is still within ε (a route past it can only get worse)."""
        if len(state) == 0:
            return state, np.zeros(0, dtype=bool)
        new = self._fly_memo(state, to)
        return new, new.failed.mean(axis=1) <= self.eps + 1e-12

    def home(self, state: RiskState) -> RiskOutcome:
        if len(state) == 0:
            return self._outcome(state)
        out = self._outcome(self._fly_memo(state, np.full(len(state), self.landing_node, dtype=np.int64)))
        obj = out.objective()
        for b, r in enumerate(state.route):
            self.seen[r] = (bool(out.feasible[b]), float(out.reward[b]), float(obj[b]))
        return out

    def _stress(self, state: RiskState) -> np.ndarray:
        return self.base._stress(state)  # the vehicle's limits, per draw

    def _soc(self, x: np.ndarray) -> np.ndarray:
        """(B, S, P) SoC of each draw under its own parameters."""
        return kernel.state_of_charge(self.draws.pack_params[None], x)

    def cost_lower_bound(self, state: RiskState) -> tuple[np.ndarray, np.ndarray]:
        soc = self._soc(state.x).min(axis=2)
        return (self._stress(state) + (1.0 - soc)).mean(axis=1), state.energy_j.mean(axis=1) / 1e6

    def _outcome(self, final: RiskState) -> RiskOutcome:
        B = len(final)
        P, M = self.draws.pack_params.shape[1], self.draws.motor_params.shape[1]
        soc = self._soc(final.x) if B else np.zeros((0, self.S, P))
        low = np.where(final.failed, 0.0, soc.min(axis=2)) if B else np.zeros((0, self.S))
        p_fail = final.failed.mean(axis=1) if B else np.zeros(0)
        success = ~final.failed & (low >= self._reserve)
        p_success = success.mean(axis=1) if B else np.zeros(0)
        q = np.quantile(low, [self.reserve_quantile, 0.5, 0.95], axis=1).T if B else np.zeros((0, 3))
        feasible = (p_fail <= self.eps + 1e-12) & (q[:, 0] >= self._reserve)
        cause = np.full(B, kernel.FAIL_NONE, dtype=np.int64)
        for b in np.flatnonzero(~feasible):
            fc = final.cause[b][final.failed[b]]
            cause[b] = int(np.bincount(fc).argmax()) if p_fail[b] > self.eps and fc.size else FAIL_RESERVE
        expected = final.reward * p_success
        health = (self._stress(final) + 1.0 - low).mean(axis=1) if B else np.zeros(0)
        # the medians over the draws, in one pass: SoC (P), pack temperatures (P), motor temperatures (M), time
        per_draw = np.concatenate([soc, final.x[..., kernel.S_T], final.motor_temp, final.time_s[..., None]], axis=2)
        med = np.median(per_draw, axis=1) if B else per_draw[:, 0]
        return RiskOutcome(feasible=feasible, cause=cause, reward=np.where(feasible, expected, 0.0),
                           reward_reached=expected, health_cost=health,
                           power_cost=final.energy_j.mean(axis=1) / 1e6 if B else np.zeros(0),
                           final_soc=med[:, :P], final_pack_temp=med[:, P:2 * P],
                           final_motor_temp=med[:, 2 * P:2 * P + M], flight_time_s=med[:, 2 * P + M],
                           p_failure=p_fail, p_success=p_success, landing_soc_q=q, nominal_reward=final.reward)

    # ---- whole routes ----------------------------------------------------------------------------
    def evaluate(self, routes: Sequence[Sequence[int]], *, dt_s: float | None = None) -> RouteEvaluation:
        """Whole routes on every draw (leg by leg from the carried states: the same numbers as
        ``advance``/``home``). ``fail_leg``: -1 when the risk verdict holds, else ``len(route)``
        (the risk is a property of the whole route, not of one leg)."""
        if dt_s is not None and dt_s != self.dt_s:
            raise ValueError("RiskSimulator.evaluate: the planning step is fixed by the base simulator")
        routes = [tuple(int(w) for w in r) for r in routes]
        B = len(routes)
        state = self.start_state(B)
        for level in range(max((len(r) for r in routes), default=0)):
            idx = np.array([b for b, r in enumerate(routes) if len(r) > level], dtype=np.int64)
            new = self._fly_memo(state.take(idx), np.array([routes[b][level] for b in idx], dtype=np.int64))
            state = _scatter(state, idx, new)
        out = self.home(state)
        lens = np.array([len(r) for r in routes], dtype=np.int64)
        return RouteEvaluation(**{f: getattr(out, f) for f in Outcome.__dataclass_fields__},
                               fail_leg=np.where(out.feasible, -1, lens), reached=lens)

    def subset(self, n: int, dt_s: float | None = None) -> "RiskSimulator":
        """The same simulator on the first ``n`` draws (a common subset: the same random numbers),
        sampled at ``dt_s`` (default: the same step)."""
        d = self.draws
        sub = Draws(*(getattr(d, f)[:n] for f in Draws.__dataclass_fields__))
        base = self.base if dt_s is None or dt_s == self.dt_s else self.base.resampled(dt_s)
        return RiskSimulator(base, sub, max_failure_probability=self.eps, reserve_quantile=self.reserve_quantile)

    def risk_of(self, route: Sequence[int]) -> dict:
        """The risk figures of one route, for the plan's record."""
        state = self.start_state(1)
        for w in route:
            state = self._fly_memo(state, np.array([int(w)]))  # flown already when it was evaluated
        out = self.home(state)
        return {"p_failure": float(out.p_failure[0]), "p_success": float(out.p_success[0]),
                "landing_soc_quantiles": {"q": [self.reserve_quantile, 0.5, 0.95],
                                          "soc": [float(v) for v in out.landing_soc_q[0]]},
                "expected_reward": float(out.reward_reached[0]), "nominal_reward": float(out.nominal_reward[0]),
                "samples": self.S, "max_failure_probability": self.eps, "reserve_quantile": self.reserve_quantile}


def plan_risk_bounded(search: Callable[..., Plan], sim: RiskSimulator, *,
                      search_samples: int | None = DEFAULT_SEARCH_SAMPLES,
                      search_dt_s: float | None = DEFAULT_SEARCH_DT_S, finalists: int = 12,
                      particles: int = 30, seed=0, theta: Sequence[float] = DEFAULT_THETA,
                      should_stop: Callable[[], bool] | None = None) -> Plan:
    """Run the planner ``search`` (a registry entry's ``run(sim, *, particles, seed, theta,
    should_stop)``; by name: ``planners.run_risk_bounded``) with the risk-aware objective.

    With ``search_samples`` (< the draws), the search runs on that common subset of the draws
    sampled at ``search_dt_s`` (coarser than the planning step: it only ranks routes), and
    the ``finalists`` best distinct routes it closed (plus its own answer and the way straight home)
    are flown on ALL the draws; the best of them that keeps the risk bound there is the plan. So
    the decision, and every figure reported with it, is on all the draws; the subset only steers
    the search (the 1-s budget: docs/planning.md). ``search_samples=None`` searches on all of them."""
    if search_samples is None or search_samples >= sim.S:
        search_sim = sim if search_dt_s is None else sim.subset(sim.S, search_dt_s)
    else:
        search_sim = sim.subset(int(search_samples), search_dt_s)
    found = search(search_sim, particles=particles, seed=seed, theta=theta, should_stop=should_stop)
    ranked = sorted(search_sim.seen.items(), key=lambda kv: (not kv[1][0], -kv[1][1], -kv[1][2]))
    routes = [found.route, ()] + [r for r, v in ranked[:finalists] if v[0]]
    routes = list(dict.fromkeys(tuple(r) for r in routes))
    flown, ev = _decide_on_all_draws(sim, routes)
    obj = ev.objective(theta)
    i = rank(np.where(ev.feasible, ev.reward, -1.0), np.where(ev.feasible, obj, -np.inf))
    stats = dict(found.stats, search_samples=search_sim.S, finalists=len(routes), finalists_flown=len(flown),
                 searched_planner=found.planner, risk=sim.risk_of(flown[i]))
    return make_plan(sim, flown[i], f"{found.planner}_risk", theta, **stats)


#: finalists flown on all the draws per batch, best nominal reward first
FINALIST_BATCH = 3


def _decide_on_all_draws(sim: RiskSimulator, routes: list[tuple]) -> tuple[list[tuple], RouteEvaluation]:
    """The finalists that can still be the decision, flown on all the draws: best nominal reward
    first, in batches, until the best feasible expected reward so far exceeds every remaining
    route's nominal reward (an expected reward is at most the nominal one, so none of those could
    rank first: the decision is the one flying them all would give). Returns the routes flown and
    their evaluation."""
    nominal = [float(sum(sim.rewards[w] for w in r)) for r in routes]
    order = sorted(range(len(routes)), key=lambda k: -nominal[k])
    flown: list[tuple] = []
    parts: list[RouteEvaluation] = []
    best = -np.inf
    for start in range(0, len(order), FINALIST_BATCH):
        batch = order[start:start + FINALIST_BATCH]
        if nominal[batch[0]] < best:
            break
        ev = sim.evaluate([routes[k] for k in batch])
        flown += [routes[k] for k in batch]
        parts.append(ev)
        if ev.feasible.any():
            best = max(best, float(ev.reward[ev.feasible].max()))
    return flown, RouteEvaluation(**{f: np.concatenate([getattr(e, f) for e in parts])
                                     for f in RouteEvaluation.__dataclass_fields__})


#: routes whose flown states are remembered (about 40 kB each at 200 draws)
MEMO_LIMIT = 20_000


class _FlownRoutes:
    """The states of the routes flown so far, one row each of growing arrays (a batch of them is
    one gather per field, not one small array per route)."""

    def __init__(self) -> None:
        self._row: dict[tuple, int] = {}
        self._rows: RiskState | None = None

    def __len__(self) -> int:
        return len(self._row)

    def __contains__(self, route: tuple) -> bool:
        return route in self._row

    def clear(self) -> None:
        self._row.clear()
        self._rows = None

    def add(self, routes: list[tuple], flown: RiskState) -> None:
        start = len(self._row)
        if self._rows is None:
            self._rows = _grown(flown, max(64, len(routes)), 0)
        elif start + len(routes) > len(self._rows):
            self._rows = _grown(self._rows, 2 * (start + len(routes)), start)
        for f in RiskState.__dataclass_fields__:
            getattr(self._rows, f)[start:start + len(routes)] = getattr(flown, f)
        self._row.update(zip(routes, range(start, start + len(routes))))

    def get(self, routes: list[tuple]) -> RiskState:
        return self._rows.take(np.fromiter((self._row[r] for r in routes), dtype=np.int64, count=len(routes)))


def _grown(rows: RiskState, capacity: int, keep: int) -> RiskState:
    """``rows``' arrays with room for ``capacity`` rows, the first ``keep`` copied over."""
    out = {}
    for f in RiskState.__dataclass_fields__:
        a = getattr(rows, f)
        out[f] = np.empty((capacity,) + a.shape[1:], dtype=a.dtype)
        out[f][:keep] = a[:keep]
    return RiskState(**out)


#: the kernel call's fixed cost, in row-steps (about 100 µs against about 1 µs per row-step)
CALL_COST_ROW_STEPS = 600


#: a kernel call is split over the threads only when each piece keeps at least this many row-steps
#: (about 2 ms: a thread's hand-over costs tens of µs)
MIN_ROW_STEPS_PER_THREAD = 4000


def _pieces(row_steps: int) -> int:
    return max(1, min(available_threads(), row_steps // MIN_ROW_STEPS_PER_THREAD))


def _step_groups(rows: np.ndarray, n_steps: np.ndarray) -> list[np.ndarray]:
    """``rows`` split into kernel calls, each sorted by its number of steps (the last is the
    longest), the split the cheapest in row-steps flown (padding included) plus
    ``CALL_COST_ROW_STEPS`` per call: a dynamic programme over the distinct step counts."""
    if rows.size == 0:
        return []
    order = np.argsort(n_steps, kind="stable")
    values, counts = np.unique(n_steps[order], return_counts=True)
    values, cum = values.tolist(), [0, *np.cumsum(counts).tolist()]
    best, cut = [0.0], [0]
    for j in range(1, len(values) + 1):  # best[j]: the first j step counts split; the last call flies values[j-1]
        i = min(range(j), key=lambda i: best[i] + (cum[j] - cum[i]) * values[j - 1])
        cut.append(i)
        best.append(best[i] + (cum[j] - cum[i]) * values[j - 1] + CALL_COST_ROW_STEPS)
    bounds, j = [], len(values)
    while j > 0:
        bounds.append((cum[cut[j]], cum[j]))
        j = cut[j]
    return [rows[order[a:b]] for a, b in reversed(bounds)]


def _routes(items: Sequence[tuple]) -> np.ndarray:
    out = np.empty(len(items), dtype=object)
    out[:] = list(items)
    return out


def _scatter(base, idx: np.ndarray, values):
    fields = {}
    for f in type(base).__dataclass_fields__:
        a = getattr(base, f).copy()
        a[idx] = getattr(values, f)
        fields[f] = a
    return type(base)(**fields)


__all__ = ["DEFAULT_MAX_FAILURE_PROBABILITY", "DEFAULT_RESERVE_QUANTILE", "DEFAULT_SAMPLES", "Draws",
           "PRIOR_PARAM_REL_SIGMA", "ParameterSpread", "RiskOutcome", "RiskSimulator", "RiskState", "Uncertainty",
           "draw", "plan_risk_bounded", "prior_spread", "spread_from_estimator"]
