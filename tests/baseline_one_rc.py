"""Test helper: the plain baseline the issue measures the extended variant against.

A one-RC equivalent circuit with a polynomial open-circuit voltage and an I²R lumped thermal model,
fitted by least squares (scipy) on the same cleaned flights as the product's fit:

    V = P(SoC) - I R_0 - v_1,      dv_1/dt = (I R_1 - v_1) / tau,     SoC = SoC_0 - ∫I dt / Q
    C dT/dt = R_th I² + h (T_a - T)

P is a degree-5 polynomial in SoC. Each training flight's initial SoC is a free unknown of the
least squares; a flight it predicts starts at the SoC where P equals its first voltage (the pack is
at rest then). Not product code: it only exists so the acceptance test has an independent yardstick.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter

DEGREE = 5


@dataclass
class BaselineModel:
    poly: np.ndarray        # P coefficients, highest power first (np.polyval)
    r0: float
    r1: float
    tau: float
    capacity_c: float
    r_th: float
    c_th: float
    h: float

    def initial_soc(self, v_rest: float) -> float:
        grid = np.linspace(-0.2, 1.2, 1401)
        ocv = np.polyval(self.poly, grid)
        return float(grid[np.argmin(np.abs(ocv - v_rest))])

    def voltage(self, flight, soc0: float | None = None) -> np.ndarray:
        t, i = flight.time_s, flight.current_a
        dt = np.diff(t, prepend=t[0])
        soc0 = self.initial_soc(_first(flight.voltage_v)) if soc0 is None else soc0
        soc = soc0 - np.cumsum(i * dt) / self.capacity_c
        v1 = _rc(i, dt, self.r1, self.tau)
        return np.polyval(self.poly, soc) - i * self.r0 - v1

    def temperature(self, flight) -> np.ndarray:
        return _thermal(flight, self.r_th, self.c_th, self.h)


def _first(x: np.ndarray) -> float:
    return float(x[np.isfinite(x)][0])


def _rc(i: np.ndarray, dt: np.ndarray, r: float, tau: float) -> np.ndarray:
    a = np.exp(-np.median(dt[1:]) / tau)
    return lfilter([(1 - a) * r], [1, -a], i)


def _thermal(flight, r_th: float, c_th: float, h: float) -> np.ndarray:
    dt = np.diff(flight.time_s, prepend=flight.time_s[0])
    a = np.exp(-np.median(dt[1:]) * h / c_th)
    drive = flight.ambient_c + r_th * flight.current_a ** 2 / h
    t0 = _first(flight.temperature_c)
    # T_k = a T_{k-1} + (1 - a) drive_k, starting at T_0
    out, _ = lfilter([1 - a], [1, -a], drive, zi=[a * t0])
    return out


def fit_baseline(flights) -> BaselineModel:
    """Least-squares fit of the baseline on cleaned battery flights (uniform ~1 Hz logs)."""
    v_all = np.concatenate([f.voltage_v for f in flights])
    lo_v, hi_v = np.nanmin(v_all), np.nanmax(v_all)

    def unpack(x):
        poly = x[:DEGREE + 1]
        r0, r1, tau, cap = np.exp(x[DEGREE + 1:DEGREE + 5])
        return poly, r0, r1, tau, cap, x[DEGREE + 5:]

    def res_v(x):
        poly, r0, r1, tau, cap, socs = unpack(x)
        m = BaselineModel(poly, r0, r1, tau, cap, 0, 1, 1)
        out = []
        for f, s0 in zip(flights, socs):
            pred = m.voltage(f, s0)
            ok = np.isfinite(f.voltage_v)
            out.append(pred[ok] - f.voltage_v[ok])
        return np.concatenate(out)

    # start: a straight OCV from the lowest to the highest voltage seen, 20 mOhm, 30 s, rated 7.8 Ah
    poly0 = np.zeros(DEGREE + 1)
    poly0[-2:] = (hi_v - lo_v + 1.0, lo_v - 0.5)
    soc0 = [(_first(f.voltage_v) - poly0[-1]) / poly0[-2] for f in flights]
    x0 = np.concatenate([poly0, np.log([0.02, 0.01, 30.0, 7.8 * 3600]), soc0])
    fit = least_squares(res_v, x0, method="trf", x_scale="jac", max_nfev=300)
    poly, r0, r1, tau, cap, _ = unpack(fit.x)

    def res_t(y):
        r_th, c_th, h = np.exp(y)
        out = []
        for f in flights:
            ok = np.isfinite(f.temperature_c)
            out.append(_thermal(f, r_th, c_th, h)[ok] - f.temperature_c[ok])
        return np.concatenate(out)

    th = least_squares(res_t, np.log([0.03, 1000.0, 2.0]), method="trf", max_nfev=200)
    r_th, c_th, h = np.exp(th.x)
    return BaselineModel(poly, r0, r1, tau, cap, r_th, c_th, h)
