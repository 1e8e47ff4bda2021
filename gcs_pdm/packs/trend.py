"""Across flights: each pack's capacity fade and resistance growth against equivalent full cycles,
the retirement forecast with its interval, and the priors the next flight's estimator starts from
(pure).

The wear law fitted is a power law in equivalent cycles n, ``y(n) = y0 · (1 ∓ a·n^b)``: b ≈ 0.5 is
diffusion-limited SEI growth (fade slowing down), b ≈ 1 a steady loss, b > 1 an accelerating one
(plating, a knee). It is fitted with the threshold's crossing N itself as a parameter (as log N,
``a = |ratio - 1| / N^b``), by weighted least squares on the health points' σ; the forecast's
interval is log N's from the fit's covariance (scaled by the residuals when they exceed the σ). Limits (docs/packs.md): the law is extrapolated; a
knee that has not begun by the last point cannot be foreseen; fewer than ``MIN_POINTS`` points give
no forecast.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: a trend needs this many health points with the quantity known
MIN_POINTS = 4
#: the forecast interval's coverage (central)
INTERVAL = 0.8
#: the exponent's range
B_RANGE = (0.3, 2.5)


@dataclass(frozen=True)
class WearFit:
    """``y(n) = y0 · (1 + sign·a·n^b)`` with ``a = step / N^b``: N is where y reaches
    ``y0 · (1 + sign·step)`` (the threshold), fitted directly as log N so its interval is the fit's."""
    y0: float
    log_n: float
    b: float
    cov: np.ndarray  # of (y0, log N, b)
    residual_scale: float
    n_points: int
    sign: float  # -1: fade (capacity), +1: growth (resistance)
    step: float  # |threshold ratio - 1|

    @property
    def a(self) -> float:
        return self.step / math.exp(self.log_n) ** self.b

    def at(self, n) -> np.ndarray:
        n = np.maximum(np.asarray(n, float), 0.0)
        return self.y0 * (1.0 + self.sign * self.a * n ** self.b)


def _model(n, y0, log_n, b, sign, step):
    return y0 * (1.0 + sign * step * (np.maximum(n, 0.0) / np.exp(log_n)) ** b)


