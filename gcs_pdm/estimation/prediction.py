"""Monte Carlo prediction: where the packs and motors are heading under a future load.

From the estimator's state (mean and covariance of every pack, motor temperatures), draw N
samples of the state *and* of the parameters (multiplicative log-normal spread around the
parameter set — the model's own uncertainty), and fly all of them through the future shaft-power
profile in ONE ``topology.simulate_vehicle`` call with ``stop_on_failure``. Each sample stops at
its first failure (cut-off voltage, depletion, over-temperature, power); the spread of the
results is the prediction's uncertainty.

The future load is a shaft-power profile (``FutureLoad``); the planner's vehicle simulator turns a
route into exactly such a profile, so a route can be predicted by passing its profile.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
from numba import config as numba_config
from numba import njit

from gcs_pdm.estimation import held_current_arrays
from gcs_pdm.estimation.calibrated_cutoff import CutoffModel
from gcs_pdm.estimation.calibrated_pack import CalibratedPacks
from gcs_pdm.estimation.extended_prediction import ExtendedPacks
from gcs_pdm.estimation.parallel import available_threads, thread_map
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES, ParameterSet
from gcs_pdm.models.powertrain import Limits
from gcs_pdm.vehicle.model_inputs import ModelInputs, model_inputs
from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

QUANTILES = (0.05, 0.5, 0.95)
#: the paper's aircraft (the ``edge540`` preset): what ``predict`` flies when no vehicle is named
EDGE540_INPUTS = model_inputs(PRESETS[DEFAULT_PRESET])


@dataclass(frozen=True)
class FutureLoad:
    """Shaft power over the future: sample k lasts ``dt[k]`` s at ``shaft_power_w[k]`` W."""

    dt: np.ndarray
    shaft_power_w: np.ndarray
    ambient_c: np.ndarray | float = 20.0

    def __post_init__(self) -> None:
        dt = np.asarray(self.dt, dtype=np.float64)
        p = np.asarray(self.shaft_power_w, dtype=np.float64)
        if dt.ndim != 1 or p.shape != dt.shape:
            raise ValueError(f"FutureLoad: dt and shaft_power_w must be 1-D of one length, got {dt.shape}, {p.shape}")
        if np.any(~np.isfinite(dt)) or np.any(dt < 0):
            raise ValueError("FutureLoad.dt: steps must be finite and non-negative")
        if np.any(~np.isfinite(p)):
            raise ValueError("FutureLoad.shaft_power_w: must be finite")

    @classmethod
    def constant(cls, power_w: float, duration_s: float, step_s: float = 1.0, ambient_c: float = 20.0) -> "FutureLoad":
        n = max(1, int(math.ceil(duration_s / step_s)))
        return cls(np.full(n, duration_s / n), np.full(n, float(power_w)), ambient_c)

    @property
    def duration_s(self) -> float:
        return float(np.sum(self.dt))

    def after(self, elapsed_s: float) -> "FutureLoad":
        """The part of the load still ahead once ``elapsed_s`` of it has been flown."""
        ends = np.cumsum(self.dt)
        k = int(np.searchsorted(ends, elapsed_s, side="right"))
        amb = self.ambient_c if np.ndim(self.ambient_c) == 0 else np.asarray(self.ambient_c)[k:]
        dt = np.array(self.dt, dtype=np.float64)[k:]
        if dt.size:
            dt[0] = ends[k] - max(elapsed_s, 0.0) if elapsed_s > 0 else dt[0]  # the part of sample k still ahead
        return FutureLoad(dt, np.asarray(self.shaft_power_w)[k:], amb)


def load_for_route(simulator, route, *, from_node: int | None = None, land: bool = True) -> FutureLoad:
    """The shaft-power load of flying ``route`` (waypoint indices) with the planner's vehicle
    simulator (``gcs_pdm.planning.simulator.VehicleSimulator``: its sampled leg table), from
    ``from_node`` (default: the scenario's start) and, with ``land``, on to the landing site."""
    legs = simulator.legs
    nodes = [simulator.start_node if from_node is None else int(from_node)] + [int(w) for w in route]
    if land:
        nodes.append(simulator.landing_node)
    dt, power, ambient = [], [], []
    for a, b in zip(nodes[:-1], nodes[1:]):
        k = int(legs.steps[a, b])
        dt.append(legs.dt[a, b, :k])
        power.append(legs.power[a, b, :k])
        ambient.append(legs.ambient[a, b, :k])
    if not dt:
        raise ValueError("load_for_route: empty route and no landing")
    return FutureLoad(np.concatenate(dt), np.concatenate(power), np.concatenate(ambient))


@dataclass(frozen=True)
class Prediction:
    """Quantiles (5 %, 50 %, 95 %) over the Monte Carlo samples; ``inf`` = not reached within the horizon."""

    horizon_s: float
    n_samples: int
    p_failure: float
    time_to_failure_s: np.ndarray        # (3,)
    failure_causes: dict
    pack_time_to_cutoff_s: np.ndarray    # (4, 3) to the pack's cut-off voltage or empty, whichever first
    pack_energy_to_cutoff_j: np.ndarray  # (4, 3) energy drawn from the pack until its cut-off (or horizon)
    peak_pack_temp_c: np.ndarray         # (4, 3)
    peak_motor_temp_c: np.ndarray        # (2, 3)
    time_s: np.ndarray | None = None     # (m,) offsets into the future of the median trajectories (every ~10 s)
    soc_median: np.ndarray | None = None          # (n, 4)
    pack_temp_median: np.ndarray | None = None    # (n, 4)
    motor_temp_median: np.ndarray | None = None   # (n, 2)
    extra: dict = field(default_factory=dict)
    #: the packs and motors the rows are (a vehicle description's, or the paper's)
    pack_names: tuple[str, ...] = PACK_NAMES
    motor_names: tuple[str, ...] = MOTOR_NAMES
    #: per sample (``predict(..., per_sample=True)``, else None): when it first failed (``inf``: it
    #: did not), the ``kernel.FAILURE_NAMES`` code of that failure (``kernel.FAIL_NONE``: none), and
    #: each pack's SoC at the end of the load (NaN where the sample stopped at a failure before it)
    sample_failure_time_s: np.ndarray | None = None   # (N,)
    sample_failure_cause: np.ndarray | None = None    # (N,) int
    sample_end_soc: np.ndarray | None = None          # (N, packs)

    def to_dict(self) -> dict:
        def q(a):
            return [None if not math.isfinite(float(x)) else round(float(x), 3) for x in a]

        return {
            "horizon_s": self.horizon_s,
            "n_samples": self.n_samples,
            "p_failure": round(self.p_failure, 4),
            "quantiles": list(QUANTILES),
            "time_to_failure_s": q(self.time_to_failure_s),
            "failure_causes": dict(self.failure_causes),
            "packs": {n: {"time_to_cutoff_s": q(self.pack_time_to_cutoff_s[i]),
                          "energy_to_cutoff_j": q(self.pack_energy_to_cutoff_j[i]),
                          "peak_temp_c": q(self.peak_pack_temp_c[i])} for i, n in enumerate(self.pack_names)},
            "motors": {n: {"peak_temp_c": q(self.peak_motor_temp_c[i])} for i, n in enumerate(self.motor_names)},
            **self.extra,
        }


ParamsLike = "ParameterSet | tuple[np.ndarray, np.ndarray]"


@lru_cache(maxsize=64)
def _nearest_ranks(n: int) -> np.ndarray:
    """The order statistics ``np.quantile(…, QUANTILES, method="nearest")`` picks from n values
    (numpy's own rounding, read off the ranks 0 … n-1 themselves)."""
    return np.quantile(np.arange(n), QUANTILES, method="nearest").astype(np.intp)


def nearest_quantiles(a: np.ndarray) -> np.ndarray:
    """(columns, 3): ``np.quantile(a, QUANTILES, axis=0, method="nearest").T`` of (samples, columns),
    the same numbers (each is one of the values), from one sort: numpy's quantile costs ~0.1 ms a
    call in its argument handling, five calls a prediction (docs/notes/2026-11-27-extended-mc-4.md).
    A column with a NaN gives NaN, as numpy's."""
    a = np.asarray(a, dtype=np.float64)
    ordered = np.sort(a, axis=0)  # NaN sorts last
    out = ordered[_nearest_ranks(a.shape[0])].T
    out[np.isnan(ordered[-1])] = np.nan
    return out


def _motor_types(motors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(motors, axis=0, return_inverse=True)`` (rows sorted, each motor's row): with one
    type (every row the same bytes, the usual vehicle) that type without numpy's row sort, ~0.1 ms."""
    bits = np.ascontiguousarray(motors, dtype=np.float64).view(np.int64)
    if bits.shape[0] and (bits == bits[0]).all() and not np.isnan(motors).any():
        return np.array(motors[:1], dtype=np.float64), np.zeros(motors.shape[0], dtype=np.intp)
    return np.unique(motors, axis=0, return_inverse=True)


def base_arrays(params) -> tuple[np.ndarray, np.ndarray]:
    """(4, 12) pack matrix and (5,) motor vector from a ParameterSet or such a pair of arrays
    (the estimator's own, once diagnosed degradation has been adopted)."""
    if isinstance(params, ParameterSet):
        return params.pack_matrix(), params.motor_vector()
    packs, motor = params
    return np.asarray(packs, dtype=np.float64), np.asarray(motor, dtype=np.float64)


def sample_parameters(params, n: int, rng: np.random.Generator, rel_sigma: float | np.ndarray,
                      motor_rel_sigma: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n, 4, 12) pack and (n, 5) motor parameter samples, log-normal around ``params``.

    q_max keeps its ratio to C_b (a full pack stays at full voltage), C_max never exceeds q_max,
    and R_cp2 — an exponent — moves by a tenth of the spread with R_cp1 compensating, so the
    end-of-discharge resistance varies by the spread itself (as ``params.perturbed`` does).

    ``rel_sigma``: one log-σ for every pack parameter, or one per pack and parameter (the pack
    matrix's shape: what is known differs by pack and parameter, ``planning.risk.ParameterSpread``);
    ``motor_rel_sigma``: the motors' (default ``rel_sigma``, which must then be a number)."""
    base, motor_base = base_arrays(params)
    packs = base[None] * np.exp(rng.normal(0.0, rel_sigma, size=(n,) + base.shape))
    rcp2_sigma = rel_sigma if np.ndim(rel_sigma) == 0 else np.asarray(rel_sigma)[:, kernel.I_RCP2]
    packs[..., kernel.I_RCP2] = base[:, kernel.I_RCP2] * (1.0 + rng.normal(0.0, rcp2_sigma / 10.0, size=(n, base.shape[0])))
    packs[..., kernel.I_RCP1] *= np.exp(base[:, kernel.I_RCP2] - packs[..., kernel.I_RCP2])
    packs[..., kernel.I_QMAX] = packs[..., kernel.I_CB] * (base[:, kernel.I_QMAX] / base[:, kernel.I_CB])
    packs[..., kernel.I_CMAX] = np.minimum(packs[..., kernel.I_CMAX], packs[..., kernel.I_QMAX])
    motor_sigma = rel_sigma if motor_rel_sigma is None else motor_rel_sigma
    motor = motor_base[None] * np.exp(rng.normal(0.0, motor_sigma, size=(n,) + motor_base.shape))
    return packs, motor


def sample_states(pack_mean: np.ndarray, pack_cov: np.ndarray, motor_mean: np.ndarray, motor_sd: np.ndarray,
                  n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, 4, 4) pack states from per-pack Gaussians, (n, 2) motor temperatures."""
    chol = np.linalg.cholesky(pack_cov + 1e-9 * np.eye(pack_cov.shape[-1]))
    z = rng.standard_normal((n,) + pack_mean.shape)
    x = pack_mean[None] + np.einsum("bij,nbj->nbi", chol, z)
    tm = motor_mean[None] + motor_sd[None] * rng.standard_normal((n, motor_mean.size))
    return x, tm


def restate(base: np.ndarray, x: np.ndarray, sampled: np.ndarray) -> np.ndarray:
    """Re-express states estimated under ``base`` parameters for ``sampled`` ones.

    The kernel's charges are absolute (q_b counts from empty capacitor, not from cut-off), so a
    state only means the same thing under another parameter vector once re-expressed: keep the
    SoC (a fraction of *that* sample's capacity, so capacity uncertainty reaches the prediction)
    and the voltages across C_cp and C_s."""
    out = x.copy()
    deficit = base[:, kernel.I_QMAX] - x[..., kernel.S_QB]
    out[..., kernel.S_QB] = sampled[..., kernel.I_QMAX] - deficit * sampled[..., kernel.I_CMAX] / base[:, kernel.I_CMAX]
    out[..., kernel.S_QCP] = x[..., kernel.S_QCP] * sampled[..., kernel.I_CCP] / base[:, kernel.I_CCP]
    out[..., kernel.S_QS] = x[..., kernel.S_QS] * sampled[..., kernel.I_CS] / base[:, kernel.I_CS]
    return out


def predict(params, pack_mean: np.ndarray, pack_cov: np.ndarray, motor_temp_c: np.ndarray,
            motor_temp_sd: np.ndarray, load: FutureLoad, *, rng: np.random.Generator, n_samples: int = 100,
            param_rel_sigma: float = 0.08, fault: np.ndarray | None = None, limits: Limits | None = None,
            trajectories: bool = True, stop_on_failure: bool = True, trajectory_every_s: float = 10.0,
            vehicle: ModelInputs = EDGE540_INPUTS, per_sample: bool = False, extended=None) -> Prediction:
    """Monte Carlo prediction over state and parameter uncertainty (one kernel call).

    ``vehicle``: the description's ``ModelInputs`` (its P packs, M motors, buses and per-pack and
    per-motor limits; default the paper's aircraft, ``edge540``). ``params``: a ParameterSet or a
    (pack matrix (P, 12), motor vector (5,) or matrix (M, 5)) pair. Motors with one parameter
    vector are one type and share each sample's draw (as the planner's risk draws do).

    ``fault``: (M,) motor fault magnitudes believed present — the diagnoser's faults.
    ``limits``: one ``Limits`` for every pack and motor instead of the description's (a scenario's).
    With ``stop_on_failure`` a sample ends at the vehicle's first failure, so a pack that had not
    reached its cut-off by then reports ``inf`` for that sample; pass ``False`` to run every sample
    through the whole horizon and read each pack's own cut-off time.

    ``per_sample``: also report each sample's failure time and cause and its packs' SoC at the end
    of the load (``Prediction.sample_*``), for a caller that needs more than the quantiles (a
    route's landing SoC over the samples that land).

    ``extended``: an ``extended_prediction.ExtendedPacks`` (the paper's aircraft) or a
    ``calibrated_pack.CalibratedPacks`` (a description's self-calibrated packs): those packs are
    drawn from their own filter and fly the kernel's extended variant
    (``topology.simulate_vehicle_extended``)."""
    if n_samples < 1:
        raise ValueError(f"n_samples: must be >= 1, got {n_samples}")
    n_motors = vehicle.n_motors
    packs0, motors0 = base_arrays(params)
    motor_types, type_of_motor = _motor_types(np.broadcast_to(motors0, (n_motors, kernel.N_MOTOR_PARAMS)))
    pp, mp = sample_parameters((packs0, motor_types), n_samples, rng, param_rel_sigma)
    mp = mp[:, np.asarray(type_of_motor).reshape(-1)]  # (n, M, 5): each motor its type's draw
    x0, tm0 = sample_states(np.asarray(pack_mean, dtype=np.float64), np.asarray(pack_cov, dtype=np.float64),
                            np.asarray(motor_temp_c, dtype=np.float64), np.asarray(motor_temp_sd, dtype=np.float64),
                            n_samples, rng)
    x0 = restate(packs0, x0, pp)
    if extended is not None:
        x0, ep = extended.sample(x0, n_samples, rng, param_rel_sigma)
    topo = vehicle.topology if limits is None else vehicle.topology.with_limits(*limits.as_tuple())
    f = np.zeros((1, n_motors)) if fault is None else np.clip(
        np.asarray(fault, dtype=np.float64).reshape(1, n_motors), 0.0, 1.0)
    dt = np.asarray(load.dt, dtype=np.float64)
    amb = load.ambient_c if np.ndim(load.ambient_c) == 0 else np.asarray(load.ambient_c, dtype=np.float64)
    power = np.asarray(load.shaft_power_w, dtype=np.float64)
    t_end = np.cumsum(dt)
    traj_k = None
    if trajectories:
        # medians on a coarse grid: a median over samples is the costly part, and the rate
        # comparison needs minutes, not seconds
        traj_k = np.unique(np.searchsorted(t_end, np.arange(0.0, t_end[-1] + trajectory_every_s, trajectory_every_s)))
        traj_k = traj_k[traj_k < t_end.size]
    # the steps the kernel records: the trajectories' grid, and the load's last step for per-sample end states
    rec_k = traj_k
    if per_sample:
        last = np.array([t_end.size - 1], dtype=np.int64)
        rec_k = last if traj_k is None else np.union1d(traj_k, last)

    def fly(rows: slice) -> dict:
        """Samples ``rows`` through the load, reduced to what the prediction reports (the kernel
        keeps each pack's end — cut-off or empty — and the peaks to the first failure as it flies;
        per-step values only on the trajectories' coarse grid)."""
        f_rows = f if f.shape[0] == 1 else f[rows]
        if extended is not None:  # some packs on the extended variant: the kernel's extended driver
            run = topology.simulate_vehicle_extended(topo, pp[rows], ep[rows], extended.is_ext, mp[rows], x0[rows],
                                                     tm0[rows], dt, power, amb, f_rows,
                                                     stop_on_failure=stop_on_failure, record_at=rec_k)
        else:
            run = topology.simulate_vehicle(topo, pp[rows], mp[rows], x0[rows], tm0[rows], dt, power, amb, f_rows,
                                            stop_on_failure=stop_on_failure, record_at=rec_k)
        out = {"fail_step": run.fail_step, "fail_cause": run.fail_cause, "reached": run.pack_end_step >= 0,
               "k_cut": run.pack_end_step, "energy": run.pack_end_energy_j,
               "peak_pack": run.peak_pack_temp_to_failure, "peak_motor": run.peak_motor_temp_to_failure}
        if traj_k is not None:
            at = slice(None) if rec_k is traj_k else np.searchsorted(rec_k, traj_k)
            out.update(soc=run.pack_soc[:, at], pack_temp=run.pack_temp[:, at], motor_temp=run.motor_temp[:, at])
        if per_sample:
            out["end_soc"] = run.pack_soc[:, -1]  # rec_k ends at the load's last step
        return out

    parts = _map_chunks(fly, n_samples)
    run = {k: np.concatenate([part[k] for part in parts]) for k in parts[0]}
    failed = run["fail_step"] >= 0
    ttf = np.where(failed, t_end[np.maximum(run["fail_step"], 0)], np.inf)
    causes: dict = {}
    for c in run["fail_cause"][failed]:
        name = kernel.FAILURE_NAMES[int(c)]
        causes[name] = causes.get(name, 0) + 1
    pack_ttc = np.where(run["reached"], t_end[run["k_cut"]], np.inf)
    energy = run["energy"]
    peak_pack = np.maximum(run["peak_pack"], x0[..., kernel.S_T])
    peak_motor = np.maximum(run["peak_motor"], tm0)
    pred = Prediction(
        horizon_s=float(t_end[-1]) if t_end.size else 0.0,
        n_samples=n_samples,
        p_failure=float(failed.mean()),
        time_to_failure_s=nearest_quantiles(ttf[:, None])[0],
        failure_causes=causes,
        pack_time_to_cutoff_s=nearest_quantiles(pack_ttc),
        pack_energy_to_cutoff_j=nearest_quantiles(energy),
        peak_pack_temp_c=nearest_quantiles(peak_pack),
        peak_motor_temp_c=nearest_quantiles(peak_motor),
        pack_names=vehicle.pack_names, motor_names=vehicle.motor_names,
        **({} if not per_sample else {"sample_failure_time_s": ttf,
                                      "sample_failure_cause": np.where(failed, run["fail_cause"], kernel.FAIL_NONE),
                                      "sample_end_soc": run["end_soc"]}),
    )
    if trajectories:
        pred = Prediction(**{**pred.__dict__, "time_s": t_end[traj_k],
                             "soc_median": _median_over_samples(run["soc"]),
                             "pack_temp_median": _median_over_samples(run["pack_temp"]),
                             "motor_temp_median": _median_over_samples(run["motor_temp"])})
    return pred


@njit(cache=True, nogil=True)
def median_by_selection(x):
    """``np.median`` of a non-empty 1-D finite array, the same number, by selection (quickselect on
    a copy) instead of a sort: the middle order statistic, or the mean of the middle two. Written
    out rather than ``np.partition``, whose numba implementation costs ~12 s of CPU to compile
    (issue 33: a fresh install's first run)."""
    a = x.copy()
    n = a.size
    half = n // 2
    lo, hi = 0, n - 1
    while lo < hi:  # Hoare partition around the median of three until a[half] is in place
        mid = (lo + hi) // 2
        p = max(min(a[lo], a[mid]), min(max(a[lo], a[mid]), a[hi]))
        i, j = lo, hi
        while i <= j:
            while a[i] < p:
                i += 1
            while a[j] > p:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if half <= j:
            hi = j
        elif half >= i:
            lo = i
        else:
            break
    if n % 2:
        return a[half]
    lower = a[0]
    for k in range(1, half):  # everything before a[half] is <= it: the largest is the lower middle
        if a[k] > lower:
            lower = a[k]
    return (lower + a[half]) / 2.0


@njit(cache=True, nogil=True)
def _median_compiled(a, out):
    n_vec, m, c = a.shape
    col = np.empty(n_vec)
    for k in range(m):
        for i in range(c):
            n = 0
            for j in range(n_vec):
                if not math.isnan(a[j, k, i]):
                    col[n] = a[j, k, i]
                    n += 1
            if n == 0:
                out[k, i] = np.nan
                continue
            out[k, i] = median_by_selection(col[:n])


def _median_over_samples(a: np.ndarray) -> np.ndarray:
    """``np.nanmedian(a, axis=0)`` of (samples, steps, parts), the same numbers: NaN (a sample that
    stopped) left out, the mean of the middle two for an even count, NaN where every sample stopped.
    numpy's version loops over the (steps × parts) columns through masked arrays: tens of ms."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    out = np.empty(a.shape[1:])
    _median_compiled(a, out)
    return out


#: samples per thread below which one thread flies them all. A second thread shortens the wall
#: time but costs CPU of its own (its block's per-step overhead, the pool's hand-over, two cores
#: sharing one cache): at 100 samples one thread spent 13.9 ms of CPU on the paper packs against
#: 14.7 on two, and 22.2 against 24.3 on the extended packs (one process, load 2.1;
#: docs/notes/2026-11-27-extended-mc-4.md), so a 100-sample prediction flies on one thread
MIN_SAMPLES_PER_THREAD = 64


def _map_chunks(fly, n_samples: int) -> list[dict]:
    """``fly`` over the samples in contiguous chunks, one per thread available: every sample is
    independent, so the results are the one-call results."""
    n_threads = max(1, min(available_threads(), n_samples // MIN_SAMPLES_PER_THREAD))
    edges = np.linspace(0, n_samples, n_threads + 1).astype(int)
    return thread_map(fly, [slice(a, b) for a, b in zip(edges[:-1], edges[1:])])


def predict_from_estimator(estimator, load: FutureLoad, *, rng: np.random.Generator, n_samples: int = 100,
                           fault: np.ndarray | None = None, **kw) -> Prediction:
    """``predict`` from a ``StateEstimator``'s current state and its own (possibly adopted) parameters.

    The samples' SoC spread is the estimate's full one: the filter's covariance plus the capacity
    mismatch the estimator adds to ``Estimate.soc_sd`` (``EstimatorConfig.capacity_rel_sigma``),
    which the filter cannot see but which biases its SoC just the same; while a pack fails the
    estimator's model-consistency test, its covariance is scaled up by the test's statistic
    (``StateEstimator.prediction_inflation``)."""
    tm, tm_sd = estimator.motors.temperature()
    tm = np.where(np.isfinite(tm), tm, estimator.ambient_c)
    tm_sd = np.where(np.isfinite(tm_sd), tm_sd, 2.0)
    packs = estimator.packs
    cov = packs.cov.copy()
    soc = kernel.state_of_charge(packs.params, packs.mean)
    extra = estimator.config.capacity_rel_sigma * np.clip(1.0 - soc, 0.0, 1.0) * packs.params[:, kernel.I_CMAX]
    cov[:, kernel.S_QB, kernel.S_QB] += extra ** 2
    inflation = estimator.prediction_inflation()
    cov *= inflation[:, None, None]  # wider while a pack does not match its model
    # a self-calibrated pack flies its filter's learned model (``calibrated_pack``), not the kernel
    # pack; otherwise a parameter set's extended packs their extended filter. (A description whose
    # packs are of both kinds at once flies the calibrated ones' models and its others' kernel packs.)
    extended = CalibratedPacks.of(estimator) or ExtendedPacks.of(estimator, inflation)
    return predict((packs.params, estimator.motors.params), packs.mean, cov, tm, tm_sd, load, rng=rng,
                   n_samples=n_samples, fault=fault, vehicle=estimator.inputs, extended=extended, **kw)


@dataclass(frozen=True)
class PackCutoffPrediction:
    """Per pack (any number, the estimator's order): quantiles (5 %, 50 %, 95 %) of the time to its
    cut-off voltage (or empty) if it keeps drawing ``current_a``; ``inf`` = not within the horizon."""

    pack_names: tuple[str, ...]
    current_a: np.ndarray             # (N,)
    horizon_s: float
    n_samples: int
    time_to_cutoff_s: np.ndarray      # (N, 3)
    peak_temp_c: np.ndarray           # (N, 3)

    def to_dict(self) -> dict:
        def q(a):
            return [None if not math.isfinite(float(x)) else round(float(x), 3) for x in a]

        return {"horizon_s": self.horizon_s, "n_samples": self.n_samples, "quantiles": list(QUANTILES),
                "packs": {n: {"current_a": round(float(self.current_a[i]), 3),
                              "time_to_cutoff_s": q(self.time_to_cutoff_s[i]), "peak_temp_c": q(self.peak_temp_c[i])}
                          for i, n in enumerate(self.pack_names)}}


#: steps a row of ``predict_packs_at_current`` is simulated before it is checked for its cut-off
_CUTOFF_CHUNK_STEPS = 60
_VARIANT_CODE = {"paper": 0, "extended": 1}


@njit(cache=True, nogil=True)
def _held_current_to_cutoff_compiled(variant, params, state, dt, current, cutoff_v, ambient_c, max_dt, end_step,
                                     peak):
    """``_held_current_to_cutoff``'s chunks in one compiled call (the GIL released throughout):
    each chunk flies the rows still above their cut-off through the kernel's own driver
    (``kernel._simulate_packs`` / ``kernel._simulate_ext``, what ``kernel.simulate_packs`` calls)
    on the same inputs as the wrapper would build, so the same numbers."""
    n_steps = dt.size
    active = np.arange(params.shape[0])
    k0 = 0
    n_state = state.shape[1]
    while active.size > 0 and k0 < n_steps:
        m = min(_CUTOFF_CHUNK_STEPS, n_steps - k0)
        na = active.size
        p_a = params[active]
        x_a = state[active]
        dt_a = np.empty((1, m))
        for k in range(m):  # element loops, not slice assignments (their shape-mismatch message compiles slowly)
            dt_a[0, k] = dt[k0 + k]
        cur_a = np.empty((na, m))
        for r in range(na):
            cur_a[r, :] = current[active[r]]
        amb = np.full((1, m), ambient_c)
        voltage = np.empty((na, m))
        temperature = np.empty((na, m))
        soc = np.empty((na, m))
        states = np.empty((1, 1, n_state))
        final = np.empty((na, n_state))
        if variant == 0:
            kernel._simulate_packs(p_a, x_a, dt_a, cur_a, amb, max_dt, voltage, temperature, soc, states, False,
                                   final)
        else:
            t_meas = np.full((1, m), np.nan)
            kernel._simulate_ext(p_a, x_a, dt_a, cur_a, amb, t_meas, max_dt, voltage, temperature, soc, states,
                                 False, final)
        keep = np.ones(na, dtype=np.bool_)
        for r in range(na):
            row = active[r]
            top = -np.inf  # the peak up to and including the step that ends the row (NaN spreads, as np.max)
            for k in range(m):
                t = temperature[r, k]
                if math.isnan(t) or math.isnan(top):
                    top = np.nan
                elif t > top:
                    top = t
                if voltage[r, k] < cutoff_v[row] or soc[r, k] <= 0.0:
                    end_step[row] = k0 + k
                    keep[r] = False
                    break
            if math.isnan(top) or math.isnan(peak[row]):
                peak[row] = np.nan
            elif top > peak[row]:
                peak[row] = top
            for j in range(n_state):
                state[row, j] = final[r, j]
        active = active[keep]
        k0 += m


def _held_current_to_cutoff(params: np.ndarray, state: np.ndarray, dt: np.ndarray, current: np.ndarray,
                            cutoff_v: np.ndarray, ambient_c: float, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """Rows (packs × samples) at a held current until each one's cut-off: (first step below the
    cut-off or empty, -1 if none; peak temperature up to it). In chunks, each row only until its
    cut-off: past it nothing is read, so a row that ends early stops costing. A chunk continues
    from the previous one's final state: the same numbers as one call over the whole horizon."""
    n_params, n_state = ((kernel.N_PACK_PARAMS, kernel.N_PACK_STATE) if variant == "paper"
                         else (kernel.N_EXT_PARAMS, kernel.N_EXT_STATE))
    params = np.ascontiguousarray(params, dtype=np.float64).reshape(-1, n_params)
    state = np.array(state, dtype=np.float64).reshape(-1, n_state)
    if numba_config.DISABLE_JIT and variant == "paper" and held_current_arrays.applies(dt, kernel.DEFAULT_MAX_DT):
        # without the compiler (a first replay on a cold cache): every row at once, the same numbers
        return held_current_arrays.fly(params, state, dt, current, cutoff_v, ambient_c)
    end_step = np.full(params.shape[0], -1)
    peak = np.full(params.shape[0], -np.inf)
    _held_current_to_cutoff_compiled(_VARIANT_CODE[variant], params, state, np.ascontiguousarray(dt, dtype=np.float64),
                                     np.ascontiguousarray(current, dtype=np.float64),
                                     np.ascontiguousarray(cutoff_v, dtype=np.float64), float(ambient_c),
                                     float(kernel.DEFAULT_MAX_DT), end_step, peak)
    return end_step, peak


@dataclass(frozen=True)
class HeldCurrentInputs:
    """What ``predict_packs_at_current`` reads from an estimator, copied: the packs' parameters,
    state mean and the covariance a prediction starts from (capacity mismatch and model-mismatch
    inflation applied), the held current, the motor parameters (their draws are part of the
    rng's sequence), the ambient and the extended packs. The estimator moves on; these do not, so
    the prediction can run later or on another thread with the same numbers."""

    pack_names: tuple[str, ...]
    params: np.ndarray        # (P, 12)
    mean: np.ndarray          # (P, 4)
    cov: np.ndarray           # (P, 4, 4)
    current_a: np.ndarray     # (P,)
    cutoff_v: np.ndarray      # (P,)
    motor_params: np.ndarray  # (5,)
    ambient_c: float
    extended: ExtendedPacks | None
    #: per pack: its self-calibrating filter's model (``calibrated_cutoff``), whose time to cut-off
    #: replaces the kernel's flight; None: the kernel pack's own (a fitted or paper pack)
    calibrated: tuple[CutoffModel | None, ...] = ()


def held_current_inputs(estimator, cutoff_v: np.ndarray, current_a: np.ndarray | None = None) -> HeldCurrentInputs:
    """The estimator's present state as ``predict_packs_at_current`` reads it (copies)."""
    packs = estimator.packs
    base = np.array(packs.params, dtype=np.float64)
    n_packs = base.shape[0]
    cur = np.nan_to_num(np.array(estimator.pack_current if current_a is None else current_a, dtype=np.float64))
    calibrated = calibrated_models(estimator)
    if current_a is None:  # a calibrated pack holds its recent mean load
        cur = np.array([m.held_current(c) if m is not None else c for m, c in zip(calibrated, cur)])
    cov = np.array(packs.cov, dtype=np.float64)
    soc = kernel.state_of_charge(base, packs.mean)
    extra = estimator.config.capacity_rel_sigma * np.clip(1.0 - soc, 0.0, 1.0) * base[:, kernel.I_CMAX]
    cov[:, kernel.S_QB, kernel.S_QB] += extra ** 2
    inflation = estimator.prediction_inflation()
    cov *= inflation[:, None, None]  # wider while a pack does not match its model
    return HeldCurrentInputs(
        pack_names=tuple(estimator.pack_names), params=base, mean=np.array(packs.mean, dtype=np.float64), cov=cov,
        current_a=cur, cutoff_v=np.array(np.broadcast_to(np.asarray(cutoff_v, dtype=np.float64), (n_packs,))),
        motor_params=np.array(estimator.motors.params[0], dtype=np.float64), ambient_c=float(estimator.ambient_c),
        extended=ExtendedPacks.of(estimator, inflation), calibrated=calibrated)


def calibrated_models(estimator) -> tuple[CutoffModel | None, ...]:
    """Per pack of ``estimator``: its self-calibrating filter's model now, None where it has none."""
    calib = getattr(estimator, "calib", None) or [None] * len(estimator.pack_names)
    return tuple(CutoffModel.of(c) if c is not None else None for c in calib)


def calibrated_cutoff_quantiles(model: CutoffModel, current_a: float, cutoff_v: float, *, rng: np.random.Generator,
                                n_samples: int, horizon_s: float = 3600.0) -> np.ndarray:
    """(5 %, 50 %, 95 %) of a calibrated pack's time to cut-off at a held ``current_a`` (``inf``:
    not within the horizon) over ``n_samples`` draws of its filter's state: what the product shows
    for such a pack, and what the harness measures."""
    return np.quantile(_within(model.sample_times(current_a, cutoff_v, rng, n_samples), horizon_s), QUANTILES,
                       method="nearest")


def _within(times: np.ndarray, horizon_s: float) -> np.ndarray:
    """Times beyond the horizon (or undetermined) as ``inf``, as the kernel's flights report them."""
    return np.where(np.isfinite(times) & (times <= horizon_s), times, np.inf)


def with_calibrated_cutoffs(pred: "Prediction", estimator, *, rng: np.random.Generator,
                            n_samples: int) -> "Prediction":
    """``pred`` with each self-calibrated pack's time to cut-off its filter's own, at its recent mean
    load, to its description's cut-off (``calibrated_cutoff``): the per-pack count-down the service
    shows is one path whatever the airframe (a shaft-power flight of the kernel carries only the
    calibrated SoC)."""
    models = calibrated_models(estimator)
    if not any(m is not None for m in models):
        return pred
    cutoff_v = estimator.inputs.pack_cutoff_v  # only a description's packs self-calibrate
    per_pack = np.array(pred.pack_time_to_cutoff_s, dtype=np.float64, copy=True)
    present = np.nan_to_num(np.asarray(estimator.pack_current, dtype=np.float64))
    for b, m in enumerate(models):
        if m is not None:
            per_pack[b] = calibrated_cutoff_quantiles(m, m.held_current(present[b]), float(cutoff_v[b]), rng=rng,
                                                      n_samples=n_samples, horizon_s=pred.horizon_s)
    return replace(pred, pack_time_to_cutoff_s=per_pack)


def predict_packs_at_current(estimator, cutoff_v: np.ndarray, *, current_a: np.ndarray | None = None,
                             horizon_s: float = 3600.0, step_s: float = 5.0, rng: np.random.Generator,
                             n_samples: int = 100, param_rel_sigma: float = 0.08) -> PackCutoffPrediction:
    """Monte Carlo time to cut-off of every pack at a held current (the present draw by default):
    the current-driven counterpart of ``predict`` that needs no powertrain layout, so it serves any
    vehicle description. All samples × packs are rows of one ``kernel.simulate_packs`` call.
    ``held_current_inputs`` then ``predict_held_current``: a caller that predicts elsewhere (the
    replay's trace, on a worker thread) takes the inputs now and predicts later."""
    return predict_held_current(held_current_inputs(estimator, cutoff_v, current_a), horizon_s=horizon_s,
                                step_s=step_s, rng=rng, n_samples=n_samples, param_rel_sigma=param_rel_sigma)


def predict_held_current(inputs: HeldCurrentInputs, *, horizon_s: float = 3600.0, step_s: float = 5.0,
                         rng: np.random.Generator, n_samples: int = 100,
                         param_rel_sigma: float = 0.08) -> PackCutoffPrediction:
    """``predict_packs_at_current`` from inputs taken earlier (reads nothing else)."""
    samples = draw_held_current(inputs, horizon_s=horizon_s, step_s=step_s, rng=rng, n_samples=n_samples,
                                param_rel_sigma=param_rel_sigma)
    return samples.prediction(samples.fly())


@dataclass(frozen=True)
class HeldCurrentSamples:
    """A held-current Monte Carlo's drawn rows (samples × packs, sample-major), ready to fly.

    ``fly`` is the costly part and one compiled call per variant with the GIL released, so a
    caller may run it on another thread while its own thread goes on (the replay's trace);
    ``prediction`` turns its result into the quantiles."""

    inputs: HeldCurrentInputs
    n_samples: int
    dt: np.ndarray                  # (steps,)
    rows: tuple                     # per variant present: (variant, row indices, params, states)
    #: (samples, packs) time to cut-off of the calibrated packs on their own model (NaN columns:
    #: the kernel's flight), drawn with the rest
    calibrated_ttc: np.ndarray | None = None

    def fly(self) -> tuple[np.ndarray, np.ndarray]:
        """(first step below the cut-off or empty, -1 if none; peak temperature up to it) per row."""
        n_rows = self.n_samples * self.inputs.params.shape[0]
        end_step = np.full(n_rows, -1)
        peak = np.full(n_rows, -np.inf)
        rows_cur = np.tile(self.inputs.current_a, self.n_samples)
        row_cutoff = np.tile(self.inputs.cutoff_v, self.n_samples)
        for variant, sel, params, states in self.rows:
            end_step[sel], peak[sel] = _held_current_to_cutoff(params, states, self.dt, rows_cur[sel], row_cutoff[sel],
                                                               self.inputs.ambient_c, variant)
        return end_step, peak

    def prediction(self, flown: tuple[np.ndarray, np.ndarray]) -> PackCutoffPrediction:
        end_step, peak = flown
        n_packs = self.inputs.params.shape[0]
        t_end = np.cumsum(self.dt)
        ttc = np.where(end_step >= 0, t_end[end_step], np.inf).reshape(self.n_samples, n_packs)
        if self.calibrated_ttc is not None:
            own = np.array([m is not None for m in self.inputs.calibrated])
            ttc[:, own] = _within(self.calibrated_ttc[:, own], float(t_end[-1]))
        peak = peak.reshape(self.n_samples, n_packs)
        return PackCutoffPrediction(
            pack_names=self.inputs.pack_names, current_a=self.inputs.current_a, horizon_s=float(t_end[-1]),
            n_samples=self.n_samples, time_to_cutoff_s=nearest_quantiles(ttc), peak_temp_c=nearest_quantiles(peak))


def draw_held_current(inputs: HeldCurrentInputs, *, horizon_s: float = 3600.0, step_s: float = 5.0,
                      rng: np.random.Generator, n_samples: int = 100,
                      param_rel_sigma: float = 0.08) -> HeldCurrentSamples:
    """The Monte Carlo's draws of ``predict_packs_at_current`` (states and parameters; the extended
    packs' from their own filter), in the rng's order."""
    base, cov, extended = inputs.params, inputs.cov, inputs.extended
    n_packs = base.shape[0]
    pp, _ = sample_parameters((base, inputs.motor_params), n_samples, rng, param_rel_sigma)
    chol = np.linalg.cholesky(cov + 1e-9 * np.eye(cov.shape[-1]))
    x0 = inputs.mean[None] + np.einsum("bij,nbj->nbi", chol, rng.standard_normal((n_samples, n_packs, kernel.N_PACK_STATE)))
    x0 = restate(base, x0, pp)
    n_steps = max(1, int(math.ceil(horizon_s / step_s)))
    paper_rows = np.ones(n_samples * n_packs, dtype=bool)
    rows = []
    if extended is not None:  # those packs fly the extended variant from their own filter's draws
        xe, ep = extended.sample(x0, n_samples, rng, param_rel_sigma)
        paper_rows = ~np.tile(extended.is_ext, n_samples)
    sel = np.flatnonzero(paper_rows)
    rows.append(("paper", sel, pp.reshape(-1, kernel.N_PACK_PARAMS)[sel], x0.reshape(-1, kernel.N_PACK_STATE)[sel]))
    if extended is not None:
        sel = np.flatnonzero(~paper_rows)
        rows.append(("extended", sel, ep.reshape(-1, kernel.N_EXT_PARAMS)[sel], xe.reshape(-1, kernel.N_EXT_STATE)[sel]))
    calibrated_ttc = None
    if any(m is not None for m in inputs.calibrated):  # drawn after the kernel's: their draws stay as they were
        calibrated_ttc = np.full((n_samples, n_packs), np.nan)
        for b, m in enumerate(inputs.calibrated):
            if m is not None:
                calibrated_ttc[:, b] = m.sample_times(float(inputs.current_a[b]), float(inputs.cutoff_v[b]), rng,
                                                      n_samples)
    return HeldCurrentSamples(inputs, n_samples, np.full(n_steps, horizon_s / n_steps), tuple(rows), calibrated_ttc)
