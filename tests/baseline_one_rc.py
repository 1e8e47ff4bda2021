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
from scipy.optimize import least_squares, lsq_linear
from scipy.signal import lfilter

DEGREE = 5
REST_WEIGHT = 30.0


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
        # the highest SoC whose OCV is still below the rest voltage (the polynomial need not be monotone)
        grid = np.linspace(0.0, 1.2, 1201)
        below = np.flatnonzero(np.polyval(self.poly, grid) <= v_rest)
        return float(grid[below[-1]]) if below.size else 0.0

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


def _ocv_basis(soc: np.ndarray) -> np.ndarray:
    # powers of SoC, highest first (np.polyval order)
    return np.vander(soc, DEGREE + 1)


def fit_baseline(flights) -> BaselineModel:
    """Least-squares fit of the baseline on cleaned battery flights (uniform ~1 Hz logs).

    Variable projection: for given (tau, capacity, initial SoCs) the voltage is linear in the
    polynomial's coefficients, R_0 and R_1, which a linear least squares gives exactly; scipy's
    bounded least squares searches the rest."""
    rated = 7.8 * 3600.0

    def design(x):
        tau, cap, socs = x[0], x[1] * rated, x[2:]
        rows, ys = [], []
        for f, s0 in zip(flights, socs):
            dt = np.diff(f.time_s, prepend=f.time_s[0])
            soc = s0 - np.cumsum(f.current_a * dt) / cap
            ok = np.isfinite(f.voltage_v)
            a = np.column_stack([_ocv_basis(soc), -f.current_a, -_rc(f.current_a, dt, 1.0, tau)])
            rows.append(a[ok])
            ys.append(f.voltage_v[ok])
            # the flight starts at rest: its first voltage is the OCV at its initial SoC (weighted, so the
            # SoC scale the fit settles on is the one a new flight is started with)
            rows.append(REST_WEIGHT * np.r_[_ocv_basis(np.array([s0]))[0], 0.0, 0.0][None])
            ys.append(REST_WEIGHT * np.array([_first(f.voltage_v)]))
        return np.vstack(rows), np.concatenate(ys)

    lower = np.r_[np.full(DEGREE + 1, -np.inf), 0.0, 0.0]   # resistances are not negative

    def solve(x):
        a, y = design(x)
        coef = lsq_linear(a, y, bounds=(lower, np.inf), method="bvls").x
        return coef, a @ coef - y

    x0 = np.concatenate([[30.0, 1.0], np.full(len(flights), 0.9)])
    lo = np.concatenate([[1.0, 0.5], np.full(len(flights), 0.0)])
    hi = np.concatenate([[3000.0, 1.5], np.full(len(flights), 1.2)])
    fit = least_squares(lambda x: solve(x)[1], x0, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=200)
    coef, _ = solve(fit.x)
    poly, r0, r1 = coef[:DEGREE + 1], float(coef[DEGREE + 1]), float(coef[DEGREE + 2])

    def res_t(y):
        r_th, c_th, h = np.exp(y)
        out = []
        for f in flights:
            ok = np.isfinite(f.temperature_c)
            out.append(_thermal(f, r_th, c_th, h)[ok] - f.temperature_c[ok])
        return np.concatenate(out)

    th = least_squares(res_t, np.log([0.03, 1000.0, 2.0]), bounds=(np.log([1e-4, 10.0, 0.01]), np.log([1.0, 1e5, 100.0])),
                       method="trf", max_nfev=200)
    r_th, c_th, h = np.exp(th.x)
    return BaselineModel(poly, r0, r1, float(fit.x[0]), float(fit.x[1] * rated), r_th, c_th, h)
