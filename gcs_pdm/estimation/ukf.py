"""Batched unscented-transform helpers shared by the pack and motor filters.

The filters here have a nonlinear process (the kernel's step: R_cp depends on SoC) and *linear*
observations (terminal voltage and temperature are linear in the kernel's state), so the
unscented transform is only needed for the prediction; the update is the exact Kalman update,
done one scalar observation at a time so that a missing or gated channel simply drops out.

Sigma points: the symmetric set with kappa = 0 (weights 1/2n, centre weight 0) — every weight
positive, so the predicted covariance stays positive semi-definite without repair.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gcs_pdm.models import kernel


def sigma_points(mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(m, n) means and (m, n, n) covariances -> (m, 2n, n) sigma points."""
    m, n = mean.shape
    # a covariance driven to the edge of PSD by round-off gets a tiny jitter rather than a crash
    try:
        chol = np.linalg.cholesky(n * cov)
    except np.linalg.LinAlgError:
        jitter = 1e-9 * np.einsum("kii->ki", cov).max(axis=1)[:, None, None] * np.eye(n)
        chol = np.linalg.cholesky(n * (0.5 * (cov + cov.transpose(0, 2, 1)) + jitter + 1e-12 * np.eye(n)))
    offsets = chol.transpose(0, 2, 1)  # rows are the columns of the factor
    return np.concatenate([mean[:, None, :] + offsets, mean[:, None, :] - offsets], axis=1)


def recombine(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m, 2n, n) propagated sigma points -> means (m, n) and covariances (m, n, n)."""
    mean = points.mean(axis=1)
    dev = points - mean[:, None, :]
    cov = np.einsum("kji,kjl->kil", dev, dev) / points.shape[1]
    return mean, cov


def scalar_update(mean: np.ndarray, cov: np.ndarray, h: np.ndarray, z: np.ndarray, r: float | np.ndarray,
                  gate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Kalman update of rows with a linear scalar observation z = h·x + noise(r), gated.

    mean (m, n), cov (m, n, n), h (m, n), z (m,). Rows whose normalised innovation exceeds
    ``gate`` are left untouched. Returns (mean, cov, innovation, normalised innovation)."""
    r = np.broadcast_to(np.asarray(r, dtype=np.float64), z.shape)
    ph = np.einsum("kij,kj->ki", cov, h)
    s = np.einsum("ki,ki->k", h, ph) + r
    nu = z - np.einsum("ki,ki->k", h, mean)
    norm = nu / np.sqrt(s)
    ok = np.abs(norm) <= gate
    gain = ph / s[:, None]
    gain[~ok] = 0.0
    mean = mean + gain * nu[:, None]
    # Joseph form keeps the covariance symmetric and PSD with any gain
    eye = np.eye(mean.shape[1])
    a = eye - gain[:, :, None] * h[:, None, :]
    cov = np.einsum("kij,kjl,kml->kim", a, cov, a) + (r[:, None] * gain)[:, :, None] * gain[:, None, :]
    return mean, cov, nu, norm


# ---- compiled filter steps -------------------------------------------------------------------------
#
# The live link and a replay step one pack (or one motor) per telemetry frame: at that size the
# numpy version above spends its time in array overhead, not arithmetic. These compiled steps do the
# same sums — the same sigma points, the kernel's own ``_pack_advance``/``_thermal_advance``, the
# same gated scalar updates in Joseph form, the same re-lock — one row at a time, in place.

