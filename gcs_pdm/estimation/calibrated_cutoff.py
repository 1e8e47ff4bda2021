"""Time to cut-off of a self-calibrated pack, on its own filter's model (issue 29).

A pack whose state comes from a ``calibration.PackCalibrator`` is predicted on that filter's
model — its chemistry curve with the learned offset and scale, its learned resistances, Arrhenius
factor and capacity — not on the description's kernel pack, which carries only its SoC (a derived
LiPo's kernel pack is the paper's LLF20 scaled, with a rested voltage linear in charge). The
product's held-current prediction (``prediction.draw_held_current``: the replay's trace, a live
fixed wing) and the service's per-pack count-down (``service.adapters.prediction_job``) both come
from here, and so does the harness's figure (``replay.calibration_eval.pybamm_flight_soc``).

At a held current I the pack reaches its cut-off where S·OCV_cell(SoC) − sag(SoC) = cut-off, with
the polarisation settled: sag = (R₀ + R₁ + R₂) f(T) I now, rising near empty as the paper's fitted
pack's resistance does (``low_charge_rise``: the filter cannot learn that rise before the pack gets
there, and a cell's sag does grow there — 1.8 V at half-way, 3.1 V at cut-off on a PyBaMM LG M50). What the model does not explain now — the
recent loaded voltage's shortfall below the model's (``PackCalibrator.recent_miss_v``, a mean over
``calibration.RECENT_LOAD_TAU_S``), scaled to the held current — stays in the sag: a voltage the
filter stopped following (its resistances back at the prior) still sags the pack at cut-off. The
time is the charge between here and there over the charge count's rate.

The interval: the same computation on draws of what is uncertain — the filter's state from its
covariance (SoC, capacity, resistances, curve, temperature factor, jointly; a capacity whose learning
was held keeps its prior's σ), held inside what the chemistry allows — and three things the filter
does not carry:

* the future load: the held mean times a log-normal factor whose σ is how far the held mean has moved
  over each ``RECENT_LOAD_TAU_S`` of this flight's load (``PackCalibrator.current_move_log_var``),
  ``CURRENT_PRIOR_LOG_SD`` before one whole span was seen;
* the sag the model does not explain: the shortfall drawn about its recent mean with its recent
  variability (``PackCalibrator.recent_miss_var``);
* the sag's rise near empty: one fitted pack's (``low_charge_rise``), raised to a log-normal power
  (σ ``RISE_LOG_SD``): a cell's own rise is not seen before it gets there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from gcs_pdm.estimation.calibration import (I_DV, I_E, I_G, I_K, I_R0, I_R1, I_R2, I_SOC, I_V1, I_V2, N_STATE,
                                            PackCalibrator)

#: the state components a draw varies (the charge count's start is not part of the model)
_DRAWN = np.arange(N_STATE - 1)
#: σ of the log of the future mean load over the held one before one whole span of load has been
#: seen: a flight's phases differ by about this much (a PyBaMM flight's climb 17 A, its cruise 12 A)
CURRENT_PRIOR_LOG_SD = 0.3
#: σ of the log of the near-empty rise's power: the rise is the paper's LLF20's; a cell's own can be
#: half or twice as steep in log (an LG M50's sag at cut-off is 1.7x its half-way one, LLF20's 1.1-1.5x)
RISE_LOG_SD = 0.7


@dataclass(frozen=True)
class CutoffModel:
    """A copy of one calibrator's model and state (it moves on; this does not): a prediction taken
    now can run later or on another thread with the same numbers."""

    x: np.ndarray
    P: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    table: np.ndarray
    mid: float
    cells: int
    q0: float
    #: 1/T − 1/298.15 of the last temperature reading
    temp_u: float
    #: the mean loaded current and the model's voltage shortfall at it (NaN: no load seen)
    recent_current_a: float
    recent_miss_v: float
    #: the shortfall's recent σ (V); σ of the log of the future mean load over the held one
    recent_miss_sd_v: float = 0.0
    current_log_sd: float = CURRENT_PRIOR_LOG_SD
    #: σ of the log of the near-empty rise's power
    rise_log_sd: float = RISE_LOG_SD

    @classmethod
    def of(cls, cal: PackCalibrator) -> "CutoffModel | None":
        """The calibrator's model now; None before its first voltage. A ``CurveBank`` (curve
        hypotheses) gives its leading curve's filter, its SoC variance widened to the bank's (which
        holds the other curves in proportion to their weight)."""
        if not cal.initialised:
            return None
        bank_soc_var = None
        if hasattr(cal, "lead"):
            bank_soc_var, cal = cal.filter_soc_sd ** 2, cal.lead
        move = cal.current_move_log_var
        P = cal.P.copy()
        if bank_soc_var is not None and math.isfinite(bank_soc_var) and bank_soc_var > P[I_SOC, I_SOC]:
            f = math.sqrt(bank_soc_var / P[I_SOC, I_SOC])  # the same correlations, a wider SoC
            P[I_SOC, :] *= f
            P[:, I_SOC] *= f
        return cls(cal.x.copy(), P, cal.lo.copy(), cal.hi.copy(), cal.table.copy(), float(cal.mid),
                   int(cal.cells), float(cal.q0), float(cal.last_u), float(cal.recent_current_a),
                   float(cal.recent_miss_v), math.sqrt(max(cal.recent_miss_var, 0.0)),
                   math.sqrt(move) if math.isfinite(move) else CURRENT_PRIOR_LOG_SD)

    def without_unmodelled(self) -> "CutoffModel":
        """This model with only the filter's covariance drawn (the load held exactly, the shortfall
        at its mean, LLF20's rise): what the interval was before those were drawn, to measure them."""
        return replace(self, recent_miss_sd_v=0.0, current_log_sd=0.0, rise_log_sd=0.0)

    def held_current(self, present_a: float) -> float:
        """The current a held-current prediction holds: the recent mean load (a flight's draw moves
        ±10 % over tens of seconds; the present sample's noise is not the future's), else the present."""
        return self.recent_current_a if math.isfinite(self.recent_current_a) else present_a

    def times(self, states: np.ndarray, current, cutoff_v: float, miss_v=None, rise_power=1.0) -> np.ndarray:
        """Seconds to the cut-off at a held ``current`` (A, or one per row) for each row of ``states``
        (N_STATE wide), the model's recent shortfall ``miss_v`` (V, or one per row; None: its recent
        mean) and the near-empty rise to ``rise_power`` (or one per row): NaN at no current, 0 where
        already below."""
        s = np.atleast_2d(states)
        cur = np.broadcast_to(np.asarray(current, dtype=float), (s.shape[0],))
        if not np.all(cur > 0):
            return np.full(s.shape[0], math.nan)
        ft = np.exp(s[:, I_E] * self.temp_u)
        settled = (s[:, I_R0] + s[:, I_R1] + s[:, I_R2]) * ft * cur
        sag = settled
        i_r = self.recent_current_a
        miss = self.recent_miss_v if miss_v is None else np.asarray(miss_v, dtype=float)
        if math.isfinite(i_r) and i_r > 0 and np.all(np.isfinite(miss)):
            # the recent voltage, as the model at its mean state less its shortfall, against each row's model
            measured = self._loaded_voltage(self.x[None], i_r)[0] - miss
            sag = np.maximum(settled + (self._loaded_voltage(s, i_r) - measured) * (cur / i_r), 0.0)
        curves = self.table[None] + s[:, I_DV, None] + s[:, I_K, None] * (self.table[None] - self.mid)
        # the loaded voltage on a fine SoC grid, the sag rising near empty from where it is now:
        # it rises as SoC falls, so the cut-off is its one crossing
        power = np.broadcast_to(np.asarray(rise_power, dtype=float), (s.shape[0],))[:, None]
        rise = (low_charge_rise(_FINE)[None] / low_charge_rise(np.clip(s[:, I_SOC], 0.0, 1.0))[:, None]) ** power
        loaded = self.cells * _on_fine(curves) - sag[:, None] * rise
        soc_cut = _crossing(loaded, np.full(s.shape[0], cutoff_v), _FINE)
        left = np.maximum(s[:, I_SOC] - soc_cut, 0.0)
        return left * self.q0 / (s[:, I_G] * cur)

    def time_to_cutoff(self, current: float, cutoff_v: float) -> float:
        """``times`` of the mean state."""
        return float(self.times(self.x[None], current, cutoff_v)[0])

    def sample_times(self, current: float, cutoff_v: float, rng: np.random.Generator, n_samples: int) -> np.ndarray:
        """``times`` of ``n_samples`` draws: states from the filter's covariance, within its bounds,
        and the future load, the shortfall and the near-empty rise (the module doc). The draws come
        in antithetic pairs (``antithetic_normals``): the median of 64 independent draws moved ±10 %
        from one call to the next on a PyBaMM flight's half-way (its 5-95 % ±66 % wide), in pairs ±1 %."""
        z = antithetic_normals(rng, n_samples, _DRAWN.size + 3)
        states, e = self._states(z[:, :_DRAWN.size]), z[:, _DRAWN.size:].T
        return self.times(states, current * np.exp(self.current_log_sd * e[0]), cutoff_v,
                          self.recent_miss_v + self.recent_miss_sd_v * e[1], np.exp(self.rise_log_sd * e[2]))

    def draw_states(self, rng: np.random.Generator, n_samples: int) -> np.ndarray:
        """(n_samples, N_STATE) states drawn from the filter's covariance, held within its bounds."""
        return self._states(rng.standard_normal((n_samples, _DRAWN.size)))

    def _states(self, z: np.ndarray) -> np.ndarray:
        """The states of standard normal rows ``z`` (n, drawn components) under the filter's covariance,
        held within its bounds."""
        n_samples = z.shape[0]
        cov = self.P[np.ix_(_DRAWN, _DRAWN)]
        w, v = np.linalg.eigh(0.5 * (cov + cov.T))
        states = np.repeat(self.x[None], n_samples, axis=0)
        states[:, _DRAWN] += (z * np.sqrt(np.maximum(w, 0.0))) @ v.T
        np.clip(states, self.lo, self.hi, out=states)
        return states

    def sag_beyond_model_ohm(self, states: np.ndarray) -> np.ndarray:
        """Per row of ``states``: what ``times`` adds to the settled sag, per ampere — the recent
        loaded voltage's shortfall below that row's model (``recent_miss_v`` at the mean state),
        over the recent current (0 with no load seen)."""
        s = np.atleast_2d(states)
        shortfall = self._shortfall(s)
        return np.zeros(s.shape[0]) if shortfall is None else shortfall / self.recent_current_a

    def _shortfall(self, s: np.ndarray) -> np.ndarray | None:
        """Per row: its model's loaded voltage at the recent current less the recent measured one
        (the model at its mean state less its shortfall); None with no load seen."""
        i_r, miss = self.recent_current_a, self.recent_miss_v
        if not (math.isfinite(i_r) and i_r > 0 and math.isfinite(miss)):
            return None
        measured = self._loaded_voltage(self.x[None], i_r)[0] - miss
        return self._loaded_voltage(s, i_r) - measured

    def _loaded_voltage(self, s: np.ndarray, current: float) -> np.ndarray:
        """The model's terminal voltage at ``current`` now (the pairs as they are, not settled)."""
        ocv = np.interp(np.clip(s[:, I_SOC], 0.0, 1.0), _GRID, self.table)
        ft = np.exp(s[:, I_E] * self.temp_u)
        return (self.cells * (ocv + s[:, I_DV] + s[:, I_K] * (ocv - self.mid)) - s[:, I_V1] - s[:, I_V2]
                - s[:, I_R0] * ft * current)


