"""A pack's rested curve and capacity from one whole flight: what its next flight starts from (issue 29).

In flight the filter cannot learn a curve far from its prior: on PyBaMM's Marquis2019 cell (an LCO
pouch whose curve lies 0.04-0.11 V off the published ones) it stopped trusting the voltage on every
flight and went back to its priors, so its end state carries nothing to a next flight. After the
flight the whole record is there, and a batch fit can use what an online filter cannot: the rest
before take-off and the fall to the end together.

Model: the filter's own (``estimation.calibration``), fitted to every sample at once,

    V = S·[c(s) + ΔV + k (c(s) − c(½))] − f(T)·(R0 I + R1 L1(I) + R2 L2(I)),   s = s0 − q / (ρ Q0)

c a published curve of the pack's chemistry (``models.curve_hypotheses``), q the charge drawn, L
first-order lags of the current with the chemistry's τ₁ and ``TAU2_FACTOR`` τ₁, f the chemistry's
Arrhenius factor. Given the start SoC s0 and capacity scale ρ the rest is linear: ΔV, k (with the
prior's σ as pseudo-observations) and the resistances by least squares. (s0, ρ) run over a grid:
the posterior there, with the voltage's log-likelihood counted over the residuals' effective
samples (``health.effective_samples``: a circuit's misfit is correlated over minutes), gives each
quantity's mean and σ, and each curve hypothesis its weight.

**The anchor.** A rested voltage reads an offset and a SoC alike (an offset of the curve and a
different start explain the same flight: notes/2026-11-27-chemistry-prior-limits.md). When the
description declares the charge voltage and the flight starts rested within
``DECLARED_FULL_MATCH_V`` of it, the pack started full: s0 ≈ 1 (σ ``FULL_START_SD``). Without that,
s0 rests on the offset's prior only, and the fit says so (``started_full`` false).
"""
from __future__ import annotations

import math

import numpy as np

from gcs_pdm.packs.health import effective_samples

#: a flight drawing less than this share of the rated capacity leaves the capacity and the curve's
#: shape open (the same limit the filter's capacity learning has, doubled: a batch has no second chance)
MIN_DRAWN_FRACTION = 0.2
#: the start SoC of a pack plugged in at its declared charge voltage
FULL_START_SD = 0.02
#: the grids: the start SoC and the capacity scale (coarse, then fine about the coarse best)
S0_RANGE = (0.05, 1.0)
RHO_RANGE = (0.5, 1.6)
#: the curve's shape beyond its offset and scale: corrections at this many evenly spaced SoCs, each
#: 0 ± SHAPE_SD (V per cell: the published LCO curves lie 0.04-0.11 V apart), smooth between knots
SHAPE_KNOTS = 11
SHAPE_SD = 0.05
SHAPE_CURVATURE_SD = 0.03
#: samples the fit reads at most (a longer record is thinned; the lags are computed on all of it)
MAX_SAMPLES = 900