def as_rows(a, shape) -> np.ndarray:
    """An argument of the compiled steps as a writable contiguous float64 array of ``shape`` (scalars
    broadcast; ``kernel.owned``: one compiled version per step). Called for every argument of every
    frame's step, so the two common cases skip ``broadcast_to`` (several µs each): an array that is
    already one, and a scalar."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.shape == shape and a.flags.c_contiguous \
            and a.flags.writeable:
        return a
    if isinstance(a, (float, int)):
        return np.full(shape, float(a))
    return kernel.owned(np.broadcast_to(np.asarray(a, dtype=np.float64), shape))


_JIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")
_N = kernel.N_PACK_STATE
#: columns of a consistency window's integer array (``pack_filter.ConsistencyWindow.ints``)
(W_POS, W_COUNT, W_ACTIVE, W_QUIET) = range(4)


@njit(**_JIT)
def _cholesky_scaled(cov, scale, out):
    """Lower factor of ``scale * cov`` into ``out``; False if not positive definite."""
    n = cov.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = scale * cov[i, j]
            for k in range(j):
                s -= out[i, k] * out[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                out[i, i] = math.sqrt(s)
            else:
                out[i, j] = s / out[j, j]
        for j in range(i + 1, n):
            out[i, j] = 0.0
    return True


@njit(**_JIT)
def _sigma_factor(cov, chol):
    """``sigma_points``' factor of n·cov, with its jitter fallback for a round-off-edge covariance."""
    n = cov.shape[0]
    if _cholesky_scaled(cov, float(n), chol):
        return
    big = cov[0, 0]
    for i in range(1, n):
        big = max(big, cov[i, i])
    fixed = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            fixed[i, j] = 0.5 * (cov[i, j] + cov[j, i])
        fixed[i, i] += 1e-9 * big + 1e-12
    if not _cholesky_scaled(fixed, float(n), chol):
        raise np.linalg.LinAlgError("covariance is not positive semi-definite")


@njit(**_JIT)
def _scalar_update_row(mean, cov, h, z, r, gate):
    """``scalar_update`` for one row, in place; returns (innovation, normalised innovation)."""
    n = mean.shape[0]
    ph = np.empty(n)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += cov[i, j] * h[j]
        ph[i] = s
    s = r
    nu = z
    for i in range(n):
        s += h[i] * ph[i]
        nu -= h[i] * mean[i]
    norm = nu / math.sqrt(s)
    if not abs(norm) <= gate:
        return nu, norm  # gain 0: the Joseph form leaves mean and covariance as they are
    gain = ph / s
    for i in range(n):
        mean[i] += gain[i] * nu
    a = np.eye(n)
    for i in range(n):
        for j in range(n):
            a[i, j] -= gain[i] * h[j]
    ac = a @ cov
    new = ac @ a.T
    for i in range(n):
        for j in range(n):
            cov[i, j] = new[i, j] + r * gain[i] * gain[j]
    return nu, norm


@njit(**_JIT)
def _observe(mean, cov, h, z, r, gate, relock_after, relock_inflation, ch, b, last_innovation,
             rejected_total, rejected_in_row, relocks):
    """One gated channel of one row, with the filters' re-lock rule (see pack_filter's docstring).
    Returns the innovation and its normalised value (before any re-lock)."""
    nu, norm = _scalar_update_row(mean, cov, h, z, r, gate)
    last_innovation[b, ch] = nu
    if abs(norm) > gate:
        rejected_total[b, ch] += 1
        rejected_in_row[b, ch] += 1
    else:
        rejected_in_row[b, ch] = 0
    if rejected_in_row[b, ch] >= relock_after:
        for i in range(cov.shape[0]):
            for j in range(cov.shape[1]):
                cov[i, j] *= relock_inflation
        _scalar_update_row(mean, cov, h, z, r, np.inf)
        relocks[b] += 1
        rejected_in_row[b, ch] = 0
    return nu, norm


