"""Fitting problems: whole-flight simulation error of batches of parameter vectors.

A problem maps a batch of points ``U`` (N, d) in the unit cube — each coordinate the position of one
free parameter between the log of its lower and upper bound — to the residuals of N whole-flight
simulations on every flight of a split (one kernel call per flight for the whole batch). Working in
log-parameters makes R_cp1 ≈ 1e-16 Ω and C_b ≈ 2e4 F equally well conditioned.

* :class:`PackProblem` — one pack through ``kernel.simulate_packs``, target ``"voltage"``
  (terminal voltage) or ``"temperature"`` (pack temperature, with the pack's R from the circuit).
* :class:`MotorProblem` — the motor pair through ``kernel.simulate_motor_thermal``: mean motor
  current in, one bracket temperature out.

Initial state per flight (it is not in the log; packs are not always full): the temperature starts
at the median of the first ``init_samples // 2`` measured temperatures; the state of charge is the
one at which the model, for *this* parameter vector, gives the mean voltage of the leading samples
(at most ``init_samples``) whose current stays within 0.5 A (or 10 %) of the first one, at their
mean current, with both R–C pairs settled (bisection on the model's own
voltage–SoC curve, vectorised over the batch). Because it is recomputed for every vector, the
initial SoC is profiled out of the search instead of traded off against C_b.

Bounds are written for the paper's 5S 7.8 Ah pack; ``battery_bounds(model, PackFormat(...))`` carries
them to any pack (cells in series, capacity) with ``models.pack_scaling``.

Pure: numpy in, numpy out. Parallelism is injected (``mapper``: a ``map``-like callable, e.g. a
thread pool's ``map``; the kernel releases the GIL).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import numpy as np

from gcs_pdm.logs.tables import BATTERY, MOTOR, Flight
from gcs_pdm.models import kernel
from gcs_pdm.models.pack_scaling import value_scale
from gcs_pdm.models.params import CELLS_PER_PACK, PACK_CAPACITY_C

Mapper = Callable[[Callable, Iterable], Iterable]


@dataclass(frozen=True)
class Bound:
    """Expected physical range of one parameter (both ends > 0; searched in log space)."""

    name: str
    lo: float
    hi: float
    unit: str
    why: str = ""


#: Expected ranges for one 5S 7.8 Ah LiPo pack (docs/fitting.md explains each).
BATTERY_ELECTRICAL_BOUNDS: tuple[Bound, ...] = (
    Bound("R_s", 2e-3, 3e-2, "ohm", "0.4-6 mOhm per cell: ohmic resistance of a 7.8 Ah LiPo cell string"),
    Bound("R_p", 1e3, 1e5, "ohm", "self-discharge 0.2-20 mA at 20 V"),
    Bound("R_cp0", 5e-3, 1e-1, "ohm", "polarisation resistance on the plateau"),
    Bound("R_cp1", 1e-18, 1e-14, "ohm", "with R_cp2: end-of-discharge resistance R_cp1 exp(R_cp2)"),
    Bound("R_cp2", 25.0, 45.0, "1", "knee sharpness: the knee lies in the last 5-15 % of charge"),
    Bound("C_s", 20.0, 1000.0, "F", "tau_s = R_s C_s between 0.04 s and 30 s"),
    Bound("C_b", 5e3, 6e4, "F", "open-circuit voltage drops 0.5-5.6 V over the 28 kC capacity"),
    Bound("C_cp", 50.0, 3000.0, "F", "tau_cp = R_cp0 C_cp between 0.25 s and 300 s"),
)
BATTERY_THERMAL_BOUNDS: tuple[Bound, ...] = (
    Bound("C_t", 200.0, 5000.0, "J/K", "0.2-5 kJ/K: a 1 kg pack at c_p ~ 1 kJ/(kg K), with its mounting"),
    Bound("h", 0.2, 10.0, "W/K", "natural to strong forced convection over ~0.06 m^2"),
)
def _ocv_increment_bounds() -> tuple[Bound, ...]:
    # pack-level (5S) rise of the open-circuit voltage between neighbouring knots: positive (monotone)
    # and at most what a discharge curve shows between those SoCs (the lowest knots are the steepest)
    out = []
    for k in range(1, kernel.N_OCV_KNOTS):
        width = float(kernel.EXT_OCV_SOC[k] - kernel.EXT_OCV_SOC[k - 1])
        out.append(Bound(f"docv_{k}", 1e-3, max(0.5, 25.0 * width) if k > 2 else 3.0, "V",
                         f"OCV rise over SoC {kernel.EXT_OCV_SOC[k - 1]:.2f}-{kernel.EXT_OCV_SOC[k]:.2f}"))
    return tuple(out)


#: extended variant, 5S ~7.8 Ah pack (docs/model.md explains each)
EXTENDED_RC_BOUNDS: tuple[Bound, ...] = (
    Bound("R_0", 1e-3, 0.2, "ohm", "ohmic + fast charge-transfer resistance at 25 C, mid SoC: 0.2-40 mOhm per cell"),
    Bound("R_1", 1e-4, 0.2, "ohm", "fast polarisation pair"),
    Bound("tau_1", 1.0, 100.0, "s", "charge transfer / double layer: seconds to a minute"),
    Bound("R_2", 1e-4, 0.2, "ohm", "slow (diffusion) polarisation pair"),
    Bound("tau_2", 60.0, 3000.0, "s", "solid-state diffusion: minutes to an hour"),
    Bound("E_r", 100.0, 8000.0, "K", "Arrhenius E_a/R of the resistances: activation energies 1-65 kJ/mol"),
    Bound("E_ct", 100.0, 8000.0, "K", "Arrhenius E_a/R of the exchange current (charge transfer): 1-65 kJ/mol"),
    Bound("k_soc", 1e-3, 10.0, "1", "resistance rise near empty: f = 1 + k_soc exp(-SoC_surface/soc_knee)"),
    Bound("soc_knee", 0.01, 0.3, "1", "SoC scale of that rise: how sharp the end-of-discharge collapse is"),
    Bound("b_ct", 1e-3, 1.0, "V", "charge-transfer slope: 5 cells x RT/(alpha F) ~ 0.25 V; small = no kinetics"),
    Bound("i_ct", 0.1, 500.0, "A", "current where the charge-transfer drop turns logarithmic (exchange current)"),
    Bound("k_d", 1e-2, 3000.0, "s", "surface depletion I k_d / C_max: up to 0.3 SoC at 3C (slow solid diffusion)"),
    Bound("tau_d", 5.0, 5000.0, "s", "particle-surface depletion time constant: ~R^2/(pi^2 D), seconds to an hour"),
    Bound("C_max", 0.5 * PACK_CAPACITY_C, 2.0 * PACK_CAPACITY_C, "C",
          "usable capacity 50-200 % of the rated 7.8 Ah (labels are not capacities: a worn pack, or a cell's nominal "
          "rating below its electrodes' capacity)"),
)
EXTENDED_OCV_BOUNDS: tuple[Bound, ...] = (
    Bound("ocv_0", 12.5, 18.0, "V", "OCV of the pack at SoC 0: 2.5-3.6 V per cell"),
) + _ocv_increment_bounds()
EXTENDED_ELECTRICAL_BOUNDS: tuple[Bound, ...] = EXTENDED_RC_BOUNDS + EXTENDED_OCV_BOUNDS
EXTENDED_THERMAL_BOUNDS: tuple[Bound, ...] = (
    Bound("C_t", 50.0, 2e4, "J/K", "pack (0.05-20 kJ/K) as the one sensor sees it, with its mounting"),
    Bound("h", 0.02, 50.0, "W/K", "still air to strong forced convection, pack in a fuselage or outside"),
    Bound("dU_dT", -5e-3, 5e-3, "V/K", "entropic coefficient of the pack: +-1 mV/K per cell (searched linearly)"),
)

MOTOR_THERMAL_BOUNDS: tuple[Bound, ...] = (
    Bound("C_t", 100.0, 3000.0, "J/K", "motor (~0.6 kg copper/iron) and its aluminium bracket"),
    Bound("h", 0.2, 10.0, "W/K", "propeller-wash cooled out-runner"),
    # R_w (data sheet) stays fixed and anchors the heat scale; the constant core loss is learned
    Bound("P_iron", 1.0, 60.0, "W", "core loss heating the motor: 0.05-3 % of a 2 kW out-runner's power"),
)


#: the rested empty and full cell of the pack the bounds are written for (a LiPo, models.params.OCV_PER_CELL)
REFERENCE_EMPTY_CELL_V = 3.27
REFERENCE_FULL_CELL_V = 4.2


@dataclass(frozen=True)
class PackFormat:
    """The pack a fit is for: cells in series, rated capacity and its cells' chemistry. The bounds
    above are written for the paper's 5S 7.8 Ah LiPo pack (``PAPER_PACK``); ``battery_bounds`` carries
    them to any pack with the scaling of ``models.pack_scaling`` (resistances × S/Q, capacitances ×
    Q/S, voltages × S, …), then to its chemistry's cells (``chemistry_scale``)."""

    cells: int = CELLS_PER_PACK
    capacity_c: float = PACK_CAPACITY_C
    #: resting voltage of a full cell, V (the reference pack is carried to it)
    full_cell_voltage: float = REFERENCE_FULL_CELL_V
    #: the chemistry's rested empty and full cell, V (its open-circuit curve's ends): where the
    #: voltage ranges of a LiPo sit for other cells (fitting.vehicle.pack_format reads them)
    empty_ocv_cell_v: float = REFERENCE_EMPTY_CELL_V
    full_ocv_cell_v: float = REFERENCE_FULL_CELL_V

    def scale(self, name: str) -> float:
        return value_scale(name, CELLS_PER_PACK, PACK_CAPACITY_C, self.cells, self.capacity_c)

    def chemistry_scale(self, name: str) -> float:
        """Factor on a value's range for this chemistry's cells: the open-circuit span full - empty
        sets how many volts a charge moves the OCV (C_b inversely, the knots' rises docv_k)."""
        span = (self.full_ocv_cell_v - self.empty_ocv_cell_v) / (REFERENCE_FULL_CELL_V - REFERENCE_EMPTY_CELL_V)
        if name == "C_b":
            return 1.0 / span
        return span if name.startswith("docv_") else 1.0

    def chemistry_shift_v(self, name: str) -> float:
        """Volts added to a value's range for this chemistry: the empty pack's OCV (ocv_0) sits at
        its cells' empty voltage, not a LiPo's."""
        return self.cells * (self.empty_ocv_cell_v - REFERENCE_EMPTY_CELL_V) if name == "ocv_0" else 0.0


