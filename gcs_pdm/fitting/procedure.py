"""The paper's learning procedure (§IV) for one component, as a function a job runner can call.

``fit_battery(train, val, test, settings)`` for one pack and ``fit_motor(...)`` for the motor pair:

1. clean every flight (:mod:`gcs_pdm.fitting.cleaning`); rejected flights are reported, not dropped;
2. per stage — battery: *electrical* (R_s, R_p, R_cp0, R_cp1, R_cp2, C_s, C_b, C_cp on voltage),
   then *thermal* (C_t, h on pack temperature, with the learned circuit's R); motor: *thermal*
   (C_t, h, P_iron on the bracket temperature) — simulated annealing from ``starts`` random points inside
   the expected ranges, Levenberg–Marquardt from each annealing result, and the LM solution with the
   lowest validation error kept;
3. errors (RMSE, mean absolute, max; temperatures in °C and °F) per flight and overall for train,
   validation and test, for the learned set and for a reference set.

This module orchestrates: it owns a thread pool for the duration of a fit (the kernel releases the
GIL, so the annealing population and the LM restarts run on all cores) and measures the time taken.
The physics, the search and the cleaning are the pure modules it calls.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from gcs_pdm.fitting import problem as pb
from gcs_pdm.fitting.cleaning import CleaningReport, CleaningSettings, RejectedFlight, clean_flights
from gcs_pdm.fitting.errors import error_stats, pooled, with_fahrenheit
from gcs_pdm.fitting.search import (FitCancelled, SearchSettings, anneal, levenberg_marquardt,
                                   levenberg_marquardt_subset)
from gcs_pdm.fitting.agreement import AGREEMENT_FACTOR, AGREEMENT_TOLERANCE, agreement_report, near_best
from gcs_pdm.models.training_envelope import FlightConditions, envelope_report
from gcs_pdm.fitting.misfit import (MISFIT_PER_CELL_V, left_out_warning, misfit_warnings,
                                   training_segments_to_leave_out)
from gcs_pdm.fitting.support import SOC_SUPPORT_SPAN, StartReading, support_report
from gcs_pdm.logs.tables import BATTERY, MOTOR, Flight, FlightDataError
from gcs_pdm.models import kernel
from gcs_pdm.models.params import (PACK_NAMES, MotorParams, PackParams, ParameterSet, builtin, extended_default,
                                   motor_from_vector, pack_from_vector, pack_vector)

log = logging.getLogger(__name__)

Progress = Callable[[float, str], None]
ShouldStop = Callable[[], bool]
SPLITS = ("train", "validation", "test")
#: the variant of new fits (`FitSettings().model`, `gcs-pdm fit battery` with no --model)
DEFAULT_MODEL = "extended"


@dataclass(frozen=True)
class FitSettings:
    search: SearchSettings = SearchSettings()
    cleaning: CleaningSettings = CleaningSettings()
    #: set the fixed (not learned) values come from, and the initial point of nothing: starts are random
    base: str = "previous_si"
    #: set whose errors are reported beside the learned ones
    reference: str = "previous_si"
    init_samples: int = 10
    #: LM also learns a per-training-flight initial-SoC correction of up to this much (0: off); the
    #: first-samples estimate is noisy, and near the knee a 0.005 SoC error is a visible voltage error
    soc_offset_range: float = 0.05
    #: the same for the extended variant: off. Its initial SoC comes from the rest voltage through the
    #: learned OCV (a few mV of noise: < 0.001 SoC), and a free correction lets the OCV disagree with
    #: the rest voltages, which is exactly what a predicted flight starts from (docs/fitting.md)
    extended_soc_offset_range: float = 0.0
    #: weight of the extended variant's OCV smoothness prior (problem.ExtendedPackProblem; 0: off)
    ocv_smoothing: float = 0.0
    workers: int = 2
    #: model variant of a battery fit: "extended" (the default, for new fits: right on real cells,
    #: docs/model.md) or "paper" (eqs. 1-7, for reproducing the paper: pass model="paper")
    model: str = DEFAULT_MODEL
    #: open-circuit-voltage default (start of the search) when the base set has no extended values
    chemistry: str = "lipo"
    #: search of the extended variant: LM over its 41 electrical unknowns (not the annealing, which only
    #: sees the 14 resistance, time-constant, kinetic and capacity values) does most of the work, so
    #: fewer starts with a longer LM (its Jacobian simulates 16 vectors, not 42: the OCV knots' columns
    #: come from ExtendedPackProblem.ocv_jacobian); its 3-value thermal stage needs few generations
    extended_search: SearchSettings = SearchSettings(starts=4, sa_generations=60, lm_max_nfev=60)
    extended_thermal_generations: int = 10
    #: a further LM run of this many evaluations from the chosen electrical candidate (extended
    #: variant; kept if the validation error does not rise): the short runs screen the starts
    extended_polish_nfev: int = 60
    #: LM evaluations of the extended variant's OCV knots alone, the other values held at an annealed
    #: start's, before the joint LM from it: the annealing searched with the chemistry's default curve,
    #: and the knots are cheap to fit alone (their Jacobian needs no shifted simulation)
    extended_ocv_refit_nfev: int = 20
    #: validation chooses among the extended variant's candidates whose training RMSE is within this
    #: factor of the best one (0: among all). An LM run that stopped in a poor minimum (training 2-3x
    #: the best) is not a fit of the data, yet its validation error can be the lowest by chance when
    #: every candidate misses a validation flight near the cut-off (docs/fitting.md, per-seed table)
    extended_train_tolerance: float = 1.5
    #: a validation/test flight's initial SoC counts as supported when a training flight started within
    #: half this SoC span of it (gcs_pdm.fitting.support; reported, never used in a choice)
    soc_support_span: float = SOC_SUPPORT_SPAN
    #: candidate agreement (gcs_pdm.fitting.agreement; reported, never used in a choice): the electrical
    #: candidates within this factor of the best training RMSE are compared on each validation/test
    #: flight, and a flight is undetermined when they are more than ``agreement_factor`` times the
    #: chosen candidate's training RMSE apart
    agreement_tolerance: float = AGREEMENT_TOLERANCE
    agreement_factor: float = AGREEMENT_FACTOR
    #: a training flight the chosen set misses by more than this RMS per cell (V) is warned about
    #: (gcs_pdm.fitting.misfit; reported, never used in a choice)
    misfit_per_cell_v: float = MISFIT_PER_CELL_V
    #: repeat a battery fit without the training flights it cannot draw (misfit.flights_to_leave_out):
    #: one such flight otherwise holds most of the training error and spoils the fit of the others
    leave_out_misfits: bool = True

    def search_for(self, stage: str) -> SearchSettings:
        """Search settings of a battery stage ("electrical" | "thermal") of this fit's variant."""
        if self.model != "extended":
            return self.search
        if stage == "thermal":
            return dataclasses.replace(self.extended_search, sa_generations=self.extended_thermal_generations)
        return self.extended_search

    def to_dict(self) -> dict:
        return {"search": self.search.to_dict(), "base": self.base, "reference": self.reference,
                "model": self.model, "chemistry": self.chemistry, "extended_search": self.extended_search.to_dict(),
                "extended_thermal_generations": self.extended_thermal_generations,
                "extended_polish_nfev": self.extended_polish_nfev,
                "extended_ocv_refit_nfev": self.extended_ocv_refit_nfev,
                "extended_train_tolerance": self.extended_train_tolerance,
                "soc_support_span": self.soc_support_span,
                "agreement_tolerance": self.agreement_tolerance, "agreement_factor": self.agreement_factor,
                "misfit_per_cell_v": self.misfit_per_cell_v, "leave_out_misfits": self.leave_out_misfits,
                "init_samples": self.init_samples, "soc_offset_range": self.soc_offset_range,
                "extended_soc_offset_range": self.extended_soc_offset_range, "ocv_smoothing": self.ocv_smoothing,
                "workers": self.workers,
                "cleaning": {k: v for k, v in self.cleaning.__dict__.items()}}