_GRID = np.linspace(0.0, 1.0, 21)
#: the SoC grid the loaded voltage is solved on (0.0025 apart: the knee's width is a few hundredths)
_FINE = np.linspace(0.0, 1.0, 401)
#: the sag's rise near empty: the paper's fitted pack (``paper_si`` LLF20, eq. 6), its total
#: resistance R_s + R_cp(SoC) over its value at half charge: 1.09x at 10 %, 1.5x at 5 %, 3.8x at 0
_RISE_RS, _RISE_RCP0, _RISE_RCP1, _RISE_RCP2 = 0.0074, 0.03, 1.2e-16, 34.41


def low_charge_rise_terms() -> tuple[float, float, float]:
    """``low_charge_rise`` as c (1 + k exp(−SoC / knee)): (c, k, knee) — the kernel's extended
    variant's low-charge factor (``k_soc``, ``soc_knee``) times a constant."""
    base = _RISE_RS + _RISE_RCP0
    return base / float(_total_resistance(0.5)), _RISE_RCP1 * math.exp(_RISE_RCP2) / base, 1.0 / _RISE_RCP2


def _total_resistance(soc):
    return _RISE_RS + _RISE_RCP0 + _RISE_RCP1 * np.exp(_RISE_RCP2 * (1.0 - np.asarray(soc)))