PAPER_PACK = PackFormat()


def scaled_bounds(bounds: Sequence[Bound], fmt: PackFormat = PAPER_PACK) -> tuple[Bound, ...]:
    """``bounds`` (written for the 5S 7.8 Ah LiPo pack) carried to the pack ``fmt``: its cells and
    capacity, then its chemistry's cell voltages; a value that does not scale with the pack (time
    constants, exponents) keeps its range."""
    if fmt == PAPER_PACK:
        return tuple(bounds)
    out = []
    for b in bounds:
        k, c, shift = fmt.scale(b.name), fmt.chemistry_scale(b.name), fmt.chemistry_shift_v(b.name)
        if k == 1.0 and c == 1.0 and shift == 0.0:
            out.append(b)
            continue
        why = f"{b.why} (5S 7.8 Ah range x {k:.3g} for {fmt.cells}S {fmt.capacity_c / 3.6:.0f} mAh"
        if c != 1.0 or shift != 0.0:
            why += (f"; cells resting {fmt.empty_ocv_cell_v:.2f}-{fmt.full_ocv_cell_v:.2f} V, not a LiPo's "
                    f"{REFERENCE_EMPTY_CELL_V:.2f}-{REFERENCE_FULL_CELL_V:.2f} V")
        out.append(Bound(b.name, b.lo * k * c + shift, b.hi * k * c + shift, b.unit, why + ")"))
    return tuple(out)