@njit(**_JIT)
def _window_push(b, ch, nu, norm, window):
    """Add one update's innovation to row ``b``'s model-consistency window on channel ``ch``.

    ``window`` is a ``ConsistencyWindow``'s arrays (``buf``, ``ints``, ``sums``, ``levels``; see
    ``pack_filter``; four arrays, not eight: each array costs its unboxing on every call);
    ``levels[ch]`` holds the raise level, the clear level and the clip. The squared normalised
    innovation enters clipped: an outlier then moves the window mean by at most clip/N, while a
    model that misses every sample still fills it. Raise above the raise level once the window is
    full, clear below the clear level (hysteresis). Rows still settling after a gap (``quiet``) are
    not judged. Returns 1 if the row's state flipped, else 0."""
    buf, ints, sums, levels = window
    if ints[b, ch, W_QUIET] > 0:
        ints[b, ch, W_QUIET] -= 1
        return 0
    n = buf.shape[3]
    sq = min(norm * norm, levels[ch, 2])
    k = ints[b, ch, W_POS]
    if ints[b, ch, W_COUNT] >= n:
        sums[b, ch, 0] -= buf[b, ch, 0, k]
        sums[b, ch, 1] -= buf[b, ch, 1, k]
    else:
        ints[b, ch, W_COUNT] += 1
    buf[b, ch, 0, k] = sq
    buf[b, ch, 1, k] = nu
    sums[b, ch, 0] += sq
    sums[b, ch, 1] += nu
    ints[b, ch, W_POS] = (k + 1) % n
    if ints[b, ch, W_COUNT] >= n:
        stat = sums[b, ch, 0] / n
        if ints[b, ch, W_ACTIVE] == 0 and stat > levels[ch, 0]:
            ints[b, ch, W_ACTIVE] = 1
            return 1
        if ints[b, ch, W_ACTIVE] == 1 and stat < levels[ch, 1]:
            ints[b, ch, W_ACTIVE] = 0
            return 1
    return 0


@njit(**_JIT)
def _observe_channel(m, c, h, z, r, dt, ch, b, gate, relock_after, relock_inflation, last_innovation,
                     rejected_total, rejected_in_row, relocks, window):
    """One pack channel (``ch`` 0 voltage, 1 temperature; ``z`` NaN = not measured), gated, and
    its innovation into the consistency window.

    The window takes one update per channel per advance of time: frames sharing one message-time
    stamp (a link that stamps untimed messages with the last timed one) were measured over the
    interval before it, so their innovations are not independent draws. A gated sample after an
    accepted one may be a lone spike and is left out too; the second and later of a run are a
    model the data leave behind."""
    if not math.isfinite(z):
        return 0
    run = rejected_in_row[b, ch]
    nu, norm = _observe(m, c, h, z, r, gate, relock_after, relock_inflation, ch, b,
                        last_innovation, rejected_total, rejected_in_row, relocks)
    if dt > 0.0 and (abs(norm) <= gate or run > 0):
        return _window_push(b, ch, nu, norm, window)
    return 0


@njit(**_JIT)
def _quiet_after_gap(window, b, dt):
    """After a gap longer than the window's ``gap_s`` the next updates are not judged: the current
    held over the gap was a guess, and the innovations show that, not the model."""
    levels, ints = window[3], window[1]
    if dt > levels[0, 3]:
        ints[b, 0, W_QUIET] = int(levels[0, 4])
        ints[b, 1, W_QUIET] = int(levels[0, 4])


@njit(inline="always", **_JIT)
def _sigma_point(m, chol, s, x):
    """Sigma point ``s`` of the symmetric set (m ± the columns of the factor of n·cov) into ``x``."""
    n = m.shape[0]
    sign = 1.0 if s < n else -1.0
    col = s % n
    for i in range(n):
        x[i] = m[i] + sign * chol[i, col]


@njit(**_JIT)
def _moments_into(pts, m, c, q, dt):
    """Mean and covariance of propagated sigma points ``pts`` (2n, n) into ``m``, ``c``, plus ``q dt``."""
    two_n, n = pts.shape
    for i in range(n):
        acc = 0.0
        for s in range(two_n):
            acc += pts[s, i]
        m[i] = acc / two_n
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for s in range(two_n):
                acc += (pts[s, i] - m[i]) * (pts[s, j] - m[j])
            c[i, j] = acc / two_n + q[i, j] * dt


