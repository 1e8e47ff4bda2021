"""Pack degradation: a voltage residual that persists beyond noise, read as capacity loss or
resistance rise, with an estimate of each.

Every ``check_every_s`` of message time the pack's record (cleaned current, measured voltage,
ambient; the newest ``max_samples``, since the last gap longer than ``max_gap_s``) is fitted through the kernel with three unknowns: a scale on the series
resistance (R_s and R_cp0 together), a scale on the capacity (C_b, q_max, C_max together: a pack
that lost capacity loses bulk capacitance, so its voltage falls faster per coulomb) and the
initial SoC (the record may start anywhere). A few Gauss–Newton steps with a finite-difference
Jacobian (one batched ``simulate_packs`` call each) from (1, 1, full) converge; the fit runs on
the model's own dynamics, so the R_cp–C_cp lag does not bias the resistance as a static
regression would. Spikes are cut with a MAD rule; samples near the knee (model SoC <
``min_soc``) are left out. A fault needs its estimate beyond the raise threshold (and two
standard errors above the clear one) at three checks in a row, and clears likewise.

A check after the first starts one search from the previous check's fit instead of the two or
three cold starts (``PackHealthConfig.warm_start``: ≈ 5× fewer kernel calls per check); the cold search is
kept for a new or restarted record, when the capacity becomes free, when the warm fit's residual
grows, when its verdict would change, and every ``cold_every_checks`` checks. A warm check first
tries not to simulate the record at all (``PackHealthConfig.extend_fits``): the previous fit's last
kernel run (base and perturbed rows) is carried on over the samples that arrived since, the samples
that left the record are dropped, and one Gauss–Newton step is taken from that run's theta with its
own Jacobian (``_fit_extended``); the step is kept when no unknown moves beyond its finite-difference
perturbation and the residual did not grow, else the record is fitted afresh as above. A search's
iterations (``_iterate``: one compiled call per iteration) and an extension (``_extend``) run compiled
code that releases the GIL (the least-squares step between is LAPACK's, called from Python); the fits
afresh of a check's packs run on threads.

Thresholds sit above what an uncalibrated parameter set alone produces (≈15 % per parameter for
the simulated vehicle); after the fitter has learned the real pack they can be tightened.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from gcs_pdm.diagnosis.debounce import DebounceConfig, Debouncer
from gcs_pdm.diagnosis.faults import PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE, Fault
from gcs_pdm.estimation.parallel import thread_map
from gcs_pdm.estimation.prediction import median_by_selection
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES


@dataclass(frozen=True)
class PackHealthConfig:
    check_every_s: float = 60.0
    min_history_s: float = 240.0
    min_samples: int = 150
    min_soc: float = 0.2
    #: a capacity estimate means little before a good part of the pack has been used: early on a
    #: resistance rise explains the record about as well (measured: a ×2.5 resistance read as a
    #: 50 % capacity loss after 6 minutes, correctly after 9)
    min_drawn_for_capacity: float = 0.25
    capacity_loss_raise: float = 0.22
    capacity_loss_clear: float = 0.15
    resistance_rise_raise: float = 0.6
    resistance_rise_clear: float = 0.4
    #: the record a check fits is at most this many samples (the newest; the fit's initial SoC is
    #: free, so it may start anywhere): each check's work is bounded by samples, not time span
    max_samples: int = 3000
    #: a gap longer than this starts a new record: the fit would have to simulate the gap at a
    #: current nobody measured (a 49.7-day gap was re-simulated at every check)
    max_gap_s: float = 60.0
    debounce: DebounceConfig = DebounceConfig(raise_after_s=120.0, clear_after_s=120.0)
    #: warm start: a check starts one Gauss–Newton search from the previous check's fit (its
    #: scales, and the SoC its simulation had at the record's new first sample) instead of the
    #: two or three cold starts (≈ 2–3 kernel calls instead of ≈ 12–13); the cold search runs again
    #: when there is no previous fit, the record restarted (a gap), the capacity became free, the
    #: warm fit failed or its residual grew beyond ``warm_rms_ratio`` times the previous one, its
    #: verdict (strong / below clear, either fault) differs from the previous check's, and every
    #: ``cold_every_checks`` checks, so a basin the record no longer supports is left within minutes
    warm_start: bool = True
    warm_rms_ratio: float = 1.2
    cold_every_checks: int = 10
    #: a warm check first tries one step from the previous fit's kernel run carried on over the new
    #: samples (``_fit_extended``: no simulation of the whole record), and fits afresh only when that
    #: step leaves the range its Jacobian was taken over or the residual grew
    extend_fits: bool = True


@dataclass(frozen=True)
class PackHealthEstimate:
    pack: str
    n: int
    initial_soc: float
    delta_r_ohm: float
    resistance_rise: float      # ΔR / (R_s + R_cp0)
    capacity_factor: float
    capacity_loss: float
    se_resistance_rise: float
    se_capacity_loss: float
    residual_rms_v: float


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _linearise(run_voltage, run_soc, voltage, keep, perturbed, eps, min_soc):
    """One Gauss–Newton iteration's linearisation, in one compiled pass over the record (numpy spent
    a dozen array operations of the record's length on it): the residual r = measured − simulated
    voltage, the Jacobian's forward differences (n, 3) (a held unknown's column stays zero), the
    samples used (kept so far, finite, model SoC ≥ ``min_soc``: their count is returned before the
    spike cut, as it decides whether the fit goes on) and the MAD spike cut (|r − median| > 5 MAD,
    over the used samples) applied to ``keep`` and the used samples; and the least-squares problem
    (the used rows of the free unknowns' columns — ``perturbed`` are the free unknowns — and their
    residuals). Returns (r, jac, use, keep, count, a_used, r_used): the same numbers as the numpy
    formulation (elementwise, medians by selection, copies)."""
    n = voltage.shape[0]
    r = np.empty(n)
    jac = np.zeros((n, 3))
    use = np.empty(n, dtype=np.bool_)
    count = 0
    for i in range(n):
        r[i] = voltage[i] - run_voltage[0, i]
        for k in range(perturbed.shape[0]):
            j = perturbed[k]
            jac[i, j] = (run_voltage[1 + k, i] - run_voltage[0, i]) / eps[j]
        use[i] = keep[i] and np.isfinite(r[i]) and run_soc[i] >= min_soc
        count += use[i]
    if count < 20:
        return r, jac, use, keep, count, np.empty((0, perturbed.shape[0])), np.empty(0)
    res = np.empty(count)
    k = 0
    for i in range(n):
        if use[i]:
            res[k] = r[i]
            k += 1
    centre = median_by_selection(res)
    for i in range(count):
        res[i] = abs(res[i] - centre)
    mad = 1.4826 * median_by_selection(res) + 1e-6
    kept = np.empty(n, dtype=np.bool_)
    n_used = 0
    for i in range(n):
        kept[i] = keep[i] and not abs(r[i] - centre) > 5.0 * mad
        use[i] = use[i] and kept[i]
        n_used += use[i]
    # the least-squares problem: the used rows of the free unknowns' columns, and their residuals
    a_used = np.empty((n_used, perturbed.shape[0]))
    r_used = np.empty(n_used)
    k = 0
    for i in range(n):
        if use[i]:
            for c in range(perturbed.shape[0]):
                a_used[k, c] = jac[i, perturbed[c]]
            r_used[k] = r[i]
            k += 1
    return r, jac, use, kept, count, a_used, r_used


class _Record:
    """The newest ``capacity`` samples (time, current, voltage, ambient) of one pack, kept as one
    float array so a check reads them without converting thousands of tuples: rows are appended
    into twice the room and moved back to the front when it is full. A sample arrives with every
    pack frame and is read only at a check (every minute): appends wait in a list and go into the
    array in one assignment when the record is next read."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self._rows = np.empty((2 * capacity, 4))
        self._start = self._end = 0
        self._pending: list[tuple] = []
        #: the newest sample's time (None: empty)
        self.last_time: float | None = None

    def __len__(self) -> int:
        self._flush()
        return self._end - self._start

    def __getitem__(self, i: int) -> tuple:
        n = len(self)
        if not -n <= i < n:
            raise IndexError(i)
        return tuple(self._rows[self._start + (i % n)].tolist())

    def __iter__(self):
        return iter(map(tuple, self.array().tolist()))

    def clear(self) -> None:
        self._start = self._end = 0
        self._pending.clear()
        self.last_time = None

    def append(self, row: tuple) -> None:
        self._pending.append(row)
        self.last_time = row[0]
        if len(self._pending) >= self.capacity:
            self._flush()

    def _flush(self) -> None:
        """The waiting rows into the array: the newest ``capacity`` rows stay, oldest first."""
        if not self._pending:
            return
        new = np.array(self._pending, dtype=np.float64)
        self._pending.clear()
        cap, k = self.capacity, new.shape[0]
        if k >= cap:
            self._rows[:cap] = new[k - cap:]
            self._start, self._end = 0, cap
            return
        keep = min(self._end - self._start, cap - k)   # the rows already held that stay
        if self._end + k > self._rows.shape[0]:
            self._rows[:keep] = self._rows[self._end - keep:self._end]
            self._end = keep
        self._start = self._end - keep
        self._rows[self._end:self._end + k] = new
        self._end += k

    def array(self) -> np.ndarray:
        """(n, 4) rows, oldest first (a view: valid until the next append)."""
        self._flush()
        return self._rows[self._start:self._end]