@dataclass(frozen=True)
class BatteryBounds:
    electrical: tuple[Bound, ...]
    thermal: tuple[Bound, ...]
    #: the parameters the annealing searches (the extended variant leaves the OCV knots to LM)
    annealing: tuple[Bound, ...]


def battery_bounds(model: str = "paper", fmt: PackFormat = PAPER_PACK) -> BatteryBounds:
    """The search ranges of a battery fit of variant ``model`` for the pack ``fmt``."""
    if model == "extended":
        return BatteryBounds(scaled_bounds(EXTENDED_ELECTRICAL_BOUNDS, fmt), scaled_bounds(EXTENDED_THERMAL_BOUNDS, fmt),
                             scaled_bounds(EXTENDED_RC_BOUNDS, fmt))
    electrical = scaled_bounds(BATTERY_ELECTRICAL_BOUNDS, fmt)
    return BatteryBounds(electrical, scaled_bounds(BATTERY_THERMAL_BOUNDS, fmt), electrical)


class ParameterSpace:
    """Unit-cube coordinates ↔ physical values of the free parameters: log-scaled, except a parameter
    whose range includes zero or negative values (e.g. the entropic coefficient), which is linear."""

    def __init__(self, bounds: Sequence[Bound]):
        self.bounds = tuple(bounds)
        self.names = tuple(b.name for b in self.bounds)
        lo = np.array([b.lo for b in self.bounds], dtype=np.float64)
        hi = np.array([b.hi for b in self.bounds], dtype=np.float64)
        self.linear = lo <= 0.0
        self.log_lo = np.where(self.linear, lo, np.log(np.where(self.linear, 1.0, lo)))
        self.log_hi = np.where(self.linear, hi, np.log(np.where(self.linear, 1.0, hi)))

    @property
    def dim(self) -> int:
        return len(self.bounds)

    def to_values(self, U: np.ndarray) -> np.ndarray:
        x = self.log_lo + np.asarray(U) * (self.log_hi - self.log_lo)
        return np.where(self.linear, x, np.exp(x)) if self.linear.any() else np.exp(x)

    def to_unit(self, values: np.ndarray) -> np.ndarray:
        v = np.asarray(values, dtype=np.float64)
        x = np.where(self.linear, v, np.log(np.where(self.linear, 1.0, v))) if self.linear.any() else np.log(v)
        return (x - self.log_lo) / (self.log_hi - self.log_lo)