def fit_wear(cycles, values, sds, sign: float, ratio: float) -> WearFit | None:
    """Fit ``y0·(1 + sign·|ratio-1|·(n/N)^b)`` to (cycles, values ± sds); None with fewer than MIN_POINTS."""
    from scipy.optimize import curve_fit

    step = abs(ratio - 1.0)
    n = np.asarray(cycles, float)
    y = np.asarray(values, float)
    s = np.asarray(sds, float)
    ok = np.isfinite(n) & np.isfinite(y) & np.isfinite(s) & (s > 0)
    n, y, s = n[ok], y[ok], s[ok]
    if n.size < MIN_POINTS:
        return None
    y0_guess = float(np.median(y[: max(2, n.size // 4)]))
    span = max(float(n.max()), 1e-3)
    best = None
    for b0 in (0.5, 1.0, 1.5):
        for n0 in (span, 3.0 * span, 10.0 * span):
            try:
                p, cov = curve_fit(lambda x, y0, ln, b: _model(x, y0, ln, b, sign, step), n, y,
                                   p0=(y0_guess, math.log(n0), b0), sigma=s, absolute_sigma=True,
                                   bounds=([0.0, math.log(span) - 5.0, B_RANGE[0]],
                                           [np.inf, math.log(span) + 12.0, B_RANGE[1]]), maxfev=5000)
            except (RuntimeError, ValueError):
                continue
            chi2 = float(np.sum(((y - _model(n, *p, sign, step)) / s) ** 2))
            if best is None or chi2 < best[0]:
                best = (chi2, p, cov)
    if best is None:
        return None
    chi2, p, cov = best
    dof = max(n.size - 3, 1)
    scale = math.sqrt(max(chi2 / dof, 1.0))  # residuals beyond the σ widen the interval, never narrow it
    cov = np.asarray(cov, float) * scale ** 2
    if not np.all(np.isfinite(cov)):
        cov = np.diag([max(abs(p[0]) * 0.05, 1e-9), 4.0, 1.0])
    return WearFit(float(p[0]), float(p[1]), float(p[2]), cov, scale, int(n.size), sign, step)


@dataclass(frozen=True)
class Forecast:
    """Equivalent cycles (from the pack's first) at which the threshold is crossed: the fit's and
    its ``INTERVAL`` interval; None with ``why`` when the data cannot say."""
    threshold: str
    cycles: float | None
    low: float | None
    high: float | None
    why: str | None = None

    def to_dict(self) -> dict:
        return {"threshold": self.threshold, "cycles": self.cycles, "low": self.low, "high": self.high,
                "interval": INTERVAL, "why": self.why}


def crossing(fit: WearFit | None, label: str, *, horizon_factor: float = 50.0, last_cycles: float = 0.0) -> Forecast:
    """Where ``fit`` reaches its threshold, with the interval of log N (normal, from the fit's
    covariance); past ``horizon_factor`` × the cycles flown it is "beyond reach"."""
    if fit is None:
        return Forecast(label, None, None, None, f"fewer than {MIN_POINTS} health points with it known")
    horizon = max(last_cycles, 1.0) * horizon_factor
    z = 1.2815515655446004  # the 80 % central interval of a normal
    sd = math.sqrt(max(float(fit.cov[1, 1]), 0.0))
    central = math.exp(fit.log_n)
    lo, hi = (math.exp(min(fit.log_n + d, 700.0)) for d in (-z * sd, z * sd))  # 700: exp's range
    if central > horizon:
        return Forecast(label, None, lo if lo <= horizon else None, None,
                        f"no {label} within {horizon:.0f} equivalent cycles on the trend so far")
    return Forecast(label, central, lo, hi if hi <= horizon else None)


@dataclass(frozen=True)
class PackTrend:
    pack_id: str
    points: int
    cycles_so_far: float
    capacity: WearFit | None
    resistance: WearFit | None
    capacity_forecast: Forecast
    resistance_forecast: Forecast
    retirement: Forecast

    def to_dict(self) -> dict:
        def fit_dict(f: WearFit | None):
            if f is None:
                return None
            sd = np.sqrt(np.maximum(np.diag(f.cov), 0.0))
            return {"y0": f.y0, "a": f.a, "b": f.b, "crossing_cycles": math.exp(f.log_n), "y0_sd": float(sd[0]),
                    "log_crossing_sd": float(sd[1]), "b_sd": float(sd[2]), "residual_scale": f.residual_scale,
                    "points": f.n_points}
        return {"pack_id": self.pack_id, "points": self.points, "cycles_so_far": self.cycles_so_far,
                "capacity_fit": fit_dict(self.capacity), "resistance_fit": fit_dict(self.resistance),
                "capacity_forecast": self.capacity_forecast.to_dict(),
                "resistance_forecast": self.resistance_forecast.to_dict(), "retirement": self.retirement.to_dict()}


def cumulative_cycles(points) -> np.ndarray:
    """Equivalent full cycles at each flight's start, in flight order (the first flight at 0)."""
    efc = np.array([p.equivalent_cycles for p in points], float)
    return np.concatenate([[0.0], np.cumsum(efc)[:-1]]) if efc.size else efc


def pack_trend(pack_id: str, points, *, capacity_fraction: float = 0.8, resistance_factor: float = 1.5,
               cycles=None) -> PackTrend:
    """``points``: the pack's HealthPoints in flight order; ``cycles``: their equivalent cycles (default
    :func:`cumulative_cycles`)."""
    points = list(points)
    n = cumulative_cycles(points) if cycles is None else np.asarray(cycles, float)
    last = float(n[-1] + points[-1].equivalent_cycles) if points else 0.0
    cap = [(c, p.capacity_ah, p.capacity_sd_ah) for c, p in zip(n, points) if p.capacity_ah is not None]
    res = [(c, p.resistance_25c_ohm, p.resistance_sd_ohm) for c, p in zip(n, points) if p.resistance_25c_ohm is not None]
    cap_fit = fit_wear(*zip(*cap), sign=-1.0, ratio=capacity_fraction) if len(cap) >= MIN_POINTS else None
    res_fit = fit_wear(*zip(*res), sign=+1.0, ratio=resistance_factor) if len(res) >= MIN_POINTS else None
    cf = crossing(cap_fit, f"{capacity_fraction:.0%} capacity", last_cycles=last)
    rf = crossing(res_fit, f"resistance x{resistance_factor:g}", last_cycles=last)
    known = [f for f in (cf, rf) if f.cycles is not None]
    if known:
        first = min(known, key=lambda f: f.cycles)
        lows = [f.low for f in (cf, rf) if f.low is not None]
        retire = Forecast(first.threshold, first.cycles, min(lows) if lows else None, first.high)
    else:
        retire = Forecast("retirement", None, None, None, "; ".join(f.why for f in (cf, rf) if f.why))
    return PackTrend(pack_id, len(points), last, cap_fit, res_fit, cf, rf, retire)


def estimator_priors(points) -> dict | None:
    """What the next flight's estimator starts from for this pack: its latest known capacity and
    resistance at 25 °C, each with its σ (None: no point knows it), and the latest flight's curve fit
    (``packs.flight_curve``). The hook for the estimator's priors (docs/packs.md): {"capacity_ah",
    "capacity_sd_ah", "capacity_depth_of_discharge" (the SoC used between the rests it was read
    from), "resistance_25c_ohm", "resistance_sd_ohm", "curve", "from_flight_end_s"}."""
    points = list(points)
    if not points:
        return None
    cap = next((p for p in reversed(points) if p.capacity_ah is not None), None)
    res = next((p for p in reversed(points) if p.resistance_25c_ohm is not None), None)
    curve = next((p.curve for p in reversed(points) if p.curve and not p.curve.get("why")), None)
    return {"capacity_ah": cap.capacity_ah if cap else None, "capacity_sd_ah": cap.capacity_sd_ah if cap else None,
            "capacity_depth_of_discharge": cap.depth_of_discharge if cap else None,
            "resistance_25c_ohm": res.resistance_25c_ohm if res else None,
            "resistance_sd_ohm": res.resistance_sd_ohm if res else None,
            "curve": curve, "from_flight_end_s": points[-1].end_s}