def _scaled(params: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Pack parameter rows for theta = (resistance scale, capacity scale, initial SoC) rows."""
    p = np.repeat(params[None], theta.shape[0], axis=0)
    for k in (kernel.I_RS, kernel.I_RCP0):
        p[:, k] *= theta[:, 0]
    for k in (kernel.I_CB, kernel.I_QMAX, kernel.I_CMAX):
        p[:, k] *= theta[:, 1]
    return p


def fit_pack_residual(params: np.ndarray, t: np.ndarray, current: np.ndarray, voltage: np.ndarray,
                      ambient: np.ndarray, min_soc: float = 0.2, iterations: int = 10,
                      fit_capacity: bool = True) -> tuple | None:
    """Gauss–Newton fit of theta = (resistance scale, capacity scale, initial SoC) to a pack's
    voltage record, through the kernel (Jacobian by forward differences: the base and one
    perturbed vector per free unknown in ONE ``simulate_packs`` call per iteration). Spikes are cut with a MAD rule.

    Returns (theta, standard errors, residual rms, samples used) or None if the record cannot
    separate the parameters (too short, or a current that never changes). With ``fit_capacity``
    False the capacity scale stays at 1 (its standard error is then inf): early in a flight the
    record cannot tell a small pack from a weak one, and holding the capacity lets the resistance
    be read correctly from the current steps alone."""
    fit = _fit_cold(params, t, current, voltage, ambient, min_soc, iterations, fit_capacity)
    return None if fit is None else fit[:4]


def _fit_cold(params, t, current, voltage, ambient, min_soc, iterations, fit_capacity):
    """``fit_pack_residual``'s search, returning the fitted run's SoC trajectory too (a warm start's
    initial SoC for the next check)."""
    dt = np.diff(t, prepend=t[0])
    if t.size < 20 or np.ptp(current) < 1.0:
        return None
    best = None
    # a short record can be explained almost as well by a weak pack as by a small one: start from
    # both readings (and from nominal) and keep the best fit, so the search is not trapped
    starts = ((1.0, 1.0), (2.0, 1.0), (1.0, 0.7)) if fit_capacity else ((1.0, 1.0), (2.0, 1.0))
    for r_scale, c_scale in starts:
        fit = _gauss_newton(params, t, dt, current, voltage, ambient, min_soc, iterations, r_scale, c_scale,
                            fit_capacity)
        if fit is not None and (best is None or fit[2] < best[2]):
            best = fit
    return best


def _fit_warm(params, t, current, voltage, ambient, min_soc, iterations, fit_capacity, theta0):
    """One Gauss–Newton search from ``theta0`` (the previous check's scales and the SoC its run had at
    this record's first sample); None where the record cannot be fitted."""
    if t.size < 20 or np.ptp(current) < 1.0:
        return None
    return _gauss_newton(params, t, np.diff(t, prepend=t[0]), current, voltage, ambient, min_soc, iterations,
                         float(theta0[0]), float(theta0[1]), fit_capacity, soc0=float(theta0[2]))


#: the trust region of one Gauss–Newton step, and the finite-difference perturbations, per unknown
_MAX_STEP = np.array([0.5, 0.15, 0.1])
_EPS = np.array([0.02, 0.005, 0.005])
#: a Gauss–Newton search stops when no unknown moves more than this
_CONVERGED = 1e-4


def _lstsq(a: np.ndarray, b: np.ndarray, rcond: float) -> np.ndarray:
    """``np.linalg.lstsq(a, b, rcond)[0]`` as numba's compiled ``lstsq`` computes it: LAPACK's
    ``dgelsd`` from SciPy's LAPACK (the one numba links to), its workspace from the same query,
    ``b`` copied into a (max(m, n), 1) column, so the same numbers. Called from Python: compiling
    numba's ``lstsq`` cost ≈ 8 s of CPU on a fresh install's first replay (issue 33), a call here
    a few microseconds."""
    from scipy.linalg import lapack

    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise np.linalg.LinAlgError("Array must not contain infs or NaNs.")  # numba's check and words
    m, n = a.shape
    rhs = np.zeros((max(m, n), 1), order="F")
    rhs[:m, 0] = b
    work, iwork, info = lapack.dgelsd_lwork(m, n, 1, rcond)
    if info != 0:
        raise np.linalg.LinAlgError(f"dgelsd workspace query failed (info {info})")
    x, _, _, info = lapack.dgelsd(np.asfortranarray(a), rhs, int(work), iwork, rcond)
    if info > 0:
        raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")
    return x[:n, 0].copy()


def _rcond(a_used: np.ndarray) -> float:
    """``np.linalg.lstsq``'s default ``rcond``: machine precision times the larger dimension."""
    return float(np.finfo(np.float64).eps * max(a_used.shape[0], a_used.shape[1]))


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _run_and_linearise(params, dt, current, ambient, voltage, min_soc, theta, perturbed, eps, keep):
    """One Gauss–Newton iteration's compiled part (``_iterate``): the base and perturbed parameter
    rows at ``theta`` (``_scaled``), their initial states (``kernel.initial_pack_state``), one
    kernel run over the record and ``_linearise``. ``dt``, ``current``, ``ambient`` are (1, n) rows.
    Returns (parameter rows, voltages, SoCs, final states, then ``_linearise``'s seven results)."""
    n = current.shape[1]
    n_vec = 1 + perturbed.shape[0]
    p = np.empty((n_vec, params.shape[0]))
    x0 = np.empty((n_vec, kernel.N_PACK_STATE))
    run_voltage = np.empty((n_vec, n))
    run_temperature = np.empty((n_vec, n))
    run_soc = np.empty((n_vec, n))
    states = np.empty((1, 1, kernel.N_PACK_STATE))
    final = np.empty((n_vec, kernel.N_PACK_STATE))
    for v in range(n_vec):
        th = theta.copy()
        if v > 0:
            th[perturbed[v - 1]] += eps[perturbed[v - 1]]
        for i in range(params.shape[0]):
            p[v, i] = params[i]
        p[v, kernel.I_RS] *= th[0]
        p[v, kernel.I_RCP0] *= th[0]
        p[v, kernel.I_CB] *= th[1]
        p[v, kernel.I_QMAX] *= th[1]
        p[v, kernel.I_CMAX] *= th[1]
        soc = th[2]
        r_cp = p[v, kernel.I_RCP0] + p[v, kernel.I_RCP1] * np.exp(p[v, kernel.I_RCP2] * (1.0 - soc))
        x0[v, kernel.S_QB] = p[v, kernel.I_QMAX] - (1.0 - soc) * p[v, kernel.I_CMAX]
        x0[v, kernel.S_QCP] = current[0, 0] * r_cp * p[v, kernel.I_CCP]
        x0[v, kernel.S_QS] = current[0, 0] * p[v, kernel.I_RS] * p[v, kernel.I_CS]
        x0[v, kernel.S_T] = ambient[0, 0]
    kernel._simulate_packs(p, x0, dt, current, ambient, kernel.DEFAULT_MAX_DT, run_voltage, run_temperature,
                           run_soc, states, False, final)
    r, jac, use, keep, n_use, a_used, r_used = _linearise(run_voltage, run_soc[0], voltage, keep, perturbed, eps,
                                                          min_soc)
    return p, run_voltage, run_soc, final, r, jac, use, keep, n_use, a_used, r_used


def _iterate(params, dt, current, ambient, voltage, min_soc, iterations, theta, perturbed, eps, max_step):
    """A Gauss–Newton search's iterations: per iteration one compiled call (``_run_and_linearise``:
    the rows, their kernel run, the linearisation), the least-squares step (``_lstsq``, as
    ``np.linalg.lstsq`` with its default ``rcond``), the trust region and the bounds; the same
    operations in the same order as the numpy formulation, so the same numbers. Returns (ok, theta,
    step, r, jac, use, and the last run: the theta it ran at, its parameter rows, voltages, SoCs and
    final states); ok is False when fewer than 20 samples were usable."""
    if iterations < 1:
        raise ValueError(f"iterations: at least 1, got {iterations}")
    keep = np.ones(current.shape[1], dtype=np.bool_)
    theta = theta.copy()
    step = np.zeros(3)
    for _ in range(iterations):
        theta_run = theta.copy()
        p, run_voltage, run_soc, final, r, jac, use, keep, n_use, a_used, r_used = _run_and_linearise(
            params, dt, current, ambient, voltage, min_soc, theta, perturbed, eps, keep)
        if n_use < 20:
            return False, theta, step, r, jac, use, theta_run, p, run_voltage, run_soc, final
        solution = _lstsq(a_used, r_used, _rcond(a_used))
        step = np.zeros(3)
        step[perturbed] = solution
        # a trust region: the knee makes the first linearisation poor far from the answer
        shrink = np.min(max_step / (np.abs(step) + 1e-12))
        step = step * min(1.0, shrink)
        theta = theta + step
        theta[0] = max(theta[0], 0.05)
        theta[1] = min(max(theta[1], 0.05), 2.0)
        theta[2] = min(max(theta[2], 0.0), 1.1)  # above 1 only to stay unbiased near full
        if np.all(np.abs(step) < _CONVERGED):
            break
    return True, theta, step, r, jac, use, theta_run, p, run_voltage, run_soc, final


@njit(cache=True, nogil=True, fastmath=False, error_model="numpy")
def _carry_on_and_linearise(params, final, prev_voltage, prev_soc, offset, dt, current, ambient, voltage, min_soc,
                            perturbed, eps):
    """``_extend``'s compiled part: the previous run's rows (``params``, states ``final`` after its
    last sample) carried on over the new samples (``dt``, ``current``, ``ambient``: (1, m) rows) and
    joined to its voltages and SoCs from sample ``offset`` on, and the linearisation. Returns
    (voltages, SoCs, final states, then ``_linearise``'s seven results)."""
    n_vec = params.shape[0]
    m = current.shape[1]
    old = prev_voltage.shape[1] - offset
    run_voltage = np.empty((n_vec, old + m))
    run_soc = np.empty((n_vec, old + m))
    # element loops, not slice assignments: those compile numba's shape-mismatch message (~10 s of
    # CPU on a fresh install's first run, issue 33)
    for v in range(n_vec):
        for k in range(old):
            run_voltage[v, k] = prev_voltage[v, offset + k]
            run_soc[v, k] = prev_soc[v, offset + k]
    final = final.copy()
    if m > 0:
        more_voltage = np.empty((n_vec, m))
        more_soc = np.empty((n_vec, m))
        more_temperature = np.empty((n_vec, m))
        x0 = final.copy()
        kernel._simulate_packs(params, x0, dt, current, ambient, kernel.DEFAULT_MAX_DT, more_voltage,
                               more_temperature, more_soc, np.empty((1, 1, kernel.N_PACK_STATE)), False, final)
        for v in range(n_vec):
            for k in range(m):
                run_voltage[v, old + k] = more_voltage[v, k]
                run_soc[v, old + k] = more_soc[v, k]
    r, jac, use, keep, n_use, a_used, r_used = _linearise(run_voltage, run_soc[0], voltage,
                                                          np.ones(voltage.shape[0], dtype=np.bool_), perturbed, eps,
                                                          min_soc)
    return run_voltage, run_soc, final, r, jac, use, keep, n_use, a_used, r_used


def _extend(params, final, prev_voltage, prev_soc, offset, dt, current, ambient, voltage, min_soc, perturbed, eps):
    """``_fit_extended``'s work: the previous run carried on over the new samples and linearised
    (``_carry_on_and_linearise``, one compiled call), the least-squares step (``_lstsq``, as
    ``np.linalg.lstsq``), and the SoC along the record at the stepped theta to first order. Returns
    (ok, step, r, jac, use, voltages, SoCs, final states, SoC); ok is False when fewer than 20
    samples were usable or the step leaves the Jacobian's range (an unknown moving more than its
    perturbation)."""
    run_voltage, run_soc, final, r, jac, use, _, n_use, a_used, r_used = _carry_on_and_linearise(
        params, final, prev_voltage, prev_soc, offset, dt, current, ambient, voltage, min_soc, perturbed, eps)
    step = np.zeros(3)
    soc = run_soc[0].copy()
    if n_use < 20:
        return False, step, r, jac, use, run_voltage, run_soc, final, soc
    step[perturbed] = _lstsq(a_used, r_used, _rcond(a_used))
    if not np.all(np.abs(step) <= eps):  # also a NaN step
        return False, step, r, jac, use, run_voltage, run_soc, final, soc
    for k, j in enumerate(perturbed.tolist()):
        soc += step[j] * ((run_soc[1 + k] - run_soc[0]) / eps[j])
    return True, step, r, jac, use, run_voltage, run_soc, final, soc


def _row(a) -> np.ndarray:
    """A profile as the kernel's (1, n) shared row."""
    return np.ascontiguousarray(a, dtype=np.float64)[None]


def _gauss_newton(params, t, dt, current, voltage, ambient, min_soc, iterations, r_scale, c_scale, fit_capacity,
                  soc0: float | None = None):
    free = np.array([True, fit_capacity, True])
    if soc0 is None:
        # start from the SoC the first reading implies (the capacity scale leaves the open-circuit
        # curve unchanged: q_max and C_max scale with C_b)
        r_cp = float(kernel.concentration_resistance(params, 0.5))
        v_b = voltage[0] + current[0] * r_scale * (params[kernel.I_RS] + r_cp)
        soc0 = float(kernel.soc_at_bulk_voltage(params, v_b))
    theta = np.array([r_scale, c_scale, min(max(soc0, 0.2), 1.0)])
    # perturbed vectors for the free unknowns only: a held capacity needs no column of its own
    # (its column stays zero, and its step is zero)
    perturbed = np.flatnonzero(free)
    if np.any(dt < 0):
        raise ValueError("dt: time steps must be non-negative (sort and de-duplicate timestamps first)")
    ok, theta, step, r, jac, use, theta_run, p, run_voltage, run_soc, final = _iterate(
        np.ascontiguousarray(params, dtype=np.float64), _row(dt), _row(current), _row(ambient), voltage, min_soc,
        iterations, theta, perturbed, _EPS, _MAX_STEP)
    if not ok:
        return None
    se, rms, n = _uncertainty(t, r, jac, use, step, free)
    return theta, se, rms, n, run_soc[0], _Simulation(theta_run, p, perturbed, run_voltage, run_soc, final)


def _uncertainty(t, r, jac, use, step, free):
    """(standard errors, residual rms, samples used) of a fit's last linearisation (residual ``r``,
    Jacobian ``jac``, samples ``use``) after its last ``step``."""
    ju = jac[use]
    res = r[use] - ju @ step
    n = int(use.sum())
    sigma2 = float(res @ res) / max(n - int(free.sum()), 1)
    jf = ju[:, free]
    cov = np.full((3, 3), np.inf)
    cov[np.ix_(free, free)] = sigma2 * np.linalg.pinv(jf.T @ jf)
    # residuals of a model mismatch are correlated over the R_cp–C_cp time constant and longer:
    # count one independent sample per 30 s rather than per frame
    span = float(t[-1] - t[0])
    inflate = math.sqrt(max(n / max(span / 30.0, 1.0), 1.0))
    se = np.sqrt(np.maximum(np.diag(cov), 0.0)) * inflate
    return se, math.sqrt(float(res @ res) / n), n


@dataclass
class _Simulation:
    """A fit's last kernel run over its record, kept so the next check can extend it instead of
    simulating the record again: the theta it ran at (its SoC is the one at the run's first sample,
    which may lie before the record's), the parameter rows (base, then one perturbed row per free
    unknown), their voltages and SoCs at the record's samples, and their states after the last."""
    theta: np.ndarray
    params: np.ndarray
    perturbed: np.ndarray
    voltage: np.ndarray
    soc: np.ndarray
    final: np.ndarray


def _fit_extended(params, t, current, voltage, ambient, min_soc, prev_t, sim: _Simulation):
    """One Gauss–Newton step over the record ``t`` from the previous check's run ``sim`` over the
    record ``prev_t`` (a warm check on the same record, which only slid): that run's rows are carried
    on over the new samples (the kernel continues a run exactly), the samples that left the record
    are dropped, and the step is taken from the run's theta with its own finite-difference Jacobian.
    The record is not simulated again: a check costs the new samples' simulation and one
    least-squares solve instead of two or three simulations of the whole record. The model differs from
    a fresh fit's only in the state at the record's first sample (carried from the run's start
    instead of settled at that sample's current: the R_cp–C_cp transient, ≈ 10 s of a 25-minute
    record). Returns the fit as ``_gauss_newton`` does, or None where the step leaves the range the
    Jacobian was taken over (any unknown moving more than its perturbation from the run's theta) or the
    records do not line up: then the caller fits the record afresh."""
    offset = int(np.searchsorted(prev_t, t[0]))
    overlap = prev_t.size - offset
    if not (0 < overlap <= t.size and prev_t[offset] == t[0] and np.array_equal(t[:overlap], prev_t[offset:])):
        return None
    # the kernel's time convention: the first new sample's interval starts at the last old one
    ok, step, r, jac, use, run_voltage, run_soc, final, soc = _extend(
        sim.params, sim.final, sim.voltage, sim.soc, offset, _row(np.diff(t[overlap - 1:])), _row(current[overlap:]),
        _row(ambient[overlap:]), voltage, min_soc, sim.perturbed, _EPS)
    if not ok:
        return None
    theta = sim.theta + step
    theta[0] = max(theta[0], 0.05)  # the search's bounds (a step within the perturbations rarely meets them)
    theta[1] = min(max(theta[1], 0.05), 2.0)
    perturbed = sim.perturbed
    free = np.zeros(3, dtype=bool)
    free[perturbed] = True
    se, rms, n = _uncertainty(t, r, jac, use, step, free)
    fitted = np.array([theta[0], theta[1], soc[0]])
    return fitted, se, rms, n, soc, _Simulation(sim.theta, sim.params, perturbed, run_voltage, run_soc, final)


@dataclass
class _PreviousFit:
    """What a warm start needs of a pack's last fit."""
    theta: np.ndarray
    rms: float
    fit_capacity: bool
    t: np.ndarray          # the record's times at that fit
    soc: np.ndarray        # the fitted run's SoC at those times
    warm_checks: int       # warm fits since the last cold one
    simulation: _Simulation | None = None  # the fit's last kernel run (``_fit_extended``)


class PackHealthMonitor:
    def __init__(self, pack_params: np.ndarray, config: PackHealthConfig = PackHealthConfig(),
                 names: tuple[str, ...] = PACK_NAMES):
        self.params = np.asarray(pack_params, dtype=np.float64)
        self.config = config
        #: the packs' names, in the rows' order (a vehicle description's, or the paper's)
        self.names = tuple(names)
        self._buf: list[_Record] = [_Record(config.max_samples) for _ in self.names]
        self._last_check = -math.inf
        self._debounce = {(ty, n): Debouncer(config.debounce) for n in self.names
                          for ty in (PACK_CAPACITY_LOSS, PACK_RESISTANCE_RISE)}
        self.faults: dict[tuple[str, str], Fault] = {}
        self.latest: dict[str, PackHealthEstimate] = {}
        self._previous: list[_PreviousFit | None] = [None] * len(self.names)
        #: each pack's last check's verdicts (``_verdicts``): a warm fit that changes them is re-done cold
        self._verdict: list[tuple | None] = [None] * len(self.names)
        #: how the checks' fits ran (cold: the multi-start search; warm: one start from the last fit;
        #: warm_rejected: a warm fit whose residual grew, thrown away for the cold search;
        #: warm_unconfirmed: one whose verdict changed, re-done cold; both also counted as cold)
        self.fit_counts = {"cold": 0, "warm": 0, "extended": 0, "warm_rejected": 0, "warm_unconfirmed": 0}

    def _warm_applies(self, b: int, t: np.ndarray, fit_capacity: bool) -> bool:
        """Whether pack ``b``'s previous fit may start this check's (record ``t``)."""
        cfg, prev = self.config, self._previous[b]
        return (cfg.warm_start and prev is not None and prev.fit_capacity == fit_capacity
                and prev.warm_checks + 1 < cfg.cold_every_checks and prev.t[0] <= t[0] <= prev.t[-1])

    def _keep(self, b: int, t: np.ndarray, fit, fit_capacity: bool, kinds: tuple):
        """Remember pack ``b``'s fit for the next check's start; returns (the fit's estimate part, kinds)."""
        if fit is None:
            self._previous[b] = None
            return None, kinds
        prev = self._previous[b]
        self._previous[b] = _PreviousFit(fit[0].copy(), fit[2], fit_capacity, t, fit[4],
                                         prev.warm_checks + 1 if kinds[0] == "warm" else 0, fit[5])
        return fit[:4], kinds

    def _extend_record(self, b: int, arr: np.ndarray, fit_capacity: bool):
        """The check's fit of pack ``b``'s record by extending the previous fit's run
        (``_fit_extended``), as ``_fit_record`` returns it, or None where that does not apply or its
        step is refused (then ``_fit_record`` fits the record)."""
        cfg, prev = self.config, self._previous[b]
        t = arr[:, 0]
        if not (cfg.extend_fits and self._warm_applies(b, t, fit_capacity) and prev.simulation is not None):
            return None
        fit = _fit_extended(self.params[b], t, arr[:, 1], arr[:, 2], arr[:, 3], cfg.min_soc, prev.t, prev.simulation)
        if fit is None or not fit[2] <= cfg.warm_rms_ratio * prev.rms:
            return None
        return self._keep(b, t, fit, fit_capacity, ("warm", "extended"))

    def _fit_record(self, b: int, arr: np.ndarray, fit_capacity: bool, cold: bool = False):
        """The check's fit of pack ``b``'s record afresh: warm from the previous fit where it still
        applies, else (or when the warm fit looks trapped) the cold multi-start search. Returns the fit
        (or None) and how it ran, for ``fit_counts`` (counted by the caller: the packs' fits run on threads)."""
        cfg = self.config
        p = self.params[b]
        t, cur, v, amb = arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3]
        prev = self._previous[b]
        fit, kinds = None, ("cold",)
        if not cold and self._warm_applies(b, t, fit_capacity):
            theta0 = prev.theta.copy()
            theta0[2] = float(np.interp(t[0], prev.t, prev.soc))
            fit = _fit_warm(p, t, cur, v, amb, cfg.min_soc, 10, fit_capacity, theta0)
            if fit is not None and fit[2] <= cfg.warm_rms_ratio * prev.rms:
                kinds = ("warm",)
            else:
                kinds, fit = ("warm_rejected", "cold"), None
        if fit is None:
            fit = _fit_cold(p, t, cur, v, amb, cfg.min_soc, 10, fit_capacity)
        return self._keep(b, t, fit, fit_capacity, kinds)

    def _estimate(self, b: int, fit) -> PackHealthEstimate:
        p = self.params[b]
        theta, se, rms, n = fit
        r_nom = p[kernel.I_RS] + p[kernel.I_RCP0]
        return PackHealthEstimate(self.names[b], n, float(theta[2]), float((theta[0] - 1.0) * r_nom),
                                  float(theta[0] - 1.0), float(theta[1]), float(1.0 - theta[1]), float(se[0]),
                                  float(se[1]), rms)

    def _judged(self, est: PackHealthEstimate) -> tuple:
        """(fault type, value, standard error, raise threshold, clear threshold) for both faults."""
        cfg = self.config
        return ((PACK_CAPACITY_LOSS, est.capacity_loss, est.se_capacity_loss, cfg.capacity_loss_raise,
                 cfg.capacity_loss_clear),
                (PACK_RESISTANCE_RISE, est.resistance_rise, est.se_resistance_rise, cfg.resistance_rise_raise,
                 cfg.resistance_rise_clear))

    def _verdicts(self, est: PackHealthEstimate | None, drawn: float) -> tuple:
        """What a check's estimate tells the debouncers: (strong, below clear) per fault, or None."""
        if est is None:
            return None
        held = drawn < self.config.min_drawn_for_capacity
        return tuple(None if held and ty == PACK_CAPACITY_LOSS else (value >= hi and value - 2.0 * se_v > lo, value < lo)
                     for ty, value, se_v, hi, lo in self._judged(est))

    def add(self, b: int, time_s: float, current_a: float, voltage_v: float, ambient_c: float,
            ) -> None:
        if not (math.isfinite(current_a) and math.isfinite(voltage_v) and math.isfinite(time_s)):
            return
        buf = self._buf[b]
        last = buf.last_time
        if last is not None:
            if time_s < last:
                return  # out of order: the estimator drops (and counts) it too
            if time_s - last > self.config.max_gap_s:
                buf.clear()
        buf.append((time_s, current_a, voltage_v, ambient_c))

    def due(self, time_s: float) -> bool:
        """Whether ``check`` at ``time_s`` would fit (the caller can skip the call between checks)."""
        return not time_s - self._last_check < self.config.check_every_s

    def check(self, time_s: float) -> list[tuple[str, Fault]]:
        if not self.due(time_s):
            return []
        self._last_check = time_s
        events = []

        def record(b: int):
            buf = self._buf[b]
            if len(buf) < self.config.min_samples or buf[-1][0] - buf[0][0] < self.config.min_history_s:
                return None
            arr = buf.array().copy()  # the next fit keeps its times: a copy, not a view of the buffer
            p = self.params[b]
            drawn = float(np.sum(arr[1:, 1] * np.diff(arr[:, 0]))) / p[kernel.I_CMAX]
            return drawn, arr, drawn >= self.config.min_drawn_for_capacity

        records = [record(b) for b in range(len(self.names))]
        # the extensions first, here (≈ 0.5 ms each: a thread's hand-off would cost a good part of
        # that); the records they do not fit are fitted afresh, on the threads available when there
        # are several (the compiled searches release the GIL)
        fits: list[tuple | None] = [None] * len(self.names)
        afresh = []
        for b, rec in enumerate(records):
            extended = None if rec is None else self._extend_record(b, rec[1], rec[2])
            if extended is not None:
                fits[b] = (*rec, *extended)
            elif rec is not None:
                afresh.append(b)
        for b, fitted in zip(afresh, thread_map(lambda b: self._fit_record(b, records[b][1], records[b][2]), afresh)):
            fits[b] = (*records[b], *fitted)
        for b, name in enumerate(self.names):
            if fits[b] is None:
                continue
            drawn, arr, fit_capacity, fit_b, kinds = fits[b]
            est = None if fit_b is None else self._estimate(b, fit_b)
            if kinds[0] == "warm" and self._verdicts(est, drawn) != self._verdict[b]:
                # a warm fit that would change what the debouncers are told is confirmed by the cold
                # search: a fault's raise or clear never rests on a warm fit's change alone
                fit_b, cold = self._fit_record(b, arr, fit_capacity, cold=True)
                kinds = ("warm_unconfirmed", *cold)
                est = None if fit_b is None else self._estimate(b, fit_b)
            for kind in kinds:
                self.fit_counts[kind] += 1
            self._verdict[b] = self._verdicts(est, drawn)
            if est is None:
                continue
            rms, n = est.residual_rms_v, est.n
            self.latest[name] = est
            cfg = self.config
            for ty, value, se_v, hi, lo in self._judged(est):
                if ty == PACK_CAPACITY_LOSS and drawn < cfg.min_drawn_for_capacity:
                    continue  # the fit held the capacity: no verdict on it yet
                strong = value >= hi and value - 2.0 * se_v > lo
                deb = self._debounce[(ty, name)]
                ev = deb.update(time_s, strong, value < lo)
                conf = 0.5 * (1.0 + math.erf((value - lo) / (max(se_v, 1e-6) * math.sqrt(2.0))))
                evidence = {"delta_r_ohm": round(est.delta_r_ohm, 5), "capacity_factor": round(est.capacity_factor, 4),
                            "initial_soc": round(est.initial_soc, 4), "residual_rms_v": round(rms, 4), "n_samples": n,
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