@dataclass
class Candidate:
    start: int
    sa_rmse: float
    lm_rmse: float
    val_rmse: float
    lm_nfev: int
    values: dict[str, float]
    #: a longer LM run from the chosen candidate (``polish_nfev``), kept if validation agrees
    polished: bool = False

    def to_dict(self) -> dict:
        return {"start": self.start, "sa_train_rmse": self.sa_rmse, "lm_train_rmse": self.lm_rmse,
                "validation_rmse": self.val_rmse, "lm_evaluations": self.lm_nfev, "parameters": self.values,
                "polished": self.polished}


@dataclass
class StageResult:
    name: str
    target: str
    free: tuple[str, ...]
    bounds: dict[str, tuple[float, float]]
    candidates: list[Candidate]
    chosen: int
    evaluations: int
    seconds: float
    #: training flights' initial SoC with their LM corrections (stages that learn them)
    train_initial_soc: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"stage": self.name, "target": self.target, "free": list(self.free),
                "train_initial_soc": dict(self.train_initial_soc),
                "bounds": {k: list(v) for k, v in self.bounds.items()}, "chosen": self.chosen,
                "evaluations": self.evaluations, "seconds": self.seconds,
                "candidates": [c.to_dict() for c in self.candidates]}


@dataclass
class FlightPrediction:
    """Measured and predicted traces of one flight (for predictions/<flight>.csv and the plots)."""

    name: str
    split: str
    time_s: np.ndarray
    measured_voltage: np.ndarray | None
    predicted_voltage: np.ndarray | None
    measured_temperature: np.ndarray
    predicted_temperature: np.ndarray
    reference_voltage: np.ndarray | None
    reference_temperature: np.ndarray
    initial_soc: float | None
    #: model variants of the learned and the reference predictions (the plots name them)
    model: str = "paper"
    reference_model: str = "paper"