@njit(**_JIT)
def _pack_row(params, mean, cov, b, dt, current, ambient, voltage, temperature, q, h_v, h_t, r_v, r_t, gate,
              relock_after, relock_inflation, max_dt, last_innovation, rejected_total, rejected_in_row, relocks,
              window, chol, pts, x):
    """One frame of pack row ``b`` (``pack_step_rows``' body; ``chol``, ``pts``, ``x`` scratch).
    Returns how many of its consistency states flipped."""
    n = _N
    m, c, p = mean[b], cov[b], params[b]
    _quiet_after_gap(window, b, dt)
    if dt > 0.0:
        _sigma_factor(c, chol)
        for s in range(2 * n):
            _sigma_point(m, chol, s, x)
            kernel._pack_advance(p, x, current, ambient, dt, max_dt)
            for i in range(n):
                pts[s, i] = x[i]
        _moments_into(pts, m, c, q, dt)
    flips = _observe_channel(m, c, h_v[b], voltage, r_v, dt, 0, b, gate, relock_after, relock_inflation,
                             last_innovation, rejected_total, rejected_in_row, relocks, window)
    flips += _observe_channel(m, c, h_t, temperature, r_t, dt, 1, b, gate, relock_after, relock_inflation,
                              last_innovation, rejected_total, rejected_in_row, relocks, window)
    return flips


@njit(**_JIT)
def pack_step_rows(params, mean, cov, idx, dt, current, ambient, voltage, temperature, q, h_v,
                   r_v, r_t, gate, relock_after, relock_inflation, max_dt,
                   last_innovation, rejected_total, rejected_in_row, relocks, window):
    """``PackFilterBank.step`` for rows ``idx``, in place on the bank's arrays (``window``: the
    bank's model-consistency window, a tuple of arrays, see ``_window_push``). Returns how many
    consistency states flipped."""
    n = _N
    chol = np.empty((n, n))
    pts = np.empty((2 * n, n))
    x = np.empty(n)
    h_t = np.zeros(n)
    h_t[n - 1] = 1.0
    flips = 0
    for k in range(idx.shape[0]):
        flips += _pack_row(params, mean, cov, idx[k], dt[k], current[k], ambient[k], voltage[k], temperature[k], q,
                           h_v, h_t, r_v, r_t, gate, relock_after, relock_inflation, max_dt, last_innovation,
                           rejected_total, rejected_in_row, relocks, window, chol, pts, x)
    return flips


#: ``pack_step_one``'s ``consts``: a bank's filter constants in one array
(C_R_V, C_R_T, C_GATE, C_RELOCK_AFTER, C_RELOCK_INFLATION, C_MAX_DT, N_CONSTS) = range(7)


def step_constants(r_v: float, r_t: float, gate: float, relock_after: int, relock_inflation: float,
                   max_dt: float) -> np.ndarray:
    """``pack_step_one``'s ``consts`` array."""
    out = np.empty(N_CONSTS)
    out[[C_R_V, C_R_T, C_GATE, C_RELOCK_AFTER, C_RELOCK_INFLATION, C_MAX_DT]] = (
        r_v, r_t, gate, relock_after, relock_inflation, max_dt)
    return out


# ---- a pack filter bank's storage ------------------------------------------------------------------
#
# A telemetry frame steps one pack, and each argument of a compiled call costs its unboxing on every
# call: twenty arguments, eleven of them arrays, cost more than the step's arithmetic. So a bank
# (``pack_filter.PackFilterBank``) keeps its arrays in one float64 and one int64 buffer, each array a
# view into them, and ``pack_step_one`` takes the two buffers. The int buffer starts with a header:
# the rows, the consistency window's length, then each array's offset in the orders below.

#: the arrays in the float buffer, then those in the int buffer (``pack_shapes`` gives their shapes)
PACK_FLOAT_ARRAYS = ("params", "mean", "cov", "q", "h_v", "consts", "last_innovation",
                     "window_buf", "window_sums", "window_levels", "h_t", "scratch")
