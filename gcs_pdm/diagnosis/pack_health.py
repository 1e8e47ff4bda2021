"""Pack degradation: a voltage residual that persists beyond noise, read as capacity loss or
resistance rise, with an estimate of each.

Every ``check_every_s`` of message time the pack's whole flight so far (cleaned current,
ambient) is re-simulated open loop by ``kernel.simulate_packs`` from the state the estimator
started it in, and the residual r = V_measured - V_model is regressed on

    r ≈ c0 - ΔR · i - κ · Q,     Q = charge drawn so far (C)

c0 absorbs an initial-SoC error, ΔR is the series resistance the parameter set misses (the
quasi-static drop of R_s + R_cp), and κ = 1/C_b' - 1/C_b the faster voltage fall of a smaller
bulk capacitance: capacity factor C_b'/C_b = 1 / (1 + κ C_b). Outliers (spikes) are dropped with
a MAD rule and the fit is repeated; samples near the knee (model SoC < ``min_soc``), where the
model's own R_cp error dominates, are left out. A fault needs the estimate beyond its threshold
at two checks in a row (debounce), and clears likewise.

Thresholds sit above what an uncalibrated parameter set alone produces (≈15 % per parameter for
the simulated vehicle); after the fitter has learned the real pack they can be tightened.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gcs_pdm.diagnosis.debounce import DebounceConfig, Debouncer
from gcs_pdm.diagnosis.faults import PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE, Fault
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES


@dataclass(frozen=True)
class PackHealthConfig:
    check_every_s: float = 60.0
    min_history_s: float = 300.0
    min_samples: int = 150
    min_soc: float = 0.12
    capacity_loss_raise: float = 0.22
    capacity_loss_clear: float = 0.15
    resistance_rise_raise: float = 0.6
    resistance_rise_clear: float = 0.4
    debounce: DebounceConfig = DebounceConfig(raise_after_s=60.0, clear_after_s=60.0)


@dataclass(frozen=True)
class PackHealthEstimate:
    pack: str
    n: int
    offset_v: float
    delta_r_ohm: float
    resistance_rise: float      # ΔR / (R_s + R_cp0)
    capacity_factor: float
    capacity_loss: float
    se_resistance_rise: float
    se_capacity_loss: float
    residual_rms_v: float


def fit_pack_residual(params: np.ndarray, x0: np.ndarray, t: np.ndarray, current: np.ndarray,
                      voltage: np.ndarray, ambient: np.ndarray, min_soc: float = 0.12) -> tuple | None:
    """(coefficients [c0, ΔR, κ], standard errors, residual rms, n used) or None if not enough data."""
    dt = np.diff(t, prepend=t[0])
    run = kernel.simulate_packs(params[None], x0[None], dt, current, ambient)
    r = voltage - run.voltage[0]
    q = np.cumsum(current * dt)
    use = np.isfinite(r) & (run.soc[0] >= min_soc)
    if use.sum() < 20 or np.ptp(current[use]) < 1.0:
        return None
    a = np.stack([np.ones(use.sum()), -current[use], -q[use]], axis=1)
    y = r[use]
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        res = y - a @ coef
        mad = 1.4826 * np.median(np.abs(res - np.median(res))) + 1e-6
        keep = np.abs(res) <= 4.0 * mad
        if keep.all():
            break
        a, y = a[keep], y[keep]
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    n = y.size
    sigma2 = float(res @ res) / max(n - 3, 1)
    cov = sigma2 * np.linalg.pinv(a.T @ a)
    # residuals of a model-mismatch are correlated over the R_cp–C_cp time constant and longer:
    # count one independent sample per 30 s rather than per frame
    span = float(t[-1] - t[0])
    inflate = math.sqrt(max(n / max(span / 30.0, 1.0), 1.0))
    se = np.sqrt(np.maximum(np.diag(cov), 0.0)) * inflate
    return coef, se, math.sqrt(float(res @ res) / n), n


class PackHealthMonitor:
    def __init__(self, pack_params: np.ndarray, config: PackHealthConfig = PackHealthConfig()):
        self.params = np.asarray(pack_params, dtype=np.float64)
        self.config = config
        self._x0: list[np.ndarray | None] = [None] * len(PACK_NAMES)
        self._buf: list[list[tuple[float, float, float, float]]] = [[] for _ in PACK_NAMES]
        self._last_check = -math.inf
        self._debounce = {(ty, n): Debouncer(config.debounce) for n in PACK_NAMES
                          for ty in (PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE)}
        self.faults: dict[tuple[str, str], Fault] = {}
        self.latest: dict[str, PackHealthEstimate] = {}

    def add(self, b: int, time_s: float, current_a: float, voltage_v: float, ambient_c: float,
            start_state: np.ndarray) -> None:
        if not (math.isfinite(current_a) and math.isfinite(voltage_v)):
            return
        if self._x0[b] is None:
            self._x0[b] = np.array(start_state, dtype=np.float64)
        self._buf[b].append((time_s, current_a, voltage_v, ambient_c))

    def check(self, time_s: float) -> list[tuple[str, Fault]]:
        if time_s - self._last_check < self.config.check_every_s:
            return []
        self._last_check = time_s
        events = []
        for b, name in enumerate(PACK_NAMES):
            buf = self._buf[b]
            if len(buf) < self.config.min_samples or buf[-1][0] - buf[0][0] < self.config.min_history_s:
                continue
            arr = np.asarray(buf)
            fit = fit_pack_residual(self.params[b], self._x0[b], arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3],
                                    self.config.min_soc)
            if fit is None:
                continue
            coef, se, rms, n = fit
            p = self.params[b]
            r_nom = p[kernel.I_RS] + p[kernel.I_RCP0]
            kappa_cb = coef[2] * p[kernel.I_CB]
            factor = 1.0 / (1.0 + kappa_cb) if 1.0 + kappa_cb > 0 else math.inf
            est = PackHealthEstimate(name, n, float(coef[0]), float(coef[1]), float(coef[1] / r_nom), factor,
                                     1.0 - factor, float(se[1] / r_nom),
                                     float(se[2] * p[kernel.I_CB] * factor * factor), rms)
            self.latest[name] = est
            cfg = self.config
            for ty, value, se_v, hi, lo in ((PACK_CAPACITY_LOSS, est.capacity_loss, est.se_capacity_loss,
                                             cfg.capacity_loss_raise, cfg.capacity_loss_clear),
                                            (PACK_RESISTANCE_RISE, est.resistance_rise, est.se_resistance_rise,
                                             cfg.resistance_rise_raise, cfg.resistance_rise_clear)):
                strong = value >= hi and value - 2.0 * se_v > lo
                deb = self._debounce[(ty, name)]
                ev = deb.update(time_s, strong, value < lo)
                conf = 0.5 * (1.0 + math.erf((value - lo) / (max(se_v, 1e-6) * math.sqrt(2.0))))
                evidence = {"delta_r_ohm": round(est.delta_r_ohm, 5), "capacity_factor": round(est.capacity_factor, 4),
                            "offset_v": round(est.offset_v, 4), "residual_rms_v": round(rms, 4), "n_samples": n,
                            "standard_error": round(se_v, 4)}
                key = (ty, name)
                if ev == "raise":
                    self.faults[key] = Fault(ty, name, float(value), time_s, conf, evidence, updated_s=time_s)
                    events.append(("raise", self.faults[key]))
                elif ev == "clear":
                    self.faults[key] = self.faults[key].with_(active=False, cleared_s=time_s, updated_s=time_s,
                                                              confidence=0.0, evidence=evidence)
                    events.append(("clear", self.faults[key]))
                elif deb.active:
                    self.faults[key] = self.faults[key].with_(magnitude=float(value), confidence=conf,
                                                              updated_s=time_s, evidence=evidence)
        return events