@dataclass
class FitResult:
    component: str                       # "battery" | "motor"
    pack: str | None
    parameters: dict[str, float]         # every kernel parameter of the component, learned or fixed
    learned: tuple[str, ...]
    reference: str
    errors: dict[str, Any]               # {"learned"|"reference": {split: {"overall": …, "flights": […]}}}
    stages: list[StageResult]
    cleaning: list[CleaningReport]
    rejected: list[RejectedFlight]
    flights: dict[str, list[str]]        # split -> flight (segment) names used
    settings: FitSettings
    seconds: float
    predictions: list[FlightPrediction] = field(default_factory=list, repr=False)
    #: model variant of a battery fit ("paper" | "extended"); None for the motor
    model: str | None = None
    #: the base set's pack (an extended fit keeps its paper values for the paper-layout users)
    base_pack: PackParams | None = None
    #: {"fitted": bool, "reason": str} of the thermal stage
    thermal: dict[str, Any] = field(default_factory=lambda: {"fitted": True, "reason": ""})
    #: battery: how well the training flights' starts support each validation/test flight's initial
    #: SoC (gcs_pdm.fitting.support); None for the motor
    initial_soc_support: dict[str, Any] | None = None
    #: battery: whether each validation/test flight stays inside the training flights' temperatures and
    #: currents (gcs_pdm.models.training_envelope); None for the motor
    operating_envelope: dict[str, Any] | None = None
    #: battery: whether the near-best electrical candidates agree on each validation/test flight
    #: (gcs_pdm.fitting.agreement); None for the motor
    candidate_agreement: dict[str, Any] | None = None
    #: battery: training flights (segments) a first fit could not draw and the final fit was repeated
    #: without: [{"flight", "first_fit_rmse_v", "final_rmse_v"}] (gcs_pdm.fitting.misfit)
    left_out: list[dict[str, Any]] = field(default_factory=list)
    #: things the user should know about this result (printed by the CLI), e.g. poorly supported starts
    warnings: list[str] = field(default_factory=list)

    @property
    def pack_params(self) -> PackParams | None:
        if self.component != BATTERY:
            return None
        if self.model == "extended":
            base = self.base_pack if self.base_pack is not None else builtin(self.settings.base).packs[PACK_NAMES[0]]
            return dataclasses.replace(base, model="extended",
                                       extended={k: float(self.parameters[k]) for k in kernel.EXT_PACK_PARAMS})
        return pack_from_vector(np.array([self.parameters[k] for k in kernel.PACK_PARAMS]))

    @property
    def motor_params(self) -> MotorParams | None:
        if self.component != MOTOR:
            return None
        return motor_from_vector(np.array([self.parameters[k] for k in kernel.MOTOR_PARAMS]))

    def to_dict(self) -> dict:
        """The ``result.json`` document (docs/fitting.md describes every field); strict JSON: an
        error that could not be computed (no samples) is null, never NaN."""
        return _json_safe({
            "format": "gcs-pdm-fit/1",
            "component": self.component,
            "pack": self.pack,
            "model": self.model,
            "thermal": dict(self.thermal),
            "parameters": dict(self.parameters),
            "learned": list(self.learned),
            "reference": self.reference,
            "errors": self.errors,
            "stages": [s.to_dict() for s in self.stages],
            "flights": self.flights,
            "initial_soc": {p.name: p.initial_soc for p in self.predictions if p.initial_soc is not None},
            "initial_soc_support": self.initial_soc_support,
            "operating_envelope": self.operating_envelope,
            "candidate_agreement": self.candidate_agreement,
            "left_out": [dict(x) for x in self.left_out],
            "warnings": list(self.warnings),
            "cleaning": [r.to_dict() for r in self.cleaning],
            "rejected": [r.to_dict() for r in self.rejected],
            "provenance": {"settings": self.settings.to_dict(), "seed": self.settings.search.seed,
                           "seconds": self.seconds, "method": "SA x starts -> LM each -> lowest validation error"},
        })