PACK_INT_ARRAYS = ("rejected_total", "rejected_in_row", "relocks", "window_ints")
(H_ROWS, H_WINDOW) = range(2)
N_HEADER = 2 + len(PACK_FLOAT_ARRAYS) + len(PACK_INT_ARRAYS)


def pack_shapes(n_rows: int, window: int) -> tuple[tuple[int, ...], ...]:
    """The shapes of a bank's arrays, in the buffers' order (``pack_step_one`` carves the same)."""
    n, s = n_rows, _N
    return ((n, kernel.N_PACK_PARAMS), (n, s), (n, s, s), (s, s), (n, s), (N_CONSTS,), (n, 2),
            (n, 2, 2, window), (n, 2, 2), (2, 5), (s,), (s * s + 2 * s * s + s,), (n, 2), (n, 2), (n,), (n, 2, 4))


def pack_storage(arrays: tuple[np.ndarray, ...], window: int) -> tuple[np.ndarray, np.ndarray]:
    """The two buffers holding copies of a bank's ``arrays`` (in the orders above)."""
    n_rows = arrays[0].shape[0]
    shapes = pack_shapes(n_rows, window)
    got = tuple(a.shape for a in arrays)
    if got != shapes:
        raise ValueError(f"pack_storage: arrays of shapes {got}, expected {shapes}")
    n_float = len(PACK_FLOAT_ARRAYS)
    sizes = [math.prod(sh) for sh in shapes]
    offsets = [0] * len(shapes)
    for k in range(1, len(shapes)):
        offsets[k] = N_HEADER if k == n_float else offsets[k - 1] + sizes[k - 1]
    floats = np.empty(offsets[n_float - 1] + sizes[n_float - 1])
    ints = np.empty(offsets[-1] + sizes[-1], dtype=np.int64)
    ints[:N_HEADER] = [n_rows, window, *offsets]
    for view, a in zip(pack_views(floats, ints), arrays):
        view[...] = a
    return floats, ints


def pack_views(floats: np.ndarray, ints: np.ndarray) -> list[np.ndarray]:
    """A bank's arrays as views into its two buffers (``pack_storage``), in the buffers' order."""
    shapes = pack_shapes(int(ints[H_ROWS]), int(ints[H_WINDOW]))
    n_float = len(PACK_FLOAT_ARRAYS)
    out = []
    for k, (shape, o) in enumerate(zip(shapes, ints[2:N_HEADER].tolist())):
        buf = floats if k < n_float else ints
        out.append(buf[o:o + math.prod(shape)].reshape(shape))
    return out


@njit(**_JIT)
def pack_step_one(floats, ints, b, dt, current, ambient, voltage, temperature):
    """``pack_step_rows`` for the one row ``b`` and plain floats (a telemetry frame): the same
    arithmetic (``_pack_row``) on the same arrays, carved from the bank's two buffers
    (``pack_storage``; the carving is ``pack_shapes``' in code), without the five one-element arrays
    a frame would otherwise build, and with its scratch there too (``h_t``, the temperature row, stays
    e_T; the scratch is written before it is read)."""
    n, w, o = ints[H_ROWS], ints[H_WINDOW], ints[2:N_HEADER]
    s, n_p = _N, kernel.N_PACK_PARAMS
    params = floats[o[0]:o[0] + n * n_p].reshape((n, n_p))
    mean = floats[o[1]:o[1] + n * s].reshape((n, s))
    cov = floats[o[2]:o[2] + n * s * s].reshape((n, s, s))
    q = floats[o[3]:o[3] + s * s].reshape((s, s))
    h_v = floats[o[4]:o[4] + n * s].reshape((n, s))
    consts = floats[o[5]:o[5] + N_CONSTS]
    last_innovation = floats[o[6]:o[6] + n * 2].reshape((n, 2))
    w_buf = floats[o[7]:o[7] + n * 4 * w].reshape((n, 2, 2, w))
    w_sums = floats[o[8]:o[8] + n * 4].reshape((n, 2, 2))
    w_levels = floats[o[9]:o[9] + 10].reshape((2, 5))
    h_t = floats[o[10]:o[10] + s]
    chol = floats[o[11]:o[11] + s * s].reshape((s, s))
    pts = floats[o[11] + s * s:o[11] + 3 * s * s].reshape((2 * s, s))
    x = floats[o[11] + 3 * s * s:o[11] + 3 * s * s + s]
    rejected_total = ints[o[12]:o[12] + n * 2].reshape((n, 2))
    rejected_in_row = ints[o[13]:o[13] + n * 2].reshape((n, 2))
    relocks = ints[o[14]:o[14] + n]
    w_ints = ints[o[15]:o[15] + n * 8].reshape((n, 2, 4))
    return _pack_row(params, mean, cov, b, dt, current, ambient, voltage, temperature, q, h_v, h_t,
                     consts[C_R_V], consts[C_R_T], consts[C_GATE], int(consts[C_RELOCK_AFTER]),
                     consts[C_RELOCK_INFLATION], consts[C_MAX_DT], last_innovation, rejected_total, rejected_in_row,
                     relocks, (w_buf, w_ints, w_sums, w_levels), chol, pts, x)