def _lag(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """x through a first-order lag (the filter's discretisation: v' = a v + (1 − a) x)."""
    a = np.exp(-np.diff(t, prepend=t[0]) / tau_s)
    out = np.empty_like(x)
    acc = 0.0
    for k in range(x.size):
        acc = a[k] * acc + (1.0 - a[k]) * x[k]
        out[k] = acc
    return out


class _Problem:
    """One flight against one curve: the columns that do not depend on (s0, ρ), and the solve."""

    def __init__(self, curve, cells: int, q_drawn_c: np.ndarray, q0_c: float, v: np.ndarray, loads: np.ndarray,
                 prior, sigma_v: float):
        self.table = np.asarray(curve.ocv_cell_v, float)
        self.grid = np.linspace(0.0, 1.0, self.table.size)
        self.mid = float(np.interp(0.5, self.grid, self.table))
        self.cells, self.q, self.q0, self.v, self.loads = cells, q_drawn_c, q0_c, v, loads
        self.prior, self.sigma_v = prior, sigma_v
        self.knots = np.linspace(0.0, 1.0, SHAPE_KNOTS)
        n = 5 + SHAPE_KNOTS
        # pseudo-observations: the offset's and scale's priors; the resistances' (the filter's: R0 and
        # R1 at the chemistry's ± their prior σ, the slow pair 0 ± R2_SD R1: without them the slow
        # pair's sag traded with the curve's first quarter, 22 mV on a simulated pack); the shape's
        # corrections 0 ± SHAPE_SD each, their second differences 0 ± SHAPE_CURVATURE_SD (smooth)
        from gcs_pdm.estimation.calibration import R2_SD

        r0p = prior.r0_prior
        r1p = prior.chem.r1_ratio * r0p
        rows = np.zeros((5 + SHAPE_KNOTS + SHAPE_KNOTS - 2, n))
        rhs = np.zeros(rows.shape[0])
        for j, (mean, sd) in enumerate(((prior.ocv_offset_v, prior.ocv_offset_sd), (prior.ocv_scale, prior.ocv_scale_sd),
                                        (r0p, prior.r0_rel_sd * r0p), (r1p, prior.r0_rel_sd * r1p), (0.0, R2_SD * r1p))):
            rows[j, j], rhs[j] = 1.0 / sd, mean / sd
        for j in range(SHAPE_KNOTS):
            rows[5 + j, 5 + j] = 1.0 / SHAPE_SD
        for j in range(SHAPE_KNOTS - 2):
            rows[5 + SHAPE_KNOTS + j, 5 + j:8 + j] = np.array([1.0, -2.0, 1.0]) / SHAPE_CURVATURE_SD
        self.prior_rows, self.prior_rhs = rows, rhs

    def hats(self, soc: np.ndarray) -> np.ndarray:
        """The shape's basis: piecewise-linear hats on ``self.knots`` at each SoC."""
        return np.clip(1.0 - np.abs(soc[:, None] - self.knots[None, :]) * (SHAPE_KNOTS - 1), 0.0, None)

    def solve(self, s0: float, rho: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(cost, [ΔV, k, R0, R1, R2, the shape's corrections], their covariance, residuals V) at
        (s0, ρ): cost is Σ (r/σ)² plus the pseudo-observations, plus leaving the curve's table."""
        soc = s0 - self.q / (rho * self.q0)
        c = np.interp(soc, self.grid, self.table)
        a = np.column_stack([np.full(c.size, float(self.cells)), self.cells * (c - self.mid), -self.loads,
                             self.cells * self.hats(soc)])
        y = self.v - self.cells * c
        w2 = 1.0 / self.sigma_v ** 2
        # normal equations (a per-grid-point solve of 16 unknowns: lstsq on the samples cost 10x)
        m = w2 * (a.T @ a) + self.prior_rows.T @ self.prior_rows
        cov = np.linalg.inv(m)
        beta = cov @ (w2 * (a.T @ y) + self.prior_rows.T @ self.prior_rhs)
        resid = y - a @ beta
        cost = float(w2 * np.sum(resid ** 2) + np.sum((self.prior_rows @ beta - self.prior_rhs) ** 2))
        # outside the table the curve is flat: a start above full or an end below empty is no cell of it
        cost += 1e4 * float(max(soc[0] - 1.0, 0.0) + max(-soc.min(), 0.0))
        return cost, beta, cov, resid


def _grid_posterior(problem: _Problem, s0_prior: tuple[float, float] | None, rho_sd: float,
                    s0s: np.ndarray, rhos: np.ndarray) -> dict:
    """The posterior over the (s0, ρ) grid: log-weights (uniform measure), each point's linear solve."""
    logw, sols = [], []
    for s0 in s0s:
        for rho in rhos:
            cost, beta, cov, _ = problem.solve(float(s0), float(rho))
            cost += ((rho - 1.0) / rho_sd) ** 2
            if s0_prior is not None:
                cost += ((s0 - s0_prior[0]) / s0_prior[1]) ** 2
            logw.append(-0.5 * cost)
            sols.append((float(s0), float(rho), beta, cov))
    return {"logw": np.array(logw), "sols": sols}


def fit_flight_curve(time_s, current_a, voltage_v, temperature_c, prior) -> dict:
    """The curve, its offset and scale, and the capacity one flight's record says (a
    ``calibration.PackPrior`` gives the chemistry, cells, rated capacity and σ's, and the declared
    charge voltage). JSON-ready; ``{"why": ...}`` when the flight cannot tell."""
    from gcs_pdm.estimation.calibration import TAU2_FACTOR
    from gcs_pdm.models.curve_hypotheses import DECLARED_FULL_MATCH_V, CurveHypothesis, curve_hypotheses

    t = np.asarray(time_s, float)
    i = np.asarray(current_a, float)
    v = np.asarray(voltage_v, float)
    temp = np.full(t.size, np.nan) if temperature_c is None else np.asarray(temperature_c, float)
    ok = np.isfinite(t) & np.isfinite(i)
    t, i, v, temp = t[ok], i[ok], v[ok], temp[ok]
    if t.size < 60:
        return {"why": f"{t.size} samples: too short a record to fit a curve"}
    order = np.argsort(t, kind="stable")
    t, i, v, temp = t[order], i[order], v[order], temp[order]
    q = np.concatenate([[0.0], np.cumsum(0.5 * (i[1:] + i[:-1]) * np.diff(t))])
    q0 = float(prior.capacity_c)
    if q[-1] < MIN_DRAWN_FRACTION * q0:
        return {"why": f"{q[-1] / q0:.0%} of the rated capacity drawn: under {MIN_DRAWN_FRACTION:.0%}, the curve's "
                       "shape and the capacity stay open"}
    chem = prior.chem
    if np.isfinite(temp).any():  # a missing reading is the last one (the first: the flight's mean)
        last = np.maximum.accumulate(np.where(np.isfinite(temp), np.arange(temp.size), 0))
        temp = temp[last]
        temp = np.where(np.isfinite(temp), temp, float(np.nanmean(temp)))
    else:
        temp = np.full(t.size, 25.0)
    f = np.exp(chem.r_activation_k * (1.0 / (temp + 273.15) - 1.0 / 298.15))
    loads = np.column_stack([f * i, f * _lag(t, i, chem.tau1_s), f * _lag(t, i, TAU2_FACTOR * chem.tau1_s)])
    use = np.isfinite(v)
    if use.sum() > MAX_SAMPLES:
        use &= np.arange(t.size) % int(math.ceil(use.sum() / MAX_SAMPLES)) == 0
    cells = int(prior.cells)
    rest_a = max(0.3, 0.05 * q0 / 3600.0)  # the filter's rest current (PackCalibrator.rest_current_a)
    first_load = int(np.argmax(np.abs(i) > rest_a)) if (np.abs(i) > rest_a).any() else t.size
    start_rest_v = float(np.nanmedian(v[:max(first_load, 1)])) / cells if first_load > 0 else math.nan
    hyps = ((CurveHypothesis(prior.curve, 1.0),) if prior.curve is not None
            else curve_hypotheses(prior.chemistry, prior.full_cell_v))
    started_full = (prior.full_cell_v is not None and math.isfinite(start_rest_v)
                    and abs(start_rest_v - prior.full_cell_v) <= DECLARED_FULL_MATCH_V)
    s0_prior = (1.0, FULL_START_SD) if started_full else None
    coarse_s0, coarse_rho = np.arange(S0_RANGE[0], S0_RANGE[1] + 1e-9, 0.05), np.arange(*RHO_RANGE, 0.1)
    results = []
    for h in hyps:
        # first pass at the sensor's σ finds the best point; its residuals say how far the circuit
        # misses and how correlated the misses are, which the second pass counts
        sigma0 = 0.01 * cells
        prob = _Problem(h.curve, cells, q[use], q0, v[use], loads[use], prior, sigma0)
        post = _grid_posterior(prob, s0_prior, prior.capacity_rel_sd, coarse_s0, coarse_rho)
        s0b, rhob, *_ = post["sols"][int(np.argmax(post["logw"]))]
        _, _, _, resid = prob.solve(s0b, rhob)
        n_eff = effective_samples(resid)
        prob.sigma_v = max(float(np.sqrt(np.mean(resid ** 2))), 1e-4) * math.sqrt(resid.size / n_eff)
        fine_s0 = np.clip(np.arange(s0b - 0.1, s0b + 0.1 + 1e-9, 0.01), *S0_RANGE)
        fine_rho = np.clip(np.arange(rhob - 0.2, rhob + 0.2 + 1e-9, 0.02), *RHO_RANGE)
        post = _grid_posterior(prob, s0_prior, prior.capacity_rel_sd, np.unique(fine_s0), np.unique(fine_rho))
        lw = post["logw"]
        w = np.exp(lw - lw.max())
        w /= w.sum()
        s0s = np.array([s[0] for s in post["sols"]])
        rhos = np.array([s[1] for s in post["sols"]])
        betas = np.array([s[2] for s in post["sols"]])
        mean_beta = w @ betas
        # the mixture's variance: each point's own (its linear solve) and the spread of their means
        var_beta = w @ np.array([np.diag(s[3]) for s in post["sols"]]) + w @ (betas - mean_beta) ** 2
        # the learned curve on the table's grid, with its σ (the mixture's, as above)
        grid = prob.grid
        cbase = prob.table
        basis = np.column_stack([np.ones(grid.size), cbase - prob.mid, np.zeros((grid.size, 3)), prob.hats(grid)])
        curves = betas @ basis.T + cbase[None, :]
        curve_m = w @ curves
        curve_var = (w @ np.array([np.einsum("ij,jk,ik->i", basis, s[3], basis) for s in post["sols"]])
                     + w @ (curves - curve_m) ** 2)
        rho_m = float(w @ rhos)
        s0_m = float(w @ s0s)
        log_evidence = float(lw.max() + math.log(np.sum(np.exp(lw - lw.max()))))
        results.append({"curve": h.curve.name, "full_cell_v": float(h.curve.full_cell_v),
                        "log_weight": log_evidence + math.log(h.prior_weight),
                        "ocv_offset_v": round(float(mean_beta[0]), 4),
                        "ocv_offset_sd": round(math.sqrt(float(var_beta[0])), 4),
                        "ocv_scale": round(float(mean_beta[1]), 4),
                        "ocv_scale_sd": round(math.sqrt(float(var_beta[1])), 4),
                        "capacity_ah": round(rho_m * q0 / 3600.0, 4),
                        # floored at a quarter of the fine grid's step: a narrower posterior is not resolved
                        "capacity_sd_ah": round(math.sqrt(float(w @ (rhos - rho_m) ** 2) + 0.005 ** 2) * q0 / 3600.0, 4),
                        "start_soc": round(s0_m, 4), "start_soc_sd": round(math.sqrt(float(w @ (s0s - s0_m) ** 2)), 4),
                        "rms_v": round(float(np.sqrt(np.mean(resid ** 2))), 4), "effective_samples": round(n_eff, 1),
                        # a curve rises with its SoC: a learned dip is noise (soc_at needs it rising)
                        "ocv_cell_v": [round(float(x), 4) for x in
                                       np.maximum.accumulate(curve_m) + 1e-4 * np.arange(grid.size)],
                        "ocv_cell_sd": [round(float(x), 4) for x in np.sqrt(np.maximum(curve_var, 0.0))]})
    top = max(r["log_weight"] for r in results)
    weights = [math.exp(r["log_weight"] - top) for r in results]
    total = sum(weights)
    best = max(range(len(results)), key=lambda k: weights[k])
    out = {k: val for k, val in results[best].items() if k != "log_weight"}
    out.update(weight=round(weights[best] / total, 4), started_full=bool(started_full),
               hypotheses=[{"curve": r["curve"], "weight": round(wk / total, 4)} for r, wk in zip(results, weights)])
    return out
