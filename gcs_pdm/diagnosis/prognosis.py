"""Prognostic triggers: a limit predicted to be crossed before the mission ends, and observed
degradation rates deviating from the predicted ones (the paper's second re-evaluation trigger).

Both need the load of the rest of the mission (``FutureLoad`` — the planner's vehicle simulator
produces it for a route; the service sets it when a mission is uploaded). Without one they stay
silent, and ``PrognosisMonitor.skipped_no_mission`` counts the checks that could not run.

- Limit violation: every ``check_every_s`` the Monte Carlo prediction (one kernel call, state and
  parameter uncertainty, the diagnosed motor faults included) runs over the remaining mission; the
  fault is raised when the probability of a failure before the mission ends is at least
  ``p_raise`` at three checks in a row (after a ``warmup_s`` settling time), and cleared when it stays below ``p_clear``.
- Rate deviation: the median predicted SoC and temperature trajectories of a *baseline*
  prediction are compared with what the estimator observes since; a relative deviation of a
  pack's SoC drop beyond ``soc_rel`` (and ``soc_abs``), or a temperature rise off by more than
  ``temp_abs_c`` and ``temp_rel``, is a deviation. Once raised, the baseline is renewed (with the
  faults now known), so the fault clears when the new prediction is being followed again.

A check does not re-simulate what has not changed: the Monte Carlo is re-run only when
- there is no prediction yet, or the mission, the estimator's parameters (adopted pack
  degradation) or the diagnosed motor faults (by more than ``rerun_fault_change``) changed, or the
  estimator restarted;
- the rate deviation was raised (the baseline is renewed from a prediction made with the faults
  known now; a baseline renewed because it was followed starts from the latest prediction);
- the estimate has left the latest prediction's band: since that prediction, a pack's SoC (the
  filter's, so a voltage correction of the state counts too) or a pack's or motor's temperature
  has moved off the change its median trajectory predicted by more than ``band_sds`` of the
  estimate's sds at the time of the prediction (the samples' initial 5-95 % spread), and at least
  ``band_soc`` or ``band_temp_c``;
- the prediction is ``max_age_s`` old, or the elapsed time passed its trajectories' end;
- the limit fault is pending (its raise or clear condition holds but has not lasted long enough):
  the debouncer's "three checks in a row" then means three independent predictions, as before;
  or the latest p_failure is undecided (between ``p_clear`` and ``p_raise``), where the Monte
  Carlo's own sampling noise decides, so each check takes fresh draws as before.
Otherwise the check re-uses the latest prediction: the debouncers see its p_failure, and the limit
fault's evidence gives its times to failure from now (less its age) and ``prediction_age_s``.
``status()`` says how old the prediction is (``predicted_at_s``, ``age_s``), how many checks ran
the Monte Carlo or re-used it, and why the latest one ran. (The prediction keeps median
trajectories only, not their spread over time: the band uses the initial spread.)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gcs_pdm.diagnosis.debounce import DebounceConfig, Debouncer
from gcs_pdm.diagnosis.faults import DEGRADATION_RATE_DEVIATION, PREDICTED_LIMIT_VIOLATION, Fault
from gcs_pdm.estimation.prediction import FutureLoad, Prediction, predict_from_estimator
from gcs_pdm.models.powertrain import Limits


@dataclass(frozen=True)
class PrognosisConfig:
    check_every_s: float = 30.0
    #: no prognosis before the estimator has run this long: right after take-off its SoC still
    #: carries whatever the first voltage reading and the parameter set's errors made of it
    warmup_s: float = 120.0
    n_samples: int = 100
    p_raise: float = 0.5
    p_clear: float = 0.2
    limit_debounce: DebounceConfig = DebounceConfig(raise_after_s=60.0, clear_after_s=60.0)
    rate_window_s: float = 120.0
    soc_rel: float = 0.25
    soc_abs: float = 0.015
    temp_abs_c: float = 3.0
    temp_rel: float = 0.4
    rate_debounce: DebounceConfig = DebounceConfig(raise_after_s=30.0, clear_after_s=30.0)
    #: re-run the Monte Carlo at least this often (message time), s
    max_age_s: float = 600.0
    #: the band around the latest prediction's median trajectories that the estimate must stay in
    #: for the prediction to be re-used: SoC (absolute) and temperatures, °C
    band_soc: float = 0.02
    band_temp_c: float = 3.0
    #: and at least this many of the estimate's sds at the time of the prediction (its samples'
    #: initial spread; 1.645: their 5-95 % band)
    band_sds: float = 1.645
    #: a diagnosed motor fault magnitude changing by more than this re-runs the prediction
    rerun_fault_change: float = 0.02


class PrognosisMonitor:
    def __init__(self, limits: Limits | None = None, config: PrognosisConfig = PrognosisConfig(), seed: int = 0):
        #: one limit for every pack and motor (a scenario's); None: the vehicle's own per pack and motor
        self.limits = limits
        self.config = config
        self.rng = np.random.default_rng(seed)
        self.mission: FutureLoad | None = None
        self.mission_start_s = 0.0
        self._last_check = -math.inf
        self._limit = Debouncer(config.limit_debounce)
        self._rate = Debouncer(config.rate_debounce)
        self._baseline: tuple[float, Prediction, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.faults: dict[tuple[str, str], Fault] = {}
        self.latest_prediction: Prediction | None = None
        self.skipped_no_mission = 0
        self._ready_since = math.nan
        #: message time the latest prediction was made at, and how many checks ran / re-used one
        self.predicted_at_s = math.nan
        self.runs = 0
        self.reused = 0
        self.last_run_reason: str | None = None
        #: what the latest prediction was made from: the fault vector, the estimate (SoC and
        #: temperatures, their sds) and the rate check's snapshot, all at ``predicted_at_s``
        self._made_with: tuple | None = None
        self._stale: str | None = "first"   # why the next check must re-run, if it must

    def set_mission(self, load: FutureLoad, start_s: float) -> None:
        """The load of the mission from message time ``start_s`` on; resets the rate baseline."""
        self.mission, self.mission_start_s = load, float(start_s)
        self._baseline = None
        self._stale = "mission"

    def reset_baseline(self) -> None:
        """Forget the rate baseline (the estimator's parameters changed under it); the next check
        predicts afresh."""
        self._baseline = None
        self._stale = "parameters"

    def status(self, time_s: float) -> dict:
        """The latest prediction and how old it is at message time ``time_s`` (None: none yet)."""
        pred = self.latest_prediction
        return {"skipped_no_mission": self.skipped_no_mission,
                "latest": None if pred is None else pred.to_dict(),
                "predicted_at_s": None if pred is None else round(self.predicted_at_s, 3),
                "age_s": None if pred is None else round(time_s - self.predicted_at_s, 3),
                "runs": self.runs, "reused": self.reused, "last_run_reason": self.last_run_reason}

    def due(self, time_s: float) -> bool:
        """Whether ``check`` at ``time_s`` would run (the caller can skip building its inputs)."""
        return time_s - self._last_check >= self.config.check_every_s

    def check(self, time_s: float, estimator, fault_vector: np.ndarray) -> list[tuple[str, Fault]]:
        if not self.due(time_s):
            return []
        self._last_check = time_s
        if self.mission is None:
            self.skipped_no_mission += 1
            return []
        if not estimator.ready():
            if not math.isnan(self._ready_since):
                self._stale = "estimator restarted"
            self._ready_since = math.nan
            return []
        if math.isnan(self._ready_since):
            self._ready_since = time_s
        if time_s - self._ready_since < self.config.warmup_s:
            return []
        remaining = self.mission.after(time_s - self.mission_start_s)
        if remaining.dt.size == 0:
            return []
        fault_vector = np.asarray(fault_vector, dtype=np.float64)
        state = self._state(estimator)
        reason = self._rerun_reason(time_s, fault_vector, state[0])
        if reason is None:
            self.reused += 1
        else:
            self.latest_prediction = predict_from_estimator(
                estimator, remaining, rng=self.rng, n_samples=self.config.n_samples, fault=fault_vector,
                limits=self.limits, trajectories=True)
            self.predicted_at_s, self._stale = time_s, None
            self._made_with = (fault_vector.copy(), *state, self._snapshot(estimator))
            self.runs += 1
            self.last_run_reason = reason
        pred = self.latest_prediction
        events = self._limit_check(time_s, pred, remaining)
        events += self._rate_check(time_s, pred, estimator)
        return events

    # ---- whether to predict afresh -------------------------------------------------------------------
    @staticmethod
    def _state(estimator) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """The filter's SoC and the pack and motor temperatures (what the band is about), and their sds."""
        e = estimator.estimate(details=False)
        return ((e.soc.copy(), e.pack_temp_c.copy(), e.motor_temp_c.copy()),
                (e.soc_sd.copy(), e.pack_temp_sd.copy(), e.motor_temp_sd.copy()))

    def _rerun_reason(self, time_s: float, fault_vector: np.ndarray, state) -> str | None:
        """Why the latest prediction cannot be re-used at ``time_s`` (None: it can)."""
        cfg = self.config
        if self._stale is not None or self.latest_prediction is None or self._made_with is None:
            return self._stale or "first"
        if not math.isnan(self._limit.pending_since):
            # a limit fault waiting to be raised or cleared: its debouncer wants independent
            # predictions at each check, not the same one counted again
            return "limit pending"
        if cfg.p_clear <= self.latest_prediction.p_failure < cfg.p_raise:
            # undecided: near the thresholds the Monte Carlo's own noise matters, take fresh draws
            return "p_failure undecided"
        faults0, state0, sd0, _ = self._made_with
        if faults0.shape != fault_vector.shape or np.any(np.abs(fault_vector - faults0) > cfg.rerun_fault_change):
            return "faults"
        age = time_s - self.predicted_at_s
        if age >= cfg.max_age_s:
            return "age"
        pred = self.latest_prediction
        if pred.time_s is None or pred.time_s.size == 0 or age > pred.time_s[-1]:
            return "horizon"
        for now, then, sd, median, band in ((state[0], state0[0], sd0[0], pred.soc_median, cfg.band_soc),
                                            (state[1], state0[1], sd0[1], pred.pack_temp_median, cfg.band_temp_c),
                                            (state[2], state0[2], sd0[2], pred.motor_temp_median, cfg.band_temp_c)):
            # the change since the prediction against its median trajectory's change, interpolated;
            # the samples started spread by the estimate's sd, so a move within it is in the band
            predicted = np.array([np.interp(age, pred.time_s, median[:, i]) - median[0, i]
                                  for i in range(median.shape[1])])
            off = np.abs((now - then) - predicted) - np.maximum(cfg.band_sds * np.nan_to_num(sd), band)
            if np.any(off[np.isfinite(off)] > 0.0):
                return "out of band"
        return None

    # ---- limit violation -----------------------------------------------------------------------------
    def _limit_check(self, time_s: float, pred: Prediction, remaining: FutureLoad) -> list:
        cfg = self.config
        ev = self._limit.update(time_s, pred.p_failure >= cfg.p_raise, pred.p_failure < cfg.p_clear)
        key = (PREDICTED_LIMIT_VIOLATION, "vehicle")
        cause = max(pred.failure_causes, key=pred.failure_causes.get) if pred.failure_causes else None
        age = time_s - self.predicted_at_s
        # a re-used prediction's times to failure count from when it was made
        ttf, ttf05 = (float(x) - age for x in pred.time_to_failure_s[1::-1])
        evidence = {"p_failure": pred.p_failure, "likely_cause": cause,
                    "time_to_failure_s_median": None if not math.isfinite(ttf) else round(max(ttf, 0.0), 1),
                    "time_to_failure_s_q05": None if not math.isfinite(ttf05) else round(max(ttf05, 0.0), 1),
                    "remaining_mission_s": round(remaining.duration_s, 1),
                    "prediction_age_s": round(age, 1)}
        conf = abs(pred.p_failure - 0.5) * 2.0
        if ev == "raise":
            self.faults[key] = Fault(PREDICTED_LIMIT_VIOLATION, "vehicle", pred.p_failure, time_s, conf, evidence,
                                     updated_s=time_s)
            return [("raise", self.faults[key])]
        if ev == "clear":
            self.faults[key] = self.faults[key].with_(active=False, cleared_s=time_s, updated_s=time_s,
                                                      confidence=0.0, evidence=evidence)
            return [("clear", self.faults[key])]
        if self._limit.active:
            self.faults[key] = self.faults[key].with_(magnitude=pred.p_failure, confidence=conf, updated_s=time_s,
                                                      evidence=evidence)
        return []

    # ---- degradation-rate deviation -----------------------------------------------------------------
    def _snapshot(self, estimator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Observed SoC by counting the measured charge (the filter's SoC also moves when the voltage
        corrects it, which is calibration, not a degradation rate), and filtered temperatures."""
        e = estimator.estimate(details=False)
        soc_counted = 1.0 - estimator.charge_c / estimator.capacity_c()
        return soc_counted, e.pack_temp_c.copy(), e.motor_temp_c.copy()

    def _rate_check(self, time_s: float, pred: Prediction, estimator) -> list:
        cfg = self.config
        if self._baseline is None:
            # from the prediction, made now or re-used: then from when it was made
            self._baseline = (self.predicted_at_s, pred, *self._made_with[-1])
            return []
        t0, base, soc0, tp0, tm0 = self._baseline
        base_soc_start = base.soc_median[0]
        elapsed = time_s - t0
        if elapsed < cfg.rate_window_s or base.time_s is None or base.time_s.size == 0:
            return []
        k = int(np.clip(np.searchsorted(base.time_s, elapsed), 0, base.time_s.size - 1))
        soc, tp, tm = self._snapshot(estimator)
        # predicted changes: the baseline's median trajectory from its own start
        d_soc_pred = base.soc_median[k] - base_soc_start
        d_soc_obs = soc - soc0
        d_tp_pred, d_tp_obs = base.pack_temp_median[k] - base.pack_temp_median[0], tp - tp0
        d_tm_pred, d_tm_obs = base.motor_temp_median[k] - base.motor_temp_median[0], tm - tm0
        worst = (0.0, None, None)
        for names, obs, prd, rel_lim, abs_lim, what in (
                (estimator.pack_names, d_soc_obs, d_soc_pred, cfg.soc_rel, cfg.soc_abs, "soc"),
                (estimator.pack_names, d_tp_obs, d_tp_pred, cfg.temp_rel, cfg.temp_abs_c, "pack_temp"),
                (estimator.motor_names, d_tm_obs, d_tm_pred, cfg.temp_rel, cfg.temp_abs_c, "motor_temp")):
            for i, name in enumerate(names):
                if not (math.isfinite(obs[i]) and math.isfinite(prd[i])):
                    continue
                diff = obs[i] - prd[i]
                rel = diff / max(abs(prd[i]), abs_lim)
                if abs(diff) > abs_lim and abs(rel) > rel_lim and abs(rel) > abs(worst[0]):
                    worst = (float(rel), name, {"quantity": what, "observed_change": round(float(obs[i]), 4),
                                                "predicted_change": round(float(prd[i]), 4),
                                                "window_s": round(elapsed, 1)})
        ev = self._rate.update(time_s, worst[1] is not None, worst[1] is None)
        events = []
        comp = worst[1] or "vehicle"
        if ev == "raise":
            f = Fault(DEGRADATION_RATE_DEVIATION, "vehicle", worst[0], time_s, min(1.0, abs(worst[0])),
                      {"component": comp, **(worst[2] or {})}, updated_s=time_s)
            self.faults[(DEGRADATION_RATE_DEVIATION, "vehicle")] = f
            events.append(("raise", f))
            # the trigger has fired: predict afresh from here, with the faults known now
            self._baseline = None
            self._stale = "rate deviation"
        elif ev == "clear":
            key = (DEGRADATION_RATE_DEVIATION, "vehicle")
            self.faults[key] = self.faults[key].with_(active=False, cleared_s=time_s, updated_s=time_s, confidence=0.0)
            events.append(("clear", self.faults[key]))
        if worst[1] is None and elapsed >= 4 * cfg.rate_window_s:
            # keep the comparison local: renew a baseline that has been followed for a while
            # (from the latest prediction, at most ``max_age_s`` old)
            self._baseline = None
        return events