_NX = kernel.N_EXT_STATE
#: finite-difference steps of the extended variant's voltage linearisation: soc, v_1, v_2, T, s_d
_EXT_FD = np.array([1e-4, 1e-3, 1e-3, 1e-2, 1e-4])


@njit(**_JIT)
def _ext_voltage(p, y, d, x, current):
    """Terminal voltage of an extended pack state at ``current`` (the kernel's own, zero-length step)."""
    return kernel._ext_advance(p, y, d, x, current, 0.0, math.nan, 0.0, 1.0)


@njit(**_JIT)
def ext_pack_step_rows(params, knots_y, knots_d, mean, cov, idx, dt, current, ambient, voltage, temperature, q,
                       r_v, r_t, gate, relock_after, relock_inflation, max_dt,
                       last_innovation, rejected_total, rejected_in_row, relocks, window):
    """The extended-variant pack filter (state ``kernel.EXT_PACK_STATE``) for rows ``idx``, in place.

    Prediction: the unscented transform through the kernel's ``_ext_advance`` (the model's own
    temperature drives its resistances). Update: the terminal voltage is nonlinear in the state
    (OCV(SoC − s_d), the resistances' f(T, SoC), the Butler–Volmer term), so it is linearised at
    the predicted mean by central differences of the kernel's own voltage (an EKF update on the
    UKF's predicted moments): ν = z − V(x̄), H = ∂V/∂x at x̄. Temperature is linear (H = e_T). Returns
    how many consistency states flipped."""
    n = _NX
    chol = np.empty((n, n))
    pts = np.empty((2 * n, n))
    x = np.empty(n)
    h_t = np.zeros(n)
    h_t[kernel.X_T] = 1.0
    h_v = np.empty(n)
    flips = 0
    for k in range(idx.shape[0]):
        b = idx[k]
        m, c, p, y, d = mean[b], cov[b], params[b], knots_y[b], knots_d[b]
        _quiet_after_gap(window, b, dt[k])
        if dt[k] > 0.0:
            _sigma_factor(c, chol)
            for s in range(2 * n):
                _sigma_point(m, chol, s, x)
                kernel._ext_advance(p, y, d, x, current[k], ambient[k], math.nan, dt[k], max_dt)
                for i in range(n):
                    pts[s, i] = x[i]
            _moments_into(pts, m, c, q, dt[k])
        z = voltage[k]
        if math.isfinite(z):
            v0 = _ext_voltage(p, y, d, m, current[k])
            z_lin = z - v0
            for i in range(n):
                x[:] = m
                x[i] = m[i] + _EXT_FD[i]
                hi = _ext_voltage(p, y, d, x, current[k])
                x[i] = m[i] - _EXT_FD[i]
                lo = _ext_voltage(p, y, d, x, current[k])
                h_v[i] = (hi - lo) / (2.0 * _EXT_FD[i])
                z_lin += h_v[i] * m[i]
            flips += _observe_channel(m, c, h_v, z_lin, r_v, dt[k], 0, b, gate, relock_after, relock_inflation,
                                      last_innovation, rejected_total, rejected_in_row, relocks, window)
        flips += _observe_channel(m, c, h_t, temperature[k], r_t, dt[k], 1, b, gate, relock_after, relock_inflation,
                                  last_innovation, rejected_total, rejected_in_row, relocks, window)
    return flips