def low_charge_rise(soc: np.ndarray) -> np.ndarray:
    """The sag near empty relative to half charge (1 above ~20 % SoC). With the state right (the
    PyBaMM cells' own curve and capacity) the time to cut-off from half-way was 7-10 % long on
    Chen2020 without it, 1-5 % with it (docs/notes/2026-11-27-time-to-cutoff.md)."""
    return _total_resistance(soc) / _total_resistance(0.5)


def antithetic_normals(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """(n, k) standard normal rows in antithetic pairs (z and −z; an odd n drops the last mirror):
    each row is still a standard normal draw, so every quantile estimates the same distribution's,
    but the pairs cancel the sampling error of a central value that is close to monotone in z."""
    z = rng.standard_normal(((n + 1) // 2, k))
    return np.concatenate([z, -z])[:n]


def _on_fine(curves: np.ndarray) -> np.ndarray:
    """Rows of a 21-knot curve interpolated onto ``_FINE``."""
    k = np.minimum((_FINE * 20.0).astype(int), 19)
    frac = _FINE * 20.0 - k
    return curves[:, k] * (1.0 - frac) + curves[:, k + 1] * frac


def _crossing(curves: np.ndarray, target: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Per row: the SoC at which the rising curve (rows × knots on ``grid``) reaches ``target``
    (0 below its first knot, 1 above its last), linear between knots."""
    n_seg = curves.shape[1] - 1
    k = np.clip((curves < target[:, None]).sum(axis=1) - 1, 0, n_seg - 1)
    rows = np.arange(curves.shape[0])
    lo, hi = curves[rows, k], curves[rows, k + 1]
    frac = np.clip((target - lo) / np.maximum(hi - lo, 1e-12), 0.0, 1.0)
    return np.where(target <= curves[:, 0], 0.0, grid[k] + frac * (grid[k + 1] - grid[k]))
