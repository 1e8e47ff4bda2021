"""Unscented Kalman filter for the four packs, batched over the kernel.

State per pack: the kernel's ``PACK_STATE`` (q_b, q_cp, q_s, T). Input: measured terminal
current. Observations: terminal voltage and pack temperature (both linear in the state).

One ``step`` advances any subset of packs, each by its own dt (frames arrive per pack at their
own times): the 2n = 8 sigma points of every pack advanced go through the kernel's own step
(``kernel._pack_advance``) inside one compiled call (``ukf.pack_step_rows``) — a telemetry frame
steps one pack, and at that size array set-up, not arithmetic, was the cost (issue 18).

Robustness: each observation channel is gated on its normalised innovation (spikes are
rejected and counted); a channel rejected ``relock_after`` times in a row is taken as a real
change the model missed, so the covariance is inflated and the filter re-locks instead of
ignoring the sensor for ever. A missing channel (``NaN``) is skipped; the filter keeps
predicting and its uncertainty grows.

Model consistency (``ConsistencyWindow``): gating judges one sample; whether the pack still
behaves like its model is a question about many. Each channel keeps the mean of its last N squared
normalised innovations ν², each clipped at c² (c = 3: one spike moves the mean by at most 9/N, a
telemetry stream's 0.3 % of spikes would otherwise raise it on their own). If the model is right
and the filter consistent, the normalised innovations are independent N(0, 1), so the window's sum
is a sum of N clipped χ²₁ values, whose mean and variance are exact (``clipped_chi2_moments``); it
is approximated by a scaled χ² with those two moments (Satterthwaite). Above its 1 − α quantile (per
N) is a model mismatch with false-alarm probability ≈ α per full window; it clears only below the
median (hysteresis). The window also keeps the mean raw innovation — the residual, V or °C — as
evidence. The filter's noise is set conservatively (``voltage_sigma_v`` carries model error), so
on a pack that matches its model the statistic sits well below 1 (0.3-0.5 on synthetic flights).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gcs_pdm.estimation import ukf
from gcs_pdm.models import kernel

N_STATE = kernel.N_PACK_STATE


@dataclass(frozen=True)
class PackFilterConfig:
    voltage_sigma_v: float = 0.05       # sensor noise plus model error of one voltage sample
    #: a thermistor's 0.3 °C noise (a 1 °C-resolution report is 0.29 °C) plus the thermal model's
    #: error. With 0.5 °C and T's process noise at 0.02 the 2σ band held 99.6 % (the error's spread
    #: was half the σ shown; docs/notes/2026-11-27-risk-calibration.md)
    temperature_sigma_c: float = 0.4
    #: process noise densities per √s: q_b, q_cp, q_s (C), T (°C). q_b's covers current-sensor
    #: bias and the capacity mismatch between the parameter set and the real pack; T's, the heat
    #: the model gets wrong (at 0.005 the band lagged the truth's drift: 67 % held; at 0.01, 90-93 %)
    process_sigma: tuple[float, float, float, float] = (4.0, 1.0, 0.5, 0.012)
    initial_soc_sigma: float = 0.05
    initial_temp_sigma_c: float = 2.0
    gate: float = 5.0                   # normalised-innovation gate, σ
    relock_after: int = 5               # consecutive rejections before re-locking
    relock_inflation: float = 25.0
    #: model-consistency test (module docstring): updates per window, the false-alarm probability
    #: per full window if the model were right, and the χ² quantile the statistic must fall below
    #: to clear. 120 voltage updates are 1-4 minutes of BATTERY_STATUS
    mismatch_window: int = 120
    mismatch_false_alarm: float = 1e-4
    mismatch_clear_quantile: float = 0.5
    mismatch_clip: float = 3.0          # normalised innovations enter the test clipped at ±this
    #: after a telemetry gap longer than this (s) the next updates are not judged: the current held
    #: over the gap was a guess, and the innovations show that for a few R_cp-C_cp time constants
    mismatch_gap_s: float = 6.0
    mismatch_settle_updates: int = 20


def clipped_chi2_moments(clip: float) -> tuple[float, float]:
    """Mean and variance of min(Z², c²) for Z ~ N(0, 1)."""
    # scipy.special, not scipy.stats: the same functions, without the 0.6 s import of scipy.stats
    # on every command's start (numba already loads scipy.linalg; scipy.special adds ≈ 50 ms)
    from scipy.special import ndtr

    inside = 1.0 - 2.0 * ndtr(-clip)
    pdf = math.exp(-0.5 * clip * clip) / math.sqrt(2.0 * math.pi)
    tail = 1.0 - inside
    m1 = inside - 2.0 * clip * pdf + clip ** 2 * tail
    m2 = 3.0 * inside - 2.0 * pdf * (clip ** 3 + 3.0 * clip) + clip ** 4 * tail
    return m1, m2 - m1 ** 2


def clipped_mean_quantile(q: float, n: int, clip: float) -> float:
    """The ``q`` quantile of the mean of ``n`` independent min(Z², c²): a scaled χ² with the same
    mean and variance (Satterthwaite)."""
    from scipy.special import gammaincinv

    m1, var = clipped_chi2_moments(clip)
    scale, dof = var / (2.0 * m1), 2.0 * n * m1 ** 2 / var
    return float(scale * 2.0 * gammaincinv(0.5 * dof, q) / n)  # the χ² quantile, as scipy.stats.chi2.ppf


#: model-consistency channels (the window's second index)
CHANNELS = ("voltage", "temperature")


class ConsistencyWindow:
    """Per pack and channel: the last N clipped squared normalised innovations and raw innovations
    (ring buffers with running sums), and the hysteresis state. Updated inside the compiled step
    (``ukf._window_push``); ``arrays`` is what it is handed."""

    def __init__(self, n_rows: int, config: PackFilterConfig):
        n = int(config.mismatch_window)
        if n < 2:
            raise ValueError(f"mismatch_window: need at least 2 updates, got {n}")
        if not 0.0 < config.mismatch_false_alarm < config.mismatch_clear_quantile < 1.0:
            raise ValueError("mismatch_false_alarm must be in (0, mismatch_clear_quantile), the quantile in (0, 1)")
        self.size = n
        self.clip = float(config.mismatch_clip)
        self.raise_at = clipped_mean_quantile(1.0 - config.mismatch_false_alarm, n, self.clip)
        self.clear_at = clipped_mean_quantile(config.mismatch_clear_quantile, n, self.clip)
        self.false_alarm = float(config.mismatch_false_alarm)
        self.buf = np.zeros((n_rows, 2, 2, n))             # [..., 0, :] ν²/S clipped, [..., 1, :] ν
        self.ints = np.zeros((n_rows, 2, 4), dtype=np.int64)  # ukf.W_POS, W_COUNT, W_ACTIVE, W_QUIET
        self.sums = np.zeros((n_rows, 2, 2))
        self.levels = np.array([[self.raise_at, self.clear_at, self.clip ** 2, config.mismatch_gap_s,
                                 config.mismatch_settle_updates]] * 2)
        self.arrays = (self.buf, self.ints, self.sums, self.levels)

    def adopt(self, buf: np.ndarray, ints: np.ndarray, sums: np.ndarray, levels: np.ndarray) -> None:
        """Keep the window in these arrays (views into a filter bank's buffers), as they are."""
        self.buf, self.ints, self.sums, self.levels = buf, ints, sums, levels
        self.arrays = (buf, ints, sums, levels)

    @property
    def count(self) -> np.ndarray:
        """(rows, 2) updates in the window."""
        return self.ints[..., ukf.W_COUNT]

    @property
    def active(self) -> np.ndarray:
        """(rows, 2) bool: the channel fails the test now."""
        return self.ints[..., ukf.W_ACTIVE] != 0

    def reset(self, rows) -> None:
        """Forget rows ``rows`` (a filter restarting from a fresh reading)."""
        for a in (self.buf, self.ints, self.sums):
            a[rows] = 0

    def statistic(self) -> np.ndarray:
        """(rows, 2) mean squared normalised innovation over the window (NaN until it is full)."""
        full = self.count >= self.size
        return np.where(full, self.sums[..., 0] / np.maximum(self.count, 1), np.nan)

    def statistic_at(self, row: int, channel: int) -> float:
        """``statistic()[row, channel]`` without the whole array (a per-frame read of one pack)."""
        count = int(self.ints[row, channel, ukf.W_COUNT])
        return float(self.sums[row, channel, 0]) / max(count, 1) if count >= self.size else math.nan

    def mean_residual(self) -> np.ndarray:
        """(rows, 2) mean innovation (V, °C) over the updates in the window (NaN before any)."""
        return np.where(self.count > 0, self.sums[..., 1] / np.maximum(self.count, 1), np.nan)


def _allocate(bank, params, n_params: int, n_state: int, config: PackFilterConfig, process_sigma, name: str) -> None:
    """A filter bank's parameter rows, state, covariance, counters and consistency window."""
    bank.params = np.ascontiguousarray(np.atleast_2d(np.asarray(params, dtype=np.float64)))
    if bank.params.shape[1] != n_params:
        raise ValueError(f"{name}: expected (packs, {n_params}), got {bank.params.shape}")
    bank.config = config
    n = bank.params.shape[0]
    bank.mean = np.zeros((n, n_state))
    bank.cov = np.zeros((n, n_state, n_state))
    bank.initialised = np.zeros(n, dtype=bool)
    bank.rejected_in_row = np.zeros((n, 2), dtype=np.int64)
    bank.rejected_total = np.zeros((n, 2), dtype=np.int64)
    bank.relocks = np.zeros(n, dtype=np.int64)
    bank.last_innovation = np.full((n, 2), np.nan)
    bank.consistency = ConsistencyWindow(n, config)
    bank._q = np.diag(np.square(np.asarray(process_sigma, dtype=np.float64)))


class PackFilterBank:
    """UKF over ``n_packs`` packs sharing nothing but the kernel call."""

    def __init__(self, pack_params: np.ndarray, config: PackFilterConfig = PackFilterConfig()):
        _allocate(self, pack_params, kernel.N_PACK_PARAMS, N_STATE, config, config.process_sigma, "pack_params")
        n_packs = self.params.shape[0]
        # observation rows: V = q_b/C_b - q_cp/C_cp - q_s/C_s ; T = T
        p = self.params
        self._h_v = np.stack([1.0 / p[:, kernel.I_CB], -1.0 / p[:, kernel.I_CCP], -1.0 / p[:, kernel.I_CS],
                              np.zeros(n_packs)], axis=1)
        self._h_t = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (n_packs, 1))
        # every array ``ukf.pack_step_one`` steps lives in the bank's two buffers (``ukf.pack_storage``:
        # a telemetry frame's compiled call then takes two arrays, not twenty arguments)
        c, w = self.config, self.consistency
        consts = ukf.step_constants(c.voltage_sigma_v ** 2, c.temperature_sigma_c ** 2, c.gate, c.relock_after,
                                    c.relock_inflation, kernel.DEFAULT_MAX_DT)
        scratch = np.zeros(ukf.pack_shapes(n_packs, w.size)[ukf.PACK_FLOAT_ARRAYS.index("scratch")])
        self._floats, self._ints = ukf.pack_storage(
            (self.params, self.mean, self.cov, self._q, self._h_v, consts, self.last_innovation, w.buf, w.sums,
             w.levels, np.eye(N_STATE)[-1], scratch, self.rejected_total, self.rejected_in_row, self.relocks, w.ints), w.size)
        self._bind_views()

    def _bind_views(self) -> None:
        """The bank's arrays, and its consistency window's, as views into its two buffers."""
        (self.params, self.mean, self.cov, self._q, self._h_v, _, self.last_innovation, w_buf, w_sums, w_levels, _, _,
         self.rejected_total, self.rejected_in_row, self.relocks, w_ints) = ukf.pack_views(self._floats, self._ints)
        self.consistency.adopt(w_buf, w_ints, w_sums, w_levels)

    def __setstate__(self, state: dict) -> None:
        # a copy (copy.deepcopy, pickle) copies each view apart from the buffers: bind them again
        self.__dict__.update(state)
        self._bind_views()

    # ---- initialisation -------------------------------------------------------------------------
    def initialise(self, idx: np.ndarray, voltage: np.ndarray, current: np.ndarray, temperature: np.ndarray,
                   ambient_c: float = 20.0) -> None:
        """Start packs ``idx`` from a voltage reading: invert V = V_b - i (R_s + R_cp(SoC)) with the
        R–C pairs settled at the measured current (two fixed-point passes are enough: R_cp is flat
        away from the knee)."""
        idx = np.atleast_1d(idx)
        p = self.params[idx]
        cur = np.nan_to_num(np.asarray(current, dtype=np.float64), nan=0.0)
        temp = np.asarray(temperature, dtype=np.float64)
        soc = np.full(idx.size, 1.0)
        for _ in range(3):
            v_b = voltage + cur * (p[:, kernel.I_RS] + kernel.concentration_resistance(p, soc))
            soc = np.clip(kernel.soc_at_bulk_voltage(p, v_b), 0.0, 1.0)
        # a pack that reports no temperature starts at ambient, with the wider initial uncertainty
        temp = np.where(np.isfinite(temp), temp, ambient_c)
        x = kernel.initial_pack_state(p, soc, temp, cur)
        self.mean[idx] = x
        c = self.config
        sd = np.stack([c.initial_soc_sigma * p[:, kernel.I_CMAX], 0.3 * np.abs(x[:, 1]) + 5.0,
                       0.3 * np.abs(x[:, 2]) + 1.0,
                       np.where(np.isfinite(np.asarray(temperature, dtype=np.float64)), c.temperature_sigma_c,
                                c.initial_temp_sigma_c)], axis=1)
        self.cov[idx] = sd[:, :, None] * np.eye(N_STATE) * sd[:, None, :]
        self.initialised[idx] = True
        self.consistency.reset(idx)

    # ---- one step ----------------------------------------------------------------------------------
    def step(self, idx: np.ndarray, dt: np.ndarray, current: np.ndarray, ambient: float | np.ndarray,
             voltage: np.ndarray, temperature: np.ndarray) -> None:
        """Advance packs ``idx`` by ``dt`` s at ``current`` A, then update with ``voltage`` V and
        ``temperature`` °C (NaN = not measured). Compiled (``ukf.pack_step_rows``), in place."""
        idx = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        shape = idx.shape
        c = self.config
        ukf.pack_step_rows(self.params, self.mean, self.cov, idx, ukf.as_rows(dt, shape), ukf.as_rows(current, shape),
                           ukf.as_rows(ambient, shape), ukf.as_rows(voltage, shape), ukf.as_rows(temperature, shape), self._q,
                           self._h_v, c.voltage_sigma_v ** 2, c.temperature_sigma_c ** 2, c.gate, c.relock_after,
                           c.relock_inflation, kernel.DEFAULT_MAX_DT, self.last_innovation, self.rejected_total,
                           self.rejected_in_row, self.relocks, self.consistency.arrays)

    def step_one(self, b: int, dt: float, current: float, ambient: float, voltage: float, temperature: float) -> int:
        """``step`` for one pack and plain floats (a telemetry frame), without the array set-up
        (``ukf.pack_step_one``: the same compiled arithmetic). Returns how many of its consistency
        states flipped (0 nearly always)."""
        return ukf.pack_step_one(self._floats, self._ints, b, dt, current, ambient, voltage, temperature)

    def set_params(self, b: int, row: np.ndarray) -> None:
        """Adopt new parameters for pack ``b`` (e.g. a diagnosed capacity loss), keeping what the
        filter knows: the SoC fraction and the voltages across C_cp and C_s (``prediction.restate``)."""
        from gcs_pdm.estimation.prediction import restate

        row = np.asarray(row, dtype=np.float64)
        old = self.params[b].copy()
        if self.initialised[b]:
            x = restate(old[None], self.mean[b][None], row[None])[0]
            scale = np.array([row[kernel.I_CMAX] / old[kernel.I_CMAX], row[kernel.I_CCP] / old[kernel.I_CCP],
                              row[kernel.I_CS] / old[kernel.I_CS], 1.0])
            self.cov[b] = self.cov[b] * scale[:, None] * scale[None, :]
            self.mean[b] = x
        self.params[b] = row
        self._h_v[b] = [1.0 / row[kernel.I_CB], -1.0 / row[kernel.I_CCP], -1.0 / row[kernel.I_CS], 0.0]

    # ---- read-outs ---------------------------------------------------------------------------------
    def soc(self) -> tuple[np.ndarray, np.ndarray]:
        """SoC mean and standard deviation per pack."""
        cmax = self.params[:, kernel.I_CMAX]
        mean = kernel.state_of_charge(self.params, self.mean)
        return mean, np.sqrt(np.maximum(self.cov[:, 0, 0], 0.0)) / cmax

    def temperature(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean[:, 3].copy(), np.sqrt(np.maximum(self.cov[:, 3, 3], 0.0))

    def voltage(self) -> tuple[np.ndarray, np.ndarray]:
        v = kernel.terminal_voltage(self.params, self.mean)
        var = np.einsum("ki,kij,kj->k", self._h_v, self.cov, self._h_v)
        return v, np.sqrt(np.maximum(var, 0.0))


@dataclass(frozen=True)
class ExtendedFilterConfig:
    """Noise of the extended-variant filter (state ``kernel.EXT_PACK_STATE``); the rest (gating,
    re-lock, the consistency test) is the ``PackFilterConfig``'s."""

    #: process noise densities per √s: SoC (the paper filter's 4 C/√s over 7.8 Ah), v_1, v_2 (V),
    #: T (°C), s_d (SoC)
    process_sigma: tuple[float, float, float, float, float] = (1.4e-4, 3e-3, 1e-3, 0.02, 1e-5)
    initial_soc_sigma: float = 0.05


class ExtendedPackFilterBank:
    """The same filter for packs of the extended variant (docs/model.md): the unscented prediction
    through the kernel's ``_ext_advance``, the voltage update linearised at the predicted mean
    (``ukf.ext_pack_step_rows``). Rows are the bank's own; the estimator maps packs onto them."""

    def __init__(self, ext_params: np.ndarray, config: PackFilterConfig = PackFilterConfig(),
                 ext_config: ExtendedFilterConfig = ExtendedFilterConfig()):
        _allocate(self, ext_params, kernel.N_EXT_PARAMS, kernel.N_EXT_STATE, config, ext_config.process_sigma,
                  "ext_params")
        self.ext_config = ext_config
        n = self.params.shape[0]
        self._knots()
        self._one_idx = [np.array([b], dtype=np.int64) for b in range(n)]

    def _knots(self) -> None:
        self._y = np.empty((self.params.shape[0], kernel.N_OCV_KNOTS))
        self._d = np.empty_like(self._y)
        for b in range(self.params.shape[0]):
            kernel._ocv_knots(self.params[b], self._y[b], self._d[b])

    def initialise(self, idx: np.ndarray, voltage: np.ndarray, current: np.ndarray, temperature: np.ndarray,
                   ambient_c: float = 20.0) -> None:
        """Start rows ``idx`` from a voltage reading: the SoC at which the pack, settled at the
        measured current and temperature, shows it (``kernel.extended_rest_soc``)."""
        idx = np.atleast_1d(idx)
        cur = np.nan_to_num(np.asarray(current, dtype=np.float64), nan=0.0)
        measured = np.asarray(temperature, dtype=np.float64)
        temp = np.where(np.isfinite(measured), measured, ambient_c)
        c = self.config
        for k, b in enumerate(idx):
            p = self.params[b]
            soc = float(np.clip(kernel.extended_rest_soc(p, float(voltage[k]), float(cur[k]), float(temp[k]))[0],
                                0.0, 1.0))
            x = kernel.initial_extended_state(p, soc, float(temp[k]), float(cur[k]))[0]
            self.mean[b] = x
            sd = np.array([self.ext_config.initial_soc_sigma, 0.3 * abs(x[kernel.X_V1]) + 0.02,
                           0.3 * abs(x[kernel.X_V2]) + 0.02,
                           c.temperature_sigma_c if np.isfinite(measured[k]) else c.initial_temp_sigma_c,
                           0.3 * abs(x[kernel.X_SD]) + 0.005])
            self.cov[b] = np.diag(sd ** 2)
        self.initialised[idx] = True
        self.consistency.reset(idx)

    def step_one(self, b: int, dt: float, current: float, ambient: float, voltage: float, temperature: float) -> int:
        """One frame of row ``b``; how many of its consistency states flipped."""
        c = self.config
        return ukf.ext_pack_step_rows(self.params, self._y, self._d, self.mean, self.cov, self._one_idx[b], np.array([dt]),
                               np.array([current]), np.array([ambient]), np.array([voltage]),
                               np.array([temperature]), self._q, c.voltage_sigma_v ** 2, c.temperature_sigma_c ** 2,
                               c.gate, c.relock_after, c.relock_inflation, kernel.DEFAULT_MAX_DT,
                               self.last_innovation, self.rejected_total, self.rejected_in_row, self.relocks,
                               self.consistency.arrays)

    def set_params(self, b: int, row: np.ndarray) -> None:
        """New values for row ``b``; the state (SoC fraction, R–C voltages) carries over as it is."""
        self.params[b] = np.asarray(row, dtype=np.float64)
        kernel._ocv_knots(self.params[b], self._y[b], self._d[b])

    def soc(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean[:, kernel.X_SOC].copy(), np.sqrt(np.maximum(self.cov[:, 0, 0], 0.0))

    def temperature(self) -> tuple[np.ndarray, np.ndarray]:
        return self.mean[:, kernel.X_T].copy(), np.sqrt(np.maximum(self.cov[:, kernel.X_T, kernel.X_T], 0.0))

    def voltage(self, current: np.ndarray) -> np.ndarray:
        """Terminal voltage of each row's mean state at ``current`` (A per row)."""
        return np.array([ukf._ext_voltage(self.params[b], self._y[b], self._d[b], self.mean[b], float(current[b]))
                         for b in range(self.params.shape[0])])