@njit(**_JIT)
def _motor_row(params, mean, cov, q, dt, current, ambient, temperature, process_var, r, gate, relock_after,
               relock_inflation, rejected_total, rejected_in_row, relocks, h, innovation):
    """One frame of motor row ``q`` (``motor_step_rows``' body; ``h``, ``innovation`` scratch)."""
    m, c = mean[q], cov[q]
    if dt > 0.0:
        sd = math.sqrt(c[0, 0]) if c[0, 0] > 0.0 else math.sqrt(c[0, 0] + 1e-9 * c[0, 0] + 1e-12)
        hi = kernel._thermal_advance(params[q], m[0] + sd, current, ambient, dt)
        lo = kernel._thermal_advance(params[q], m[0] - sd, current, ambient, dt)
        m[0] = 0.5 * (hi + lo)
        c[0, 0] = 0.5 * ((hi - m[0]) ** 2 + (lo - m[0]) ** 2) + process_var * dt
    if math.isfinite(temperature):
        _observe(m, c, h, temperature, r, gate, relock_after, relock_inflation, 0, q,
                 innovation, rejected_total, rejected_in_row, relocks)


@njit(**_JIT)
def motor_step_rows(params, mean, cov, idx, dt, current, ambient, temperature, process_var, r, gate,
                    relock_after, relock_inflation, rejected_total, rejected_in_row, relocks):
    """``MotorThermalFilter.step`` for rows ``idx``, in place (one state per motor)."""
    h = np.ones(1)
    innovation = np.empty((mean.shape[0], 1))
    for k in range(idx.shape[0]):
        _motor_row(params, mean, cov, idx[k], dt[k], current[k], ambient, temperature[k], process_var, r, gate,
                   relock_after, relock_inflation, rejected_total, rejected_in_row, relocks, h, innovation)


#: ``motor_step_one``'s ``consts`` (``pack_step_one``'s, for the motors' thermal filter)
(MC_PROCESS_VAR, MC_R, MC_GATE, MC_RELOCK_AFTER, MC_RELOCK_INFLATION, N_MOTOR_CONSTS) = range(6)


def motor_step_constants(process_var: float, r: float, gate: float, relock_after: int,
                         relock_inflation: float) -> np.ndarray:
    """``motor_step_one``'s ``consts`` array."""
    out = np.empty(N_MOTOR_CONSTS)
    out[[MC_PROCESS_VAR, MC_R, MC_GATE, MC_RELOCK_AFTER, MC_RELOCK_INFLATION]] = (
        process_var, r, gate, relock_after, relock_inflation)
    return out


@njit(**_JIT)
def motor_step_one(params, mean, cov, consts, rejected_total, rejected_in_row, relocks, q, dt, current, ambient,
                   temperature):
    """``motor_step_rows`` for the one row ``q`` and plain floats (a telemetry frame), the filter's
    constants in one array (``motor_step_constants``); the bank's arguments first, as one prebuilt tuple."""
    _motor_row(params, mean, cov, q, dt, current, ambient, temperature, consts[MC_PROCESS_VAR], consts[MC_R],
               consts[MC_GATE], int(consts[MC_RELOCK_AFTER]), consts[MC_RELOCK_INFLATION], rejected_total,
               rejected_in_row, relocks, np.ones(1), np.empty((mean.shape[0], 1)))
