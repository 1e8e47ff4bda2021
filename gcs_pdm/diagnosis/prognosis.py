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


class PrognosisMonitor:
    def __init__(self, limits: Limits = Limits(), config: PrognosisConfig = PrognosisConfig(), seed: int = 0):
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

    def set_mission(self, load: FutureLoad, start_s: float) -> None:
        """The load of the mission from message time ``start_s`` on; resets the rate baseline."""
        self.mission, self.mission_start_s = load, float(start_s)
        self._baseline = None

    def reset_baseline(self) -> None:
        """Forget the rate baseline (the estimator's parameters changed under it)."""
        self._baseline = None

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
            self._ready_since = math.nan
            return []
        if math.isnan(self._ready_since):
            self._ready_since = time_s
        if time_s - self._ready_since < self.config.warmup_s:
            return []
        remaining = self.mission.after(time_s - self.mission_start_s)
        if remaining.dt.size == 0:
            return []
        pred = predict_from_estimator(estimator, remaining, rng=self.rng, n_samples=self.config.n_samples,
                                      fault=fault_vector, limits=self.limits, trajectories=True)
        self.latest_prediction = pred
        events = self._limit_check(time_s, pred, remaining)
        events += self._rate_check(time_s, pred, estimator)
        return events

    # ---- limit violation -----------------------------------------------------------------------------
    def _limit_check(self, time_s: float, pred: Prediction, remaining: FutureLoad) -> list:
        cfg = self.config
        ev = self._limit.update(time_s, pred.p_failure >= cfg.p_raise, pred.p_failure < cfg.p_clear)
        key = (PREDICTED_LIMIT_VIOLATION, "vehicle")
        cause = max(pred.failure_causes, key=pred.failure_causes.get) if pred.failure_causes else None
        ttf = pred.time_to_failure_s[1]
        evidence = {"p_failure": pred.p_failure, "likely_cause": cause,
                    "time_to_failure_s_median": None if not math.isfinite(ttf) else round(float(ttf), 1),
                    "time_to_failure_s_q05": None if not math.isfinite(pred.time_to_failure_s[0])
                    else round(float(pred.time_to_failure_s[0]), 1),
                    "remaining_mission_s": round(remaining.duration_s, 1)}
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
        e = estimator.estimate()
        soc_counted = 1.0 - estimator.charge_c / estimator.capacity_c()
        return soc_counted, e.pack_temp_c.copy(), e.motor_temp_c.copy()

    def _rate_check(self, time_s: float, pred: Prediction, estimator) -> list:
        cfg = self.config
        if self._baseline is None:
            self._baseline = (time_s, pred, *self._snapshot(estimator))
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
        elif ev == "clear":
            key = (DEGRADATION_RATE_DEVIATION, "vehicle")
            self.faults[key] = self.faults[key].with_(active=False, cleared_s=time_s, updated_s=time_s, confidence=0.0)
            events.append(("clear", self.faults[key]))
        if worst[1] is None and elapsed >= 4 * cfg.rate_window_s:
            # keep the comparison local: renew a baseline that has been followed for a while
            self._baseline = None
        return events