def _json_safe(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


# ---- helpers ---------------------------------------------------------------------------------------

def _clean_splits(splits: Mapping[str, Sequence[Flight]], kind: str, settings: CleaningSettings,
                  ) -> tuple[dict[str, list[Flight]], list[CleaningReport], list[RejectedFlight]]:
    out: dict[str, list[Flight]] = {}
    reports: list[CleaningReport] = []
    rejected: list[RejectedFlight] = []
    for split, flights in splits.items():
        wrong = [f.name for f in flights if f.kind != kind]
        if wrong:
            raise FlightDataError(f"{split}: expected {kind} flights, got other kinds: {', '.join(wrong)}")
        usable, reps, rej = clean_flights(list(flights), settings)
        reports += reps
        rejected += rej
        if not usable:
            reasons = "; ".join(f"{r.name}: {r.reason}" for r in rej) or "no flights given"
            raise FlightDataError(f"{split}: no usable flight ({reasons})")
        out[split] = usable
    return out, reports, rejected


class _Stepper:
    """Maps stage-local progress onto the whole fit's [0, 1] and checks for cancellation."""

    def __init__(self, progress: Progress | None, should_stop: ShouldStop | None):
        self.progress = progress
        self.should_stop = should_stop

    def report(self, fraction: float, stage: str) -> None:
        if self.progress is not None:
            self.progress(min(max(fraction, 0.0), 1.0), stage)

    def check(self) -> None:
        if self.should_stop is not None and self.should_stop():
            raise FitCancelled("fit cancelled")


def _run_stage(name: str, make: Callable[[Sequence[Flight], int], pb._Problem], train: Sequence[Flight],
               val: Sequence[Flight], search: SearchSettings, pool: ThreadPoolExecutor, workers: int,
               stepper: _Stepper, span: tuple[float, float], seed_offset: int,
               make_sa: Callable[[Sequence[Flight], int], pb._Problem] | None = None, polish_nfev: int = 0,
               ocv_refit_nfev: int = 0, train_tolerance: float = 0.0) -> tuple[np.ndarray, StageResult, pb._Problem]:
    """SA from random starts, LM from each SA result, the LM result with the lowest validation error.

    ``make_sa`` (optional) builds a problem over a subset of the free parameters for the annealing;
    LM then starts from each annealed point with the other parameters at the base values (the
    extended variant anneals its resistances and time constants with the default OCV curve, and
    lets LM, which is good at the nearly linear OCV knots, learn the curve: first the knots alone for
    ``ocv_refit_nfev`` evaluations, then everything). ``train_tolerance`` > 0: validation chooses only
    among the candidates whose training MSE is within that factor (in RMSE) of the best one."""
    t0 = time.perf_counter()
    prob = make(train, workers, True)
    vprob = make(val, 1, False)
    a, b = span
    sa_end = a + 0.65 * (b - a)
    rng = np.random.default_rng([search.seed, seed_offset])
    label = f"{name}: annealing"
    sa_prob = make_sa(train, workers) if make_sa is not None else prob
    # the extended variant's OCV knots: Jacobian columns from two simulations per flight, not one each
    own = getattr(prob, "ocv_columns", np.zeros(0, dtype=int))
    partial = (own, prob.ocv_jacobian) if own.size else None

    def fit_knots(u: np.ndarray, nfev: int):
        # the curve alone for the other values held (cheap: no shifted vector is simulated)
        if not own.size or nfev <= 0:
            return None
        return levenberg_marquardt_subset(lambda U: prob.residuals(U, parallel=False), u, own,
                                          dataclasses.replace(search, lm_max_nfev=nfev), partial=prob.ocv_jacobian)

    ann = anneal(sa_prob.mse, sa_prob.space.dim, search, rng,
                 progress=lambda f: stepper.report(a + f * (sa_end - a), label), should_stop=stepper.should_stop)
    if make_sa is not None:
        base_values = np.array([prob.base[kernel.EXT_PACK_PARAMS.index(n)] for n in prob.space.names])
        full = np.tile(base_values, (ann.best_u.shape[0], 1))
        sa_values = sa_prob.space.to_values(ann.best_u)
        for j, n in enumerate(sa_prob.space.names):
            full[:, prob.space.names.index(n)] = sa_values[:, j]
        ann.best_u = np.clip(prob.space.to_unit(full), 0.0, 1.0)
    stepper.check()
    stepper.report(sa_end, f"{name}: Levenberg-Marquardt")

    d, n_extra = prob.space.dim, prob.n_extra

    canonical = getattr(prob, "canonical", None)
    per_jacobian = d - own.size + (n_extra > 0) + (2 if own.size else 0)  # simulated vectors per Jacobian
    blocks = prob.row_slices if n_extra else None

    def lm(u0: np.ndarray):
        stepper.check()
        # per-flight unknowns (initial-SoC corrections) start at "none" and join the LM only
        start = np.concatenate([u0, np.full(n_extra, 0.5)])
        knots = fit_knots(start, ocv_refit_nfev)
        res = levenberg_marquardt(lambda U: prob.residuals(U, parallel=False),
                                  start if knots is None else knots.u, search, shared=d, blocks=blocks, partial=partial)
        if knots is not None:
            res.nfev += knots.nfev + 2 * knots.njev
        swapped = canonical(res.u[:d]) if canonical is not None else None
        if swapped is not None:
            # the two R-C pairs of the circuit are interchangeable on the plateau: a solution with the
            # slow pair labelled R_s-C_s is relabelled and refined; kept unless clearly worse
            alt = levenberg_marquardt(lambda U: prob.residuals(U, parallel=False),
                                      np.concatenate([swapped, res.u[d:]]), search,
                                      shared=d, blocks=blocks, partial=partial)
            alt.nfev += res.nfev
            alt.njev += res.njev
            if alt.mse <= 1.01 * res.mse:
                return alt
            res.nfev, res.njev = alt.nfev, alt.njev
        return res

    done = 0
    lm_results = []
    for r in pool.map(lm, list(ann.best_u)):
        lm_results.append(r)
        done += 1
        stepper.report(sa_end + (b - sa_end) * done / len(ann.best_u), f"{name}: Levenberg-Marquardt {done}/{len(ann.best_u)}")
    stepper.check()
    U_full = np.array([r.u for r in lm_results])
    U = U_full[:, :d]
    val_mse = vprob.mse(U, parallel=False)
    values = prob.space.to_values(U)
    candidates = [Candidate(start=i, sa_rmse=float(np.sqrt(ann.best_mse[i])), lm_rmse=float(np.sqrt(r.mse)),
                            val_rmse=float(np.sqrt(val_mse[i])), lm_nfev=r.nfev + r.njev * per_jacobian,
                            values={n: float(v) for n, v in zip(prob.space.names, values[i])})
                  for i, r in enumerate(lm_results)]
    chosen = _choose(np.array([r.mse for r in lm_results]), val_mse, train_tolerance)
    if polish_nfev > 0:
        # the short LM runs screen the starts; the chosen one is refined further (both cores on its
        # Jacobian) and the refinement kept only if the validation flights agree it is better
        stepper.check()
        more = levenberg_marquardt(lambda U_: prob.residuals(U_, parallel=True), U_full[chosen],
                                   dataclasses.replace(search, lm_max_nfev=polish_nfev),
                                   shared=d, blocks=blocks, partial=partial)
        v_more = float(vprob.mse(more.u[None, :d], parallel=False)[0])
        if v_more <= val_mse[chosen]:
            candidates.append(Candidate(start=candidates[chosen].start, sa_rmse=candidates[chosen].sa_rmse,
                                        lm_rmse=float(np.sqrt(more.mse)), val_rmse=float(np.sqrt(v_more)),
                                        lm_nfev=more.nfev + more.njev * per_jacobian,
                                        values={n: float(v) for n, v in
                                                zip(prob.space.names, prob.space.to_values(more.u[:d]))},
                                        polished=True))
            U_full = np.vstack([U_full, more.u[None]])
            U = U_full[:, :d]
            chosen = len(candidates) - 1
        else:
            candidates[chosen].lm_nfev += more.nfev + more.njev * per_jacobian
    evaluations = ann.evaluations + sum(c.lm_nfev for c in candidates) + len(candidates)
    stage = StageResult(name=name, target=getattr(prob, "target", "temperature"), free=prob.space.names,
                        bounds={bd.name: (bd.lo, bd.hi) for bd in prob.space.bounds}, candidates=candidates,
                        chosen=chosen, evaluations=int(evaluations), seconds=time.perf_counter() - t0,
                        train_initial_soc=({f.name: v for f, v in zip(prob.flights, prob.initial_soc(U_full[chosen]))}
                                           if n_extra else {}))
    log.info("%s: chose start %d, train RMSE %.4g, validation RMSE %.4g (%d evaluations, %.1f s)", name, chosen,
             candidates[chosen].lm_rmse, candidates[chosen].val_rmse, evaluations, stage.seconds)
    return U[chosen], stage, prob


def _choose(train_mse: np.ndarray, val_mse: np.ndarray, train_tolerance: float) -> int:
    """Index of the candidate with the lowest validation MSE, among those whose training RMSE is within
    ``train_tolerance`` times the best (all of them if ``train_tolerance`` is 0)."""
    val = np.asarray(val_mse, dtype=np.float64)
    if train_tolerance > 0:
        fits = np.asarray(train_mse) <= train_tolerance ** 2 * np.min(train_mse)
        val = np.where(fits, val, np.inf)
    return int(np.argmin(val))


def _split_errors(pairs: dict[str, list[tuple[str, dict[str, tuple[np.ndarray, np.ndarray]]]]]) -> dict:
    """pairs[split] = [(flight, {"voltage": (pred, meas), "temperature": (pred, meas)})]"""
    out = {}
    for split, flights in pairs.items():
        per = []
        quantities = sorted({q for _, d in flights for q in d})
        for name, d in flights:
            entry: dict[str, Any] = {"flight": name}
            for q, (p, m) in d.items():
                st = error_stats(p, m)
                entry[q] = with_fahrenheit(st) if q == "temperature" else st
            per.append(entry)
        overall = {}
        for q in quantities:
            st = pooled([d[q] for _, d in flights if q in d])
            overall[q] = with_fahrenheit(st) | {"mean_flight_rmse_f": st["mean_flight_rmse"] * 1.8,
                                                "mean_flight_mae_f": st["mean_flight_mae"] * 1.8} \
                if q == "temperature" else st
        out[split] = {"overall": overall, "flights": per}
    return out


# ---- battery -----------------------------------------------------------------------------------------

def _pack_traces(vec: np.ndarray, prepared: Sequence[pb.Prepared], model: str = "paper",
                 ) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(voltage, temperature, initial SoC) per prepared flight (``problem.prepare``) for one full pack
    vector of variant ``model`` (a prediction: the model's own temperature drives the extended
    variant's resistances)."""
    out = []
    for pv in prepared:
        P = vec[None]
        if model == "extended":
            soc = kernel.extended_rest_soc(P, pv.init_voltage, pv.init_current, pv.init_temperature)
            x0 = kernel.initial_extended_state(P, soc, pv.init_temperature, pv.init_current)
        else:
            soc = pb.initial_soc(P, pv.init_voltage, pv.init_current)
            x0 = kernel.initial_pack_state(P, soc, pv.init_temperature, pv.init_current)
        tr = kernel.simulate_packs(P, x0, pv.dt, pv.current, pv.ambient, variant=model)
        out.append((tr.voltage[0], tr.temperature[0], float(soc[0])))
    return out


def fit_battery(train: Sequence[Flight], val: Sequence[Flight], test: Sequence[Flight],
                settings: FitSettings = FitSettings(), *, pack: str | None = None,
                progress: Progress | None = None, should_stop: ShouldStop | None = None,
                base_set: ParameterSet | None = None, pack_format: pb.PackFormat | None = None) -> FitResult:
    """Learn one pack's circuit and thermal parameters from its flights (the paper's procedure).

    The values not learned come from ``base_set`` if given (any set, e.g. a user's or a vehicle's,
    whose packs may have any names), else from the built-in ``settings.base``. ``pack_format`` (a
    pack other than the paper's 5S 7.8 Ah) scales the search ranges and the reference pack to it.

    With ``settings.leave_out_misfits``, a fit that misses some training flights far beyond the
    others (``misfit.flights_to_leave_out``) is repeated without them, and the result says which and
    by how much the final set misses them (``FitResult.left_out``, a warning each)."""
    fmt = pack_format or pb.PAPER_PACK
    kw = dict(pack=pack, should_stop=should_stop, base_set=base_set, pack_format=pack_format)
    if not settings.leave_out_misfits:
        return _fit_battery_once(train, val, test, settings, progress=progress, **kw)
    first = _fit_battery_once(train, val, test, settings, progress=_progress_span(progress, 0.0, 0.55, "checked"),
                              **kw)
    train_rmse = {e["flight"]: e["voltage"]["rmse"] for e in first.errors["learned"]["train"]["flights"]}
    # cleaning may have cut a log into segments: a flagged segment's log leaves whole
    log_of = {seg: rep.name for rep in first.cleaning for seg in rep.segments if seg in train_rmse}
    leave = training_segments_to_leave_out(train_rmse, log_of, fmt.cells, settings.misfit_per_cell_v)
    logs_out = {log_of.get(n, n) for n in leave}
    kept = [f for f in train if f.name not in logs_out]
    if not leave or not kept:
        if progress is not None:
            progress(1.0, "done")
        return first
    log.info("battery fit: repeated without %s (missed by %s)", ", ".join(sorted(logs_out)),
             ", ".join(f"{train_rmse[n] * 1000:.0f} mV" for n in leave))
    final = _fit_battery_once(kept, val, test, settings, progress=_progress_span(progress, 0.55, 1.0), **kw)
    names = kernel.EXT_PACK_PARAMS if final.model == "extended" else kernel.PACK_PARAMS
    vector = np.array([final.parameters[k] for k in names])
    again = {e["flight"]: e["voltage"]["rmse"] for e in
             evaluate_battery(vector, [f for f in train if f.name in logs_out], settings, final.model)["flights"]}
    final.left_out = [{"flight": n, "log": log_of.get(n, n), "first_fit_rmse_v": train_rmse[n],
                       "final_rmse_v": again.get(n)} for n in leave]
    # the left-out logs' cleaning stays on record
    final.cleaning = [r for r in first.cleaning if r.name in logs_out] + final.cleaning
    final.warnings = [left_out_warning(x["flight"], x["first_fit_rmse_v"], x["final_rmse_v"])
                      for x in final.left_out] + final.warnings
    final.seconds += first.seconds
    return final


def _progress_span(progress: Progress | None, a: float, b: float, done: str = "done") -> Progress | None:
    """``progress`` for one pass of a fit that runs in [a, b] of the whole; the pass's own "done" reads
    ``done`` (a first pass is not the end of the fit)."""
    if progress is None:
        return None
    return lambda fraction, stage: progress(a + (b - a) * fraction, done if stage == "done" else stage)


def _fit_battery_once(train: Sequence[Flight], val: Sequence[Flight], test: Sequence[Flight],
                      settings: FitSettings, *, pack: str | None, progress: Progress | None,
                      should_stop: ShouldStop | None, base_set: ParameterSet | None,
                      pack_format: pb.PackFormat | None) -> FitResult:
    """One pass of ``fit_battery`` on the given training flights."""
    t_start = time.perf_counter()
    stepper = _Stepper(progress, should_stop)
    stepper.report(0.0, "cleaning")
    splits, reports, rejected = _clean_splits({"train": train, "validation": val, "test": test}, BATTERY, settings.cleaning)
    base_set = base_set if base_set is not None else builtin(settings.base)
    ref_set = builtin(settings.reference)
    pack_name = pack if pack in base_set.packs else next(iter(base_set.packs))
    base_pack = base_set.packs[pack_name]
    fmt = pack_format or pb.PAPER_PACK
    ref_vec = pb.reference_vector(ref_set, pack_name, fmt)
    s = settings
    if s.model not in kernel.MODEL_VARIANTS:
        raise ValueError(f"model: expected one of {', '.join(kernel.MODEL_VARIANTS)}, got {s.model!r}")
    extended = s.model == "extended"
    if extended:
        base_vec = (base_pack.extended_vector() if base_pack.extended is not None
                    else np.array(list(extended_default(s.chemistry).values())))
        problem_cls = pb.ExtendedPackProblem
    else:
        base_vec = pack_vector(base_pack)
        problem_cls = pb.PackProblem
    bounds = pb.battery_bounds(s.model, fmt)
    el_bounds, th_bounds = bounds.electrical, bounds.thermal
    # a pack without temperature samples in training or validation still gets its circuit learned
    no_temp = [f.name for sp in ("train", "validation") for f in splits[sp] if not np.isfinite(f.temperature_c).any()]
    thermal = {"fitted": not no_temp,
               "reason": "" if not no_temp else f"no pack temperature in {', '.join(no_temp)}: thermal values "
                                                f"are the base set's, not learned"}
    stepper.report(0.02, "electrical: annealing")
    with ThreadPoolExecutor(max_workers=max(1, s.workers)) as pool:
        def make_el(flights, workers, training):
            extra = {"ocv_smoothing": s.ocv_smoothing if training else 0.0} if extended else {}
            return problem_cls(flights, base_vec, el_bounds, "voltage", init_samples=s.init_samples,
                               mapper=pool.map, workers=workers,
                               soc_offset_range=(s.extended_soc_offset_range if extended else s.soc_offset_range)
                               if training else 0.0, **extra)

        def make_el_sa(flights, workers):
            return problem_cls(flights, base_vec, bounds.annealing, "voltage", init_samples=s.init_samples,
                               mapper=pool.map, workers=workers)
        u_el, st_el, prob_el = _run_stage("electrical", make_el, splits["train"], splits["validation"],
                                          s.search_for("electrical"), pool,
                                          s.workers, stepper, (0.02, 0.55), 1, make_sa=make_el_sa if extended else None,
                                          polish_nfev=s.extended_polish_nfev if extended else 0,
                                          ocv_refit_nfev=s.extended_ocv_refit_nfev if extended else 0,
                                          train_tolerance=s.extended_train_tolerance if extended else 0.0)
        el_vec = prob_el.pack_vectors(prob_el.space.to_values(u_el))[0]
        stages = [st_el]
        final = el_vec
        if thermal["fitted"]:
            def make_th(flights, workers, training):
                return problem_cls(flights, el_vec, th_bounds, "temperature", init_samples=s.init_samples,
                                   mapper=pool.map, workers=workers)
            u_th, st_th, prob_th = _run_stage("thermal", make_th, splits["train"], splits["validation"],
                                              s.search_for("thermal"), pool, s.workers, stepper, (0.55, 0.95), 2)
            final = prob_th.pack_vectors(prob_th.space.to_values(u_th))[0]
            stages.append(st_th)
        else:
            log.warning("battery fit: thermal part not fitted: %s", thermal["reason"])
    stepper.report(0.96, "errors")
    pairs_l: dict[str, list] = {}
    pairs_r: dict[str, list] = {}
    predictions: list[FlightPrediction] = []
    starts: list[StartReading] = []
    conditions: list[FlightConditions] = []
    # the near-best electrical candidates as full vectors (the chosen one's thermal values): the
    # training flights cannot tell them apart, so where they part on a flight it is undetermined
    names = kernel.EXT_PACK_PARAMS if extended else kernel.PACK_PARAMS
    siblings = near_best([c.lm_rmse for c in st_el.candidates], [c.start for c in st_el.candidates],
                         st_el.chosen, s.agreement_tolerance)
    # each sibling as its own problem built it (the paper variant's q_max and C_max follow its C_b), with
    # the chosen set's thermal values
    thermal_idx = [names.index(n) for st in stages[1:] for n in st.free]
    sibling_vectors = {}
    for c in siblings[1:]:
        vec = prob_el.pack_vectors(np.array([[st_el.candidates[c].values[n] for n in prob_el.space.names]]))[0]
        vec[thermal_idx] = final[thermal_idx]
        sibling_vectors[c] = vec
    agreement_flights: list[tuple[str, str]] = []
    agreement_voltages: dict[int, list[np.ndarray]] = {c: [] for c in siblings}
    for split in SPLITS:
        flights = splits[split]
        # once per flight: the learned and the reference traces and the start readings all use it
        prepared = [pb.prepare(f, "voltage", s.init_samples) for f in flights]
        learned = _pack_traces(final, prepared, s.model)
        for f, pv, (_, _, soc) in zip(flights, prepared, learned):
            starts.append(StartReading(f.name, split, pv.init_voltage, pv.init_current, soc, fmt.cells))
            conditions.append(FlightConditions.of(f.name, split, f.temperature_c, f.ambient_c, f.current_a,
                                                  f.time_s))
        refs = _pack_traces(ref_vec, prepared)
        if split != "train":
            agreement_flights += [(f.name, split) for f in flights]
            agreement_voltages[st_el.chosen] += [v for v, _, _ in learned]
            for c, vec in sibling_vectors.items():
                agreement_voltages[c] += [v for v, _, _ in _pack_traces(vec, prepared, s.model)]
        pairs_l[split] = [(f.name, {"voltage": (lv, f.voltage_v), "temperature": (lt, f.temperature_c)})
                          for f, (lv, lt, _) in zip(flights, learned)]
        pairs_r[split] = [(f.name, {"voltage": (rv, f.voltage_v), "temperature": (rt, f.temperature_c)})
                          for f, (rv, rt, _) in zip(flights, refs)]
        for f, (lv, lt, soc), (rv, rt, _) in zip(flights, learned, refs):
            predictions.append(FlightPrediction(f.name, split, f.time_s, f.voltage_v, lv, f.temperature_c, lt, rv, rt, soc,
                                                model=s.model))
    support, start_warnings = support_report(starts, s.soc_support_span)
    envelope, envelope_warnings = envelope_report(conditions)
    agreement, agreement_warnings = agreement_report(agreement_flights, agreement_voltages, st_el.chosen,
                                                     st_el.candidates[st_el.chosen].lm_rmse,
                                                     s.agreement_tolerance, s.agreement_factor)
    learned_errors = _split_errors(pairs_l)
    misfits = misfit_warnings(learned_errors["train"]["flights"], fmt.cells, s.misfit_per_cell_v)
    fit_warnings = misfits + start_warnings + envelope_warnings + agreement_warnings
    for w in fit_warnings:
        log.debug("battery fit: %s", w)  # the CLI prints result.warnings; at INFO they would print twice
    result = FitResult(
        component=BATTERY, pack=pack,
        parameters={k: float(v) for k, v in zip(names, final)},
        learned=sum((st.free for st in stages), ()), reference=settings.reference,
        errors={"learned": learned_errors, "reference": _split_errors(pairs_r)},
        stages=stages, cleaning=reports, rejected=rejected,
        flights={k: [f.name for f in v] for k, v in splits.items()}, settings=settings,
        seconds=time.perf_counter() - t_start, predictions=predictions, model=s.model, base_pack=base_pack,
        thermal=thermal, initial_soc_support=support, operating_envelope=envelope,
        candidate_agreement=agreement, warnings=fit_warnings)
    stepper.report(1.0, "done")
    return result


# ---- motor -----------------------------------------------------------------------------------------

def fit_motor(train: Sequence[Flight], val: Sequence[Flight], test: Sequence[Flight],
              settings: FitSettings = FitSettings(), *, progress: Progress | None = None,
              should_stop: ShouldStop | None = None, base_set: ParameterSet | None = None) -> FitResult:
    """Learn the motors' thermal parameters (C_t, h and the core loss P_iron) from the mean motor
    current and the bracket sensor; the other values from ``base_set`` (else ``settings.base``)."""
    t_start = time.perf_counter()
    stepper = _Stepper(progress, should_stop)
    stepper.report(0.0, "cleaning")
    splits, reports, rejected = _clean_splits({"train": train, "validation": val, "test": test}, MOTOR, settings.cleaning)
    s = settings
    base_vec = (base_set if base_set is not None else builtin(s.base)).motor_vector()
    ref_vec = builtin(s.reference).motor_vector()
    with ThreadPoolExecutor(max_workers=max(1, s.workers)) as pool:
        def make(flights, workers, training):
            return pb.MotorProblem(flights, base_vec, pb.MOTOR_THERMAL_BOUNDS, init_samples=s.init_samples,
                                   mapper=pool.map, workers=workers)
        u, st, prob = _run_stage("thermal", make, splits["train"], splits["validation"], s.search, pool, s.workers,
                                 stepper, (0.02, 0.95), 3)
        final = prob.motor_vectors(prob.space.to_values(u))[0]
    pairs_l: dict[str, list] = {}
    pairs_r: dict[str, list] = {}
    predictions: list[FlightPrediction] = []
    for split in SPLITS:
        for f in splits[split]:
            pr = pb.prepare(f, "temperature", s.init_samples)
            lt, rt = (kernel.simulate_motor_thermal(v[None], pr.init_temperature, pr.dt, pr.current, pr.ambient)[0]
                      for v in (final, ref_vec))
            pairs_l.setdefault(split, []).append((f.name, {"temperature": (lt, f.temperature_c)}))
            pairs_r.setdefault(split, []).append((f.name, {"temperature": (rt, f.temperature_c)}))
            predictions.append(FlightPrediction(f.name, split, f.time_s, None, None, f.temperature_c, lt, None, rt, None))
    result = FitResult(
        component=MOTOR, pack=None, parameters={k: float(v) for k, v in zip(kernel.MOTOR_PARAMS, final)},
        learned=st.free, reference=s.reference,
        errors={"learned": _split_errors(pairs_l), "reference": _split_errors(pairs_r)},
        stages=[st], cleaning=reports, rejected=rejected, flights={k: [f.name for f in v] for k, v in splits.items()},
        settings=s, seconds=time.perf_counter() - t_start, predictions=predictions)
    stepper.report(1.0, "done")
    return result


# ---- merging ---------------------------------------------------------------------------------------

def merge_results(base: ParameterSet, batteries: Mapping[str, FitResult], motor: FitResult | None = None, *,
                  name: str = "learned", description: str = "", provenance: Mapping[str, Any] | None = None,
                  ) -> ParameterSet:
    """A ParameterSet: ``base`` with each fitted pack (keyed by pack name) and the motor replaced."""
    ps = base
    prov: dict[str, Any] = {"base": base.name, "packs": {}, **(provenance or {})}
    for pack, res in batteries.items():
        if pack not in base.packs:
            raise ValueError(f"unknown pack {pack!r}; expected one of {', '.join(base.packs)}")
        if res.component != BATTERY:
            raise ValueError(f"{pack}: not a battery fit")
        ps = ps.with_pack(pack, res.pack_params)
        prov["packs"][pack] = _fit_provenance(res)
    if motor is not None:
        if motor.component != MOTOR:
            raise ValueError("motor: not a motor fit")
        ps = ps.replace(motor=motor.motor_params)
        prov["motor"] = _fit_provenance(motor)
    return ParameterSet(name=name, packs=ps.packs, motor=ps.motor,
                        description=description or f"learned from flight logs over {base.name}", provenance=prov)


def _fit_provenance(res: FitResult) -> dict:
    # the training envelope and the fit's warnings travel with the set: the service checks the vehicle
    # in flight against the conditions its packs were fitted on (service.fit_envelope)
    training = (res.operating_envelope or {}).get("training")
    return {"learned": list(res.learned), "flights": res.flights, "left_out": [dict(x) for x in res.left_out],
            **({"training_envelope": dict(training)} if training else {}), "warnings": list(res.warnings),
            "seed": res.settings.search.seed,
            "seconds": round(res.seconds, 2), "settings": res.settings.search.to_dict(),
            "test_errors": res.errors["learned"]["test"]["overall"],
            "reference_test_errors": res.errors["reference"]["test"]["overall"], "reference": res.reference}


# ---- evaluation of a given set ----------------------------------------------------------------------

def evaluate_battery(vector: np.ndarray, flights: Sequence[Flight], settings: FitSettings = FitSettings(),
                     model: str = "paper") -> dict:
    """Errors of one pack vector ((12,) paper or (N_EXT_PARAMS,) extended, per ``model``) on flights, cleaned and
    initialised exactly as in a fit (so the errors of the true parameters compare with a fit's)."""
    usable, _, _ = clean_flights(list(flights), settings.cleaning)
    traces = _pack_traces(np.asarray(vector, dtype=np.float64),
                          [pb.prepare(f, "voltage", settings.init_samples) for f in usable], model)
    return _split_errors({"eval": [(f.name, {"voltage": (v, f.voltage_v), "temperature": (t, f.temperature_c)})
                                   for f, (v, t, _) in zip(usable, traces)]})["eval"]


def evaluate_motor(vector: np.ndarray, flights: Sequence[Flight], settings: FitSettings = FitSettings()) -> dict:
    """Errors of one motor vector (5,) on motor flights, cleaned and initialised as in a fit."""
    usable, _, _ = clean_flights(list(flights), settings.cleaning)
    pairs = []
    for f in usable:
        pr = pb.prepare(f, "temperature", settings.init_samples)
        t = kernel.simulate_motor_thermal(np.asarray(vector, dtype=np.float64)[None], pr.init_temperature, pr.dt,
                                          pr.current, pr.ambient)[0]
        pairs.append((f.name, {"temperature": (t, f.temperature_c)}))
    return _split_errors({"eval": pairs})["eval"]