@dataclass(frozen=True)
class Prepared:
    """A cleaned flight as kernel inputs, with the first-samples summary for the initial state."""

    name: str
    dt: np.ndarray
    current: np.ndarray
    ambient: np.ndarray
    target: np.ndarray        # measured output, NaN where missing
    mask: np.ndarray          # finite target
    init_current: float
    init_voltage: float       # NaN for motor flights
    init_temperature: float
    #: measured temperature, interpolated over drop-outs (NaN if the flight has none); drives the
    #: extended variant's resistances in its electrical stage
    drive_temperature: np.ndarray | None = None


#: a leading sample belongs to the initial-state window while its current stays this close to the first
STEADY_CURRENT_A = 0.5
STEADY_CURRENT_REL = 0.1


def prepare(flight: Flight, target: str, init_samples: int = 10) -> Prepared:
    """Kernel inputs of a cleaned flight (no NaN in inputs, increasing time)."""
    if np.any(~np.isfinite(flight.current_a)) or np.any(~np.isfinite(flight.ambient_c)):
        raise ValueError(f"{flight.name}: current/ambient must be finite (clean the flight first)")
    if np.any(np.diff(flight.time_s) <= 0):
        raise ValueError(f"{flight.name}: time must increase (clean the flight first)")
    y = np.asarray(flight.voltage_v if target == "voltage" else flight.temperature_c, dtype=np.float64)
    has_temp = np.isfinite(flight.temperature_c)
    first_temp = flight.temperature_c[has_temp][:max(init_samples // 2, 1)]
    if first_temp.size == 0 and (flight.kind != BATTERY or target == "temperature"):
        raise ValueError(f"{flight.name}: no temperature sample for the initial state")
    if first_temp.size == 0:
        # a pack without a temperature sensor: it starts at the air temperature
        first_temp = flight.ambient_c[:1]
        drive = np.full(len(flight), np.nan)
    else:
        drive = np.interp(flight.time_s, flight.time_s[has_temp], flight.temperature_c[has_temp])
    if flight.kind == BATTERY:
        # only the leading samples at a steady current (the pack at rest before arming, or idling):
        # once the current ramps up, the R-C pairs are charging and "settled" no longer holds
        cur = flight.current_a
        steady = np.abs(cur[:init_samples] - cur[0]) <= max(STEADY_CURRENT_A, STEADY_CURRENT_REL * abs(cur[0]))
        n_steady = int(np.argmin(steady)) if not steady.all() else steady.size
        window = np.arange(max(n_steady, 1))
        fin = window[np.isfinite(flight.voltage_v[window])]
        if fin.size == 0:
            fin = np.flatnonzero(np.isfinite(flight.voltage_v))[:1]
        if fin.size == 0:
            raise ValueError(f"{flight.name}: no voltage sample for the initial state")
        init_v = float(np.mean(flight.voltage_v[fin]))
        init_i = float(np.mean(cur[: fin[-1] + 1]))
    else:
        init_v, init_i = float("nan"), float(flight.current_a[0])
    return Prepared(name=flight.name, dt=np.ascontiguousarray(flight.dt), current=np.ascontiguousarray(flight.current_a),
                    ambient=np.ascontiguousarray(flight.ambient_c), target=y, mask=np.isfinite(y),
                    init_current=init_i, init_voltage=init_v, init_temperature=float(np.median(first_temp)),
                    drive_temperature=np.ascontiguousarray(drive))


def pack_vectors_with(base: np.ndarray, names: Sequence[str], values: np.ndarray) -> np.ndarray:
    """(N, 12) pack vectors: ``base`` with ``names`` set to ``values`` (N, len(names)); q_max tracks C_b
    (full at the base's full voltage q_max / C_b) and C_max stays the base's rated capacity unless
    q_max is smaller."""
    values = np.atleast_2d(values)
    base = np.asarray(base, dtype=np.float64)
    P = np.tile(base, (values.shape[0], 1))
    for j, name in enumerate(names):
        P[:, kernel.PACK_PARAMS.index(name)] = values[:, j]
    if "C_b" in names:
        P[:, kernel.I_QMAX] = P[:, kernel.I_CB] * (base[kernel.I_QMAX] / base[kernel.I_CB])
        P[:, kernel.I_CMAX] = np.minimum(base[kernel.I_CMAX], P[:, kernel.I_QMAX])
    return P


def initial_soc(P: np.ndarray, voltage: float, current: float, iterations: int = 40) -> np.ndarray:
    """SoC (N,) at which each pack vector, settled at ``current``, shows terminal ``voltage``.

    The model's own settled terminal voltage (``kernel.initial_pack_state`` at the bulk current
    i_b = i + V / R_p, read by ``kernel.terminal_voltage``) is monotone in SoC, so bisection on
    [-0.3, 1.3] (outside [0, 1] the model is extrapolated, and the fit sees the misfit).
    """
    P = np.atleast_2d(P)
    i_b = current + voltage / P[:, kernel.I_RP]
    lo = np.full(P.shape[0], -0.3)
    hi = np.full(P.shape[0], 1.3)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        with np.errstate(over="ignore", invalid="ignore"):
            v = kernel.terminal_voltage(P, kernel.initial_pack_state(P, mid, 0.0, i_b))
        above = v > voltage
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return 0.5 * (lo + hi)


def _chunks(n: int, parts: int) -> list[slice]:
    parts = max(1, min(parts, n))
    edges = np.linspace(0, n, parts + 1).astype(int)
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


class _Problem:
    """Shared batching over flights and vectors."""

    space: ParameterSpace
    flights: list[Prepared]

    def __init__(self, space: ParameterSpace, flights: list[Prepared], mapper: Mapper | None = None, workers: int = 1):
        if not flights:
            raise ValueError("no flights")
        self.space = space
        self.flights = flights
        self.mapper = mapper or map
        self.workers = workers
        #: measured samples (rows of the data residuals); n_residuals may add prior rows after them
        self.n_data = int(sum(f.mask.sum() for f in flights))
        self.n_residuals = self.n_data
        if self.n_residuals == 0:
            raise ValueError("no measured samples in the flights")

    #: per-flight extra unknowns (columns after the d parameters in U); 0 or len(flights)
    n_extra: int = 0

    # subclasses: simulate one flight for a batch of physical value rows -> (N, n) predictions;
    # ``extra`` (N,) is this flight's extra unknown in unit coordinates, or None
    def simulate(self, values: np.ndarray, f: Prepared, extra: np.ndarray | None = None) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    @property
    def row_slices(self) -> list[slice]:
        """Rows of each flight in the residual vector."""
        edges = np.concatenate([[0], np.cumsum([int(f.mask.sum()) for f in self.flights])])
        return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]

    def _residuals_serial(self, args: tuple[np.ndarray, np.ndarray | None]) -> np.ndarray:
        values, extras = args
        out = np.empty((values.shape[0], self.n_data))
        for fi, (f, rows) in enumerate(zip(self.flights, self.row_slices)):
            pred = self.simulate(values, f, None if extras is None else extras[:, fi])
            out[:, rows] = pred[:, f.mask] - f.target[f.mask]
        # a diverged simulation (NaN/inf) is a very bad fit, not a crash
        np.nan_to_num(out, copy=False, nan=1e6, posinf=1e6, neginf=-1e6)
        return out

    def residuals(self, U: np.ndarray, parallel: bool = True) -> np.ndarray:
        """(N, m) residuals (prediction - measurement, over every measured sample of every flight).

        U is (N, d) — the free parameters — or (N, d + n_extra) with the per-flight extra unknowns.
        """
        U = np.atleast_2d(U)
        d = self.space.dim
        if U.shape[1] not in (d, d + self.n_extra):
            raise ValueError(f"U: expected {d} or {d + self.n_extra} columns, got {U.shape[1]}")
        values = self.space.to_values(U[:, :d])
        extras = U[:, d:] if U.shape[1] > d else None
        if not parallel or self.workers <= 1 or values.shape[0] < 2:
            return self._residuals_serial((values, extras))
        chunks = _chunks(values.shape[0], self.workers)
        parts = list(self.mapper(self._residuals_serial,
                                 [(values[c], None if extras is None else extras[c]) for c in chunks]))
        return np.concatenate(parts, axis=0)

    def mse(self, U: np.ndarray, parallel: bool = True) -> np.ndarray:
        r = self.residuals(U, parallel)
        return np.einsum("ij,ij->i", r, r) / r.shape[1]

    def predictions(self, u: np.ndarray) -> list[np.ndarray]:
        """Per-flight prediction (n,) for one point (free parameters only)."""
        values = self.space.to_values(np.atleast_2d(u)[:, :self.space.dim])
        return [self.simulate(values, f)[0] for f in self.flights]


class PackProblem(_Problem):
    """One pack's voltage or temperature; the free parameters replace those of ``base`` (12,)."""

    def __init__(self, flights: Sequence[Flight], base: np.ndarray, bounds: Sequence[Bound], target: str = "voltage",
                 *, init_samples: int = 10, mapper: Mapper | None = None, workers: int = 1,
                 soc_offset_range: float = 0.0):
        if target not in ("voltage", "temperature"):
            raise ValueError(f"target must be 'voltage' or 'temperature', got {target!r}")
        bad = [f.name for f in flights if f.kind != BATTERY]
        if bad:
            raise ValueError(f"not battery flights: {', '.join(bad)}")
        self.base = np.asarray(base, dtype=np.float64)
        self.target = target
        #: per-flight initial-SoC corrections of up to ±soc_offset_range may be appended to U (LM only)
        self.soc_offset_range = float(soc_offset_range)
        super().__init__(ParameterSpace(bounds), [prepare(f, target, init_samples) for f in flights], mapper, workers)
        self.n_extra = len(self.flights) if self.soc_offset_range > 0 else 0

    def soc_offset(self, extra: np.ndarray | None) -> np.ndarray | float:
        """Initial-SoC correction for an extra unknown in unit coordinates (0.5 = none)."""
        return 0.0 if extra is None else (np.asarray(extra) - 0.5) * 2.0 * self.soc_offset_range

    def pack_vectors(self, values: np.ndarray) -> np.ndarray:
        return pack_vectors_with(self.base, self.space.names, values)

    def canonical(self, u: np.ndarray) -> np.ndarray | None:
        """The same circuit with the R–C pairs relabelled if the R_s–C_s pair is the slower one, else None.

        V = V_b - V_cp - V_s: the two pairs enter alike, and away from the knee (R_cp ≈ R_cp0) swapping
        (R_s, C_s) with (R_cp0, C_cp) gives the same voltage. The model's reading is R_s–C_s the fast
        (ohmic, sub-second) pair and R_cp–C_cp the slow (concentration) one.
        """
        names = self.space.names
        need = ("R_s", "C_s", "R_cp0", "C_cp")
        if not all(n in names for n in need):
            return None
        v = self.space.to_values(np.asarray(u, dtype=np.float64))
        i = {n: names.index(n) for n in need}
        if v[i["R_s"]] * v[i["C_s"]] <= v[i["R_cp0"]] * v[i["C_cp"]]:
            return None
        w = v.copy()
        w[i["R_s"]], w[i["R_cp0"]] = v[i["R_cp0"]], v[i["R_s"]]
        w[i["C_s"]], w[i["C_cp"]] = v[i["C_cp"]], v[i["C_s"]]
        return np.clip(self.space.to_unit(w), 0.0, 1.0)

    def initial_states(self, P: np.ndarray, f: Prepared, extra: np.ndarray | None = None) -> np.ndarray:
        soc = initial_soc(P, f.init_voltage, f.init_current) + self.soc_offset(extra)
        return kernel.initial_pack_state(P, soc, f.init_temperature, f.init_current)

    def simulate(self, values: np.ndarray, f: Prepared, extra: np.ndarray | None = None) -> np.ndarray:
        P = self.pack_vectors(values)
        traj = kernel.simulate_packs(P, self.initial_states(P, f, extra), f.dt, f.current, f.ambient)
        return traj.voltage if self.target == "voltage" else traj.temperature

    def initial_soc(self, u: np.ndarray) -> list[float]:
        """Initial SoC per flight for one point (with its per-flight corrections if u has them)."""
        u = np.atleast_2d(u)
        d = self.space.dim
        P = self.pack_vectors(self.space.to_values(u[:, :d]))
        return [float(initial_soc(P, f.init_voltage, f.init_current)[0]
                      + self.soc_offset(u[0, d + i] if u.shape[1] > d else None))
                for i, f in enumerate(self.flights)]


class ExtendedPackProblem(PackProblem):
    """One pack in the extended variant; the free parameters replace those of ``base``
    (N_EXT_PARAMS,) in EXT_PACK_PARAMS order. For the voltage target the resistances follow the
    *measured* temperature (so the electrical stage needs no thermal parameters); for the temperature
    target the model's own temperature drives them, as in a prediction. The initial SoC comes from
    the first rest voltage through this vector's open-circuit voltage.

    ``ocv_smoothing`` (V per V/SoC; 0: off) appends one residual per inner OCV knot, the change of
    the curve's slope across it times that weight: a weak prior that the OCV bends only where the
    flights say it does. Data move a knot that a flight's rest voltage or trajectory sees by far more;
    a knot that none sees (a pack that never got near full, or empty) stays smooth instead of taking
    any jump that happens to help a training flight — the jump a test flight then starts on."""

    def __init__(self, *args, ocv_smoothing: float = 0.0, **kwargs):
        super().__init__(*args, **kwargs)
        names = self.space.names
        self._docv = [names.index(f"docv_{k}") if f"docv_{k}" in names else -1 for k in range(1, kernel.N_OCV_KNOTS)]
        self.ocv_smoothing = float(ocv_smoothing) if all(i >= 0 for i in self._docv) else 0.0
        if self.ocv_smoothing > 0:
            self.n_residuals += kernel.N_OCV_KNOTS - 2

    def _residuals_serial(self, args: tuple[np.ndarray, np.ndarray | None]) -> np.ndarray:
        if self.ocv_smoothing <= 0:
            return super()._residuals_serial(args)
        values, _ = args
        return np.concatenate([super()._residuals_serial(args), self._prior(values)], axis=1)

    def _prior(self, values: np.ndarray) -> np.ndarray:
        slopes = values[:, self._docv] / np.diff(kernel.EXT_OCV_SOC)
        return self.ocv_smoothing * np.diff(slopes, axis=1)

    def pack_vectors(self, values: np.ndarray) -> np.ndarray:
        values = np.atleast_2d(values)
        P = np.tile(self.base, (values.shape[0], 1))
        for j, name in enumerate(self.space.names):
            P[:, kernel.EXT_PACK_PARAMS.index(name)] = values[:, j]
        return P

    def canonical(self, u: np.ndarray) -> np.ndarray | None:
        return None  # the two pairs' time-constant ranges keep them apart

    def rest_soc(self, P: np.ndarray, f: Prepared) -> np.ndarray:
        return kernel.extended_rest_soc(P, f.init_voltage, f.init_current, f.init_temperature)

    def initial_states(self, P: np.ndarray, f: Prepared, extra: np.ndarray | None = None) -> np.ndarray:
        soc = self.rest_soc(P, f) + self.soc_offset(extra)
        return kernel.initial_extended_state(P, soc, f.init_temperature, f.init_current)

    def simulate(self, values: np.ndarray, f: Prepared, extra: np.ndarray | None = None) -> np.ndarray:
        P = self.pack_vectors(values)
        drive = f.drive_temperature if self.target == "voltage" else None
        traj = kernel.simulate_packs(P, self.initial_states(P, f, extra), f.dt, f.current, f.ambient,
                                     variant="extended", measured_temperature=drive)
        return traj.voltage if self.target == "voltage" else traj.temperature

    def initial_soc(self, u: np.ndarray) -> list[float]:
        u = np.atleast_2d(u)
        d = self.space.dim
        P = self.pack_vectors(self.space.to_values(u[:, :d]))
        return [float(self.rest_soc(P, f)[0] + self.soc_offset(u[0, d + i] if u.shape[1] > d else None))
                for i, f in enumerate(self.flights)]

    @property
    def ocv_columns(self) -> np.ndarray:
        """Free parameters that shape only the open-circuit-voltage curve (its knots); their Jacobian
        columns come from :meth:`ocv_jacobian` (voltage target) instead of one simulation each."""
        if self.target != "voltage":
            return np.zeros(0, dtype=int)
        return np.array([j for j, n in enumerate(self.space.names) if n == "ocv_0" or n.startswith("docv_")], dtype=int)

    #: initial-SoC step of the derivative of a flight's voltage trace with respect to its initial SoC
    SOC_STEP = 1e-6

    def ocv_jacobian(self, u: np.ndarray, step: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (m,) at ``u`` (free parameters, then any per-flight extras) and their forward-difference
        derivatives (m, k) with respect to the unit coordinates of :attr:`ocv_columns`, from two
        simulations per flight instead of k.

        Why this is exact: the knots move the voltage only through the OCV read at the particles'
        surface SoC, V_k = OCV(s_k) - D_k, and through the initial SoC s_0 read from the rest voltage:
        D_k (the drops, which the measured temperature or the loss-based heat drive) and the SoC
        trajectory s_k depend on the knots only through s_0. So dV_k/dy = dOCV(s_k)/dy + dV_k/ds_0 ·
        ds_0/dy, with s_k and dV_k/ds_0 from one simulation at s_0 and one at s_0 + SOC_STEP, and the
        rest are OCV evaluations and rest-SoC bisections (no simulation)."""
        u = np.asarray(u, dtype=np.float64)
        d = self.space.dim
        cols = self.ocv_columns
        values = self.space.to_values(u[None, :d])
        shifted = np.tile(u[:d], (cols.size, 1))
        shifted[np.arange(cols.size), cols] += step
        P = self.pack_vectors(values)
        Pk = self.pack_vectors(self.space.to_values(shifted))
        r0 = np.empty(self.n_residuals)
        J = np.empty((self.n_residuals, cols.size))
        surface = np.empty(self.n_data)
        for fi, (f, rows) in enumerate(zip(self.flights, self.row_slices)):
            extra = u[d + fi] if u.size > d else None
            rest = self.rest_soc(P, f)[0]
            soc0 = rest + self.soc_offset(extra)
            P2 = np.repeat(P, 2, axis=0)
            x0 = kernel.initial_extended_state(P2, np.array([soc0, soc0 + self.SOC_STEP]), f.init_temperature,
                                               f.init_current)
            traj = kernel.simulate_packs(P2, x0, f.dt, f.current, f.ambient, variant="extended",
                                         measured_temperature=f.drive_temperature, record_states=True)
            v = traj.voltage[:, f.mask]
            r0[rows] = v[0] - f.target[f.mask]
            surface[rows] = traj.states[0, f.mask, kernel.X_SOC] - traj.states[0, f.mask, kernel.X_SD]
            # through the initial SoC: dV/ds_0 (n,) times ds_0/dy (k,)
            dsoc = (self.rest_soc(Pk, f) - rest) / step
            J[rows] = np.outer((v[1] - v[0]) / self.SOC_STEP, dsoc)
        # through the curve at the surface SoC the flights passed. The knot increments are cumulative and
        # a PCHIP piece between knots k and k+1 reads the knots k-1 .. k+2: increment j shifts the curve
        # rigidly above knot j+1 (derivative = its own scale), leaves it alone below knot j-2, and only
        # between them is the curve evaluated again (about 3 of the 27 columns per sample)
        xs = kernel.EXT_OCV_SOC
        ocv = kernel.open_circuit_voltage(P, surface)
        idx = [kernel.EXT_PACK_PARAMS.index(self.space.names[c]) for c in cols]
        rigid = (Pk[np.arange(cols.size), idx] - P[0, idx]) / step
        knot = np.array([0 if self.space.names[c] == "ocv_0" else int(self.space.names[c].split("_")[1]) for c in cols])
        piece = np.searchsorted(xs, surface, side="right") - 1          # -1 below knot 0, last above the top
        # ocv_0 (knot 0) shifts every piece; increment j rigidly shifts pieces j+1 and up
        J[:self.n_data] += (piece[:, None] >= np.where(knot == 0, -1, knot + 1)[None, :]) * rigid[None, :]
        for c in np.flatnonzero(knot > 0):
            j = knot[c]
            local = np.flatnonzero((piece >= j - 2) & (piece <= j)) if j >= 2 else np.flatnonzero(piece <= j)
            if local.size:
                J[local, c] += (kernel.open_circuit_voltage(Pk[c:c + 1], np.ascontiguousarray(surface[local]))
                                - ocv[local]) / step
        if self.n_residuals > self.n_data:
            prior = self._prior(np.vstack([values, self.space.to_values(shifted)]))
            r0[self.n_data:] = prior[0]
            J[self.n_data:] = ((prior[1:] - prior[0]) / step).T
        np.nan_to_num(r0, copy=False, nan=1e6, posinf=1e6, neginf=-1e6)
        if not np.isfinite(J).all():  # a diverged simulation: no direction from it
            np.nan_to_num(J, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        return r0, J


class MotorProblem(_Problem):
    """The motor pair's bracket temperature from the mean motor current; free parameters replace
    those of ``base`` (5,) in MOTOR_PARAMS order."""

    def __init__(self, flights: Sequence[Flight], base: np.ndarray, bounds: Sequence[Bound], *, init_samples: int = 10,
                 mapper: Mapper | None = None, workers: int = 1):
        bad = [f.name for f in flights if f.kind != MOTOR]
        if bad:
            raise ValueError(f"not motor flights: {', '.join(bad)}")
        self.base = np.asarray(base, dtype=np.float64)
        super().__init__(ParameterSpace(bounds), [prepare(f, "temperature", init_samples) for f in flights], mapper, workers)

    def motor_vectors(self, values: np.ndarray) -> np.ndarray:
        values = np.atleast_2d(values)
        M = np.tile(self.base, (values.shape[0], 1))
        for j, name in enumerate(self.space.names):
            M[:, kernel.MOTOR_PARAMS.index(name)] = values[:, j]
        return M

    def simulate(self, values: np.ndarray, f: Prepared, extra: np.ndarray | None = None) -> np.ndarray:
        M = self.motor_vectors(values)
        return kernel.simulate_motor_thermal(M, np.full(M.shape[0], f.init_temperature), f.dt, f.current, f.ambient)


def reference_vector(reference_set, pack: str, fmt: PackFormat = PAPER_PACK) -> np.ndarray:
    """(12,) paper-variant vector of a reference set's pack for errors reported beside a fit: the
    set's pack of that name (else its first), carried to the pack ``fmt`` when that is not the
    5S 7.8 Ah pack the built-in sets describe."""
    from gcs_pdm.models.pack_scaling import scale_pack_vector
    from gcs_pdm.models.params import pack_vector

    ref = reference_set.packs.get(pack) or next(iter(reference_set.packs.values()))
    v = pack_vector(ref)
    if fmt == PAPER_PACK:
        return v
    return scale_pack_vector(v, CELLS_PER_PACK, PACK_CAPACITY_C, fmt.cells, fmt.capacity_c, fmt.full_cell_voltage)
