"""A pack's health point for one flight, from that flight's current, voltage and temperature (pure).

* **Capacity** (Ah) by the charge counted between two rested open-circuit voltages: the rest
  before take-off and the rest after landing, each read as a state of charge on the pack's
  open-circuit-voltage curve (the rest after as a line through its last half, read at its end:
  ``rest_end_voltage``); capacity = charge drawn / SoC used. Its σ follows from the voltage
  uncertainty at each rest (noise, and what relaxation may still be under way) through the curve's
  slope there, and the current sensor's gain error. Without both rests, or with too shallow a
  discharge (less than ``min_soc_used`` of the pack), the capacity is unknown and the point says why.
* **Resistance at 25 °C** (Ω) from the voltage steps at the flight's current steps (take-off,
  climbs, throttle-back): ΔV/ΔI one sample apart, read at the take-off step (the same condition every
  flight: the pack at its starting charge, barely loaded before; σ from the voltage noise just before
  it), else the median over the flight's steps (σ from their spread), scaled to 25 °C by an
  Arrhenius law (``activation_energy_j_mol``).
* **Use**: charge and energy drawn, equivalent full cycles (charge drawn / nominal capacity), depth
  of discharge (SoC used when the rests tell it, else charge / nominal), peak temperature.

Sign: discharge current positive (the project's convention). Time in message seconds.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from functools import cached_property

import numpy as np

GAS_CONSTANT = 8.314462618
T25_K = 298.15

#: a generic Li-ion (NMC/graphite, LiPo) cell's open-circuit voltage against SoC, for a pack with no
#: curve of its own: a capacity read on it carries ``GENERIC_CURVE_SOC_SD`` more SoC uncertainty
GENERIC_OCV_SOC = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0)
GENERIC_OCV_V = (3.30, 3.50, 3.60, 3.68, 3.73, 3.77, 3.81, 3.86, 3.93, 4.00, 4.08, 4.13, 4.19)
GENERIC_CURVE_SOC_SD = 0.03
#: the charge grid a capacity to the cut-off is read on (samples from full to an electrode's end)
CAPACITY_GRID = 4000
#: the end rest's voltage rules out the lithium inventories it lies this many σ from
REST_GATE_SD = 5.0
#: the take-off step is the flight's first current step within this long of its first load (s)
TAKEOFF_WINDOW_S = 120.0
#: a rest ends where the current's running median over this many samples leaves it: one sample's
#: noise past the rest threshold (0.02C is 3σ of a 0.05 A sensor on a 7.8 Ah pack) cut a 15-min rest
#: after landing short of ``min_rest_after_s`` on 9 of 13 PyBaMM flights
#: (docs/notes/2026-11-28-history-prior.md); a median keeps a real step's edge where it is
REST_MEDIAN_SAMPLES = 5


@dataclass(frozen=True)
class OcvCurve:
    """A cell's open-circuit voltage against state of charge (increasing in both)."""
    soc: tuple[float, ...]
    voltage_v: tuple[float, ...]
    #: extra SoC uncertainty of reading this curve (0 for the pack's own; >0 for a generic one)
    soc_sd: float = 0.0
    name: str = "own"

    def __post_init__(self):
        order = np.argsort(self.soc)
        s, v = np.asarray(self.soc, float)[order], np.asarray(self.voltage_v, float)[order]
        v = np.maximum.accumulate(v)  # a flat or noisy stretch must not make the inverse ambiguous
        object.__setattr__(self, "soc", tuple(float(x) for x in s))
        object.__setattr__(self, "voltage_v", tuple(float(x) for x in v))

    def soc_at(self, cell_v: float) -> float:
        v, s = np.asarray(self.voltage_v), np.asarray(self.soc)
        keep = np.concatenate([[True], np.diff(v) > 1e-9])
        return float(np.interp(cell_v, v[keep], s[keep]))

    def slope_at(self, soc: float, half_width: float = 0.02) -> float:
        """dV/dSoC (V per unit SoC) about ``soc``."""
        lo, hi = max(0.0, soc - half_width), min(1.0, soc + half_width)
        s, v = np.asarray(self.soc), np.asarray(self.voltage_v)
        return float((np.interp(hi, s, v) - np.interp(lo, s, v)) / max(hi - lo, 1e-6))


GENERIC_OCV = OcvCurve(GENERIC_OCV_SOC, GENERIC_OCV_V, soc_sd=GENERIC_CURVE_SOC_SD, name="generic Li-ion")


@dataclass(frozen=True)
class ElectrodeCurves:
    """A cell chemistry's two electrodes: their potentials against stoichiometry, their capacities
    (Ah) and the cell's voltage limits. With these a capacity is read as lithium lost, which is
    what SEI growth and lithium plating take: the cell's open-circuit curve against its own SoC
    changes shape as it loses lithium, so a fresh cell's curve misreads an aged cell (measured on
    the ageing fixtures: +5 % at 7 % fade), the electrodes' curves do not."""
    stoichiometry: tuple[float, ...]
    negative_v: tuple[float, ...]
    positive_v: tuple[float, ...]
    negative_ah: float
    positive_ah: float
    lower_cutoff_v: float
    name: str = "electrodes"

    def u_n(self, x):
        return np.interp(x, self.stoichiometry, self.negative_v)

    def u_p(self, y):
        return np.interp(y, self.stoichiometry, self.positive_v)

    def y_at(self, u_p_v):
        """The positive stoichiometry where its potential is ``u_p_v`` (it falls as y rises)."""
        s, v = np.asarray(self.stoichiometry), np.asarray(self.positive_v)
        return np.interp(-np.asarray(u_p_v), -v, s)

    def consistent_states(self, v0: float, v1: float, drawn_ah: float, v1_sd: float) -> tuple[np.ndarray, np.ndarray]:
        """Every negative stoichiometry x0 at the first rest (on the curve through ``v0``, cell OCV)
        from which ``drawn_ah`` later the cell rests within ``REST_GATE_SD`` σ of ``v1``, with the
        log-likelihood of that end rest (Gaussian, σ ``v1_sd``). The electrodes' plateaus make this
        a band, not a point: near a full cell the graphite's stage plateau leaves the split between
        the electrodes loosely pinned, and a box of ±2σ (the earlier rule) made the band's edges
        count as much as its middle."""
        x0 = np.linspace(0.05, 0.999, 4000)
        y0 = self.y_at(v0 + self.u_n(x0))
        x1 = x0 - drawn_ah / self.negative_ah
        y1 = y0 + drawn_ah / self.positive_ah
        ok = (x1 > 0.0) & (y1 < 1.0) & (y0 > min(self.stoichiometry)) & (y0 < max(self.stoichiometry))
        z = (self.u_p(y1) - self.u_n(x1) - v1) / v1_sd
        band = ok & (np.abs(z) <= REST_GATE_SD)
        return x0[band], -0.5 * z[band] ** 2

    def capacity_from(self, x0: float, y0: float, polarization_v: float = 0.0) -> float:
        """Charge (Ah) from (x0, y0) down to the lower cut-off, the open-circuit voltage held
        ``polarization_v`` above it (the drop of the measuring discharge's current)."""
        return float(self.capacities_from(np.array([x0], float), np.array([y0], float), polarization_v)[0])

    def capacities_from(self, x0: np.ndarray, y0: np.ndarray, polarization_v: float = 0.0) -> np.ndarray:
        """``capacity_from`` for many states at once. The charge grid is 4000 samples from 0 to
        where an electrode runs out; the open-circuit voltage falls along it (the positive's
        potential falls strictly as it fills, the negative's never rises as it empties), so the
        first sample at or below the cut-off is found by bisection on that grid: the same sample,
        and the same interpolated charge, as evaluating all 4000 (which cost about half of a
        ``liion`` log's ingest)."""
        x0, y0 = np.asarray(x0, float)[:, None], np.asarray(y0, float)[:, None]  # a row per state
        last = CAPACITY_GRID - 1
        stop = np.minimum(x0 * self.negative_ah, (1.0 - y0) * self.positive_ah)
        step = stop / last

        def charge(k):  # np.linspace(0, stop, CAPACITY_GRID)[k], to the bit
            return np.where(k == last, stop, k * step)

        def ocv(k):
            q = charge(k)
            return self.u_p(y0 + q / self.positive_ah) - self.u_n(x0 - q / self.negative_ah) - polarization_v

        cut = self.lower_cutoff_v
        if self.monotone:  # invariant: ocv(lo) > cut >= ocv(hi)
            lo, hi = np.zeros((x0.shape[0], 1), int), np.full((x0.shape[0], 1), last)
            never, at_start = ocv(hi) > cut, ocv(lo) <= cut
            while np.any(hi - lo > 1):
                mid = (lo + hi) // 2
                below = ocv(mid) <= cut
                hi, lo = np.where(below, mid, hi), np.where(below, lo, mid)
        else:  # a measured table with bumps: the first sample below, by evaluating all
            below = ocv(np.arange(CAPACITY_GRID)[None, :]) <= cut
            hi = np.argmax(below, axis=1)[:, None]
            lo = np.maximum(hi - 1, 0)
            never, at_start = ~below.any(axis=1)[:, None], hi == 0
        v_lo, v_hi = ocv(lo), ocv(hi)  # the crossing, interpolated between the two samples
        w = (v_lo - cut) / np.where(v_lo != v_hi, v_lo - v_hi, 1.0)
        crossing = charge(lo) + w * (charge(hi) - charge(lo))
        return np.where(never, stop, np.where(at_start, 0.0, crossing))[:, 0]

    @cached_property
    def monotone(self) -> bool:
        """The positive's potential falls strictly as it fills and the negative's never rises as
        it fills: the cell's open-circuit voltage then falls strictly along a discharge."""
        return bool(np.all(np.diff(self.positive_v) < 0) and np.all(np.diff(self.negative_v) <= 0))

    def full_state_for(self, capacity_ah: float, full_v: float) -> tuple[float, float]:
        """(x0, y0) of a cell resting at ``full_v`` whose charge down to the cut-off is ``capacity_ah``:
        the lithium inventory of a cell that has lost lithium (SEI, plating) and nothing else."""
        def capacity_at(x0: float) -> float:
            return self.capacity_from(x0, float(self.y_at(full_v + self.u_n(x0))))

        lo, hi = 0.05, 0.999
        if not capacity_at(lo) <= capacity_ah <= capacity_at(hi):
            raise ValueError(f"no lithium inventory of {self.name} gives {capacity_ah:.4g} Ah from {full_v:g} V")
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if capacity_at(mid) < capacity_ah else (lo, mid)
        x0 = 0.5 * (lo + hi)
        return x0, float(self.y_at(full_v + self.u_n(x0)))

    def capacity(self, v0: float, v1: float, drawn_ah: float, v1_sd: float, polarization_v: float = 0.0,
                 flight: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None):
        """(capacity, σ, how) over the states consistent with both rests; None: none is.

        ``flight`` (time, current, voltage, charge drawn since the first rest; the loaded samples):
        each consistent state's open-circuit curve along the flight, less the current's drop (an
        ohmic term and two lags, 30 s and 300 s, fitted by least squares), is compared with the
        voltage flown (the electrodes' features under load pin what the two rests leave loose:
        differential voltage analysis). The capacity is the mean over the states weighted by how
        well each fits, its σ their weighted spread: a Gaussian likelihood of the residuals with the
        best state's mean square as the noise and ``n_eff`` independent samples (the residuals are
        strongly correlated from one sample to the next, so n_eff = n (1-ρ)/(1+ρ) with ρ their lag-1
        autocorrelation). The single best-fitting state is not taken: where the flight pins the
        inventory weakly it sits at the band's edge (measured on the ageing fixtures: the misses of
        the 3 % mark were such edges, docs/notes/2026-11-27-pack-capacity.md). Each state's weight
        also holds the end rest's likelihood (``consistent_states``). Without ``flight``, the
        mean and spread over the rests' likelihood alone."""
        xs, rest_log_w = self.consistent_states(v0, v1, drawn_ah, v1_sd)
        if xs.size == 0:
            return None
        pick = slice(None, None, max(1, xs.size // 160))
        xs, rest_log_w = xs[pick], rest_log_w[pick]
        ys = self.y_at(v0 + self.u_n(xs))
        caps = self.capacities_from(xs, ys, polarization_v)
        if flight is None or xs.size == 1:
            mean, sd = _weighted_mean_sd(caps, rest_log_w)
            return mean, sd, "the rests alone"
        t, i, v, q = flight
        lags = [_lowpass(t, i, tau) for tau in (30.0, 300.0)]
        design = np.column_stack([i, *lags])
        # every state's drop along the flight (a row each), all fitted by one least-squares solve
        drops = (self.u_p(ys[:, None] + q[None, :] / self.positive_ah)
                 - self.u_n(xs[:, None] - q[None, :] / self.negative_ah) - v[None, :])
        coef, *_ = np.linalg.lstsq(design, drops.T, rcond=None)
        residuals = drops - (design @ coef).T
        rms = np.sqrt(np.mean(residuals ** 2, axis=1))
        best = int(np.argmin(rms))
        n_eff = effective_samples(residuals[best])
        log_w = rest_log_w - 0.5 * n_eff * (rms ** 2 / max(rms[best] ** 2, 1e-18) - 1.0)
        mean, sd = _weighted_mean_sd(caps, log_w)
        return mean, sd, (f"fitted to the flight's voltage (best rms {rms[best] * 1e3:.1f} mV, "
                          f"{n_eff:.0f} effective samples)")


def _weighted_mean_sd(values: np.ndarray, log_w: np.ndarray) -> tuple[float, float]:
    w = np.exp(log_w - log_w.max())
    mean = float(np.sum(w * values) / np.sum(w))
    return mean, math.sqrt(float(np.sum(w * (values - mean) ** 2) / np.sum(w)))


def rest_end_voltage(t: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    """The voltage at the end of a rest and its σ: a straight line through the rest's samples (one
    pass dropping those beyond 4 robust σ: a glitch), read at the last one. A rest's last samples
    alone are few (a log thinned to one every 30 s holds 3 in a minute) and their median carried
    1-2 mV of noise, 0.4 % of capacity per mV on an aged cell; the line also follows the
    relaxation still under way (docs/notes/2026-11-27-pack-capacity-rests.md)."""
    keep = np.isfinite(v)
    for _ in range(2):
        slope, at_end = np.polyfit(t[keep] - t[-1], v[keep], 1)
        resid = v - (at_end + slope * (t - t[-1]))
        spread = 1.4826 * float(np.median(np.abs(resid[keep])))
        if spread <= 0:
            break
        keep = np.isfinite(v) & (np.abs(resid) <= 4.0 * spread)
    n = int(keep.sum())
    tc = t[keep] - t[-1]
    s = math.sqrt(float(np.sum(resid[keep] ** 2)) / max(n - 2, 1))
    se = s * math.sqrt(1.0 / n + float(tc.mean()) ** 2 / max(float(np.sum((tc - tc.mean()) ** 2)), 1e-12))
    return float(at_end), se


def effective_samples(residuals: np.ndarray) -> float:
    """How many independent samples a series of correlated residuals is worth: n (1-ρ)/(1+ρ), ρ
    the lag-1 autocorrelation (an AR(1) reading; at least 1)."""
    r = np.asarray(residuals, float)
    if r.size < 3 or not np.any(r - r.mean()):
        return float(max(r.size, 1))
    rho = float(np.corrcoef(r[1:], r[:-1])[0, 1])
    rho = min(max(rho, 0.0), 0.999)
    return max(r.size * (1.0 - rho) / (1.0 + rho), 1.0)


def _lowpass(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    out = np.empty_like(x)
    acc = 0.0
    out[0] = 0.0
    w = np.exp(-np.diff(t) / tau_s)
    for k in range(1, x.size):
        acc = w[k - 1] * acc + (1.0 - w[k - 1]) * x[k]
        out[k] = acc
    return out


@dataclass(frozen=True)
class HealthSettings:
    #: below this share of the nominal 1C current the pack is at rest
    rest_c_rate: float = 0.02
    #: a rest before take-off must be this long to be read as an open-circuit voltage
    min_rest_before_s: float = 60.0
    #: ... and after landing (relaxation is slower after a discharge)
    min_rest_after_s: float = 600.0
    #: a capacity needs at least this share of the pack used between the two rests
    min_soc_used: float = 0.3
    #: cell voltage still relaxing after a rest of min_rest_after_s (1σ, V)
    relaxation_sd_v: float = 0.002
    #: current sensor gain error (1σ, fraction)
    current_gain_sd: float = 0.005
    #: a current step this large (share of 1C) is read for resistance
    min_step_c_rate: float = 0.2
    #: ... between samples this close (s): the voltage over a longer gap also holds diffusion
    max_step_dt_s: float = 1.5
    #: read the resistance at the take-off step when there is one (else: the median over the
    #: flight's steps)
    resistance_at_takeoff: bool = True
    #: Arrhenius activation energy of the pack's resistance (J/mol)
    activation_energy_j_mol: float = 20000.0
    #: the rate a capacity is stated at (C/20: the usual measurement, and PyBaMM's)
    measure_c_rate: float = 0.05
    #: the electrode method's own error (1σ, fraction): its equilibrium cell against a C/20
    #: measurement, measured on the PyBaMM ageing fixtures (mean |error| 0.9-1.2 %, docs/packs.md)
    electrode_model_sd: float = 0.015


@dataclass
class HealthPoint:
    """One pack's health over one flight (SI units; None: unknown, and ``why`` says why)."""
    pack_id: str
    start_s: float
    end_s: float
    capacity_ah: float | None
    capacity_sd_ah: float | None
    resistance_25c_ohm: float | None
    resistance_sd_ohm: float | None
    charge_ah: float
    energy_wh: float
    equivalent_cycles: float
    depth_of_discharge: float | None
    peak_temperature_c: float | None
    nominal_capacity_ah: float
    cells_series: int
    method: dict = field(default_factory=dict)
    why: dict = field(default_factory=dict)
    #: the flight's curve fit (``packs.flight_curve``: curve, offset, scale, capacity; or its ``why``),
    #: None where not fitted: what the next flight's estimator starts its curve from
    curve: dict | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "HealthPoint":
        names = cls.__dataclass_fields__
        return cls(**{k: v for k, v in d.items() if k in names})


def _running_median(x: np.ndarray, n: int) -> np.ndarray:
    """The median of each sample's centred window of ``n`` (odd) samples, the ends padded by their edge."""
    if x.size < n:
        return x
    half = n // 2
    padded = np.concatenate([np.full(half, x[0]), x, np.full(half, x[-1])])
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, n), axis=1)


def _trapz(y: np.ndarray, t: np.ndarray) -> float:
    if y.size < 2:
        return 0.0
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t)))


def _finite_interp(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x)
    if ok.sum() < 2:
        return x
    return np.interp(t, t[ok], x[ok])


def _step_resistance(t, i, v, nominal_capacity_ah: float, settings: HealthSettings) -> float | None:
    """The pack's resistance (Ω): the median of -ΔV/ΔI over the record's current steps (None: none)."""
    dt, di, dv = np.diff(t), np.diff(i), np.diff(v)
    step = ((np.abs(di) >= max(settings.min_step_c_rate * nominal_capacity_ah, 1e-3)) & (dt > 0)
            & (dt <= settings.max_step_dt_s) & np.isfinite(dv) & np.isfinite(di))
    return float(np.median(-dv[step] / di[step])) if step.any() else None


def health_point(pack_id: str, time_s, current_a, voltage_v, temperature_c=None, *, nominal_capacity_ah: float,
                 cells_series: int = 1, ocv: OcvCurve | None = None, electrodes: ElectrodeCurves | None = None,
                 cells_parallel: float = 1.0, settings: HealthSettings = HealthSettings()) -> HealthPoint:
    """The health point of one pack over one flight's record (rests around it included)."""
    t = np.asarray(time_s, float)
    i = np.asarray(current_a, float)
    v = np.asarray(voltage_v, float)
    temp = np.full(t.size, np.nan) if temperature_c is None else np.asarray(temperature_c, float)
    order = np.argsort(t, kind="stable")
    t, i, v, temp = t[order], i[order], v[order], temp[order]
    why, method = {}, {}
    if t.size < 2 or nominal_capacity_ah <= 0:
        raise ValueError(f"{pack_id}: a health point needs at least two samples and a nominal capacity")
    i_filled = np.nan_to_num(_finite_interp(t, i), nan=0.0)
    v_filled = _finite_interp(t, v)
    drawn = np.maximum(i_filled, 0.0)
    charge_ah = _trapz(drawn, t) / 3600.0
    energy_wh = _trapz(np.nan_to_num(np.maximum(i_filled * v_filled, 0.0)), t) / 3600.0
    peak = float(np.nanmax(temp)) if np.isfinite(temp).any() else None
    if peak is None:
        why["peak_temperature_c"] = "no pack temperature in the record"
    cells = max(int(cells_series), 1)
    curve = ocv or GENERIC_OCV
    method["ocv_curve"] = electrodes.name if electrodes is not None else curve.name

    # --- capacity between the rests ---
    capacity = capacity_sd = dod = None
    rest_a = settings.rest_c_rate * nominal_capacity_ah
    # the load's samples, read through the sensor's noise (``REST_MEDIAN_SAMPLES``): the rests' edges
    # below and the take-off step's first load
    loaded = np.flatnonzero(_running_median(np.abs(i_filled), REST_MEDIAN_SAMPLES) > rest_a)
    if loaded.size == 0:
        why["capacity_ah"] = "the pack never carried a load in this record"
    else:
        first, last = int(loaded[0]), int(loaded[-1])
        before_s = t[first] - t[0]
        after_s = t[-1] - t[last]
        if before_s < settings.min_rest_before_s:
            why["capacity_ah"] = (f"no rest before take-off ({before_s:.0f} s < {settings.min_rest_before_s:g} s): "
                                  "no open-circuit voltage to start from")
        elif after_s < settings.min_rest_after_s:
            why["capacity_ah"] = (f"no rest after landing ({after_s:.0f} s < {settings.min_rest_after_s:g} s): "
                                  "no open-circuit voltage to end at")
        else:
            pre = (t >= t[first] - min(before_s, 30.0)) & (t < t[first]) & np.isfinite(v)
            # the rest after: its last half, where the relaxation has slowed (rest_end_voltage)
            post = (t >= t[-1] - 0.5 * after_s) & (t > t[last]) & np.isfinite(v)
            if pre.sum() < 3 or post.sum() < 3:
                why["capacity_ah"] = "too few voltage samples in the rests"
            else:
                v0 = float(np.median(v[pre])) / cells
                v1, v1_noise = rest_end_voltage(t[post], v[post] / cells)
                # the reading's σ, and what relaxation may still be under way after the record ends
                v1_sd = math.hypot(v1_noise, settings.relaxation_sd_v)
                s0, s1 = curve.soc_at(v0), curve.soc_at(v1)
                used = s0 - s1
                # the counted span: from the last rest sample before the load to the first after it
                span = (t >= t[max(first - 1, 0)]) & (t <= t[min(last + 1, t.size - 1)])
                counted = _trapz(i_filled[span], t[span]) / 3600.0
                if used < settings.min_soc_used:
                    why["capacity_ah"] = (f"too shallow: {used:.0%} of the pack used between the rests "
                                          f"(< {settings.min_soc_used:.0%})")
                elif electrodes is not None:
                    # per cell of the parallel group: the electrodes are one cell's
                    q = counted / cells_parallel
                    # the true capacity is measured by a slow discharge (C/20): its current's drop
                    # through the cell's resistance ends it that much early
                    r_cell = _step_resistance(t, i, v, nominal_capacity_ah, settings)
                    pol = 0.0 if r_cell is None else (settings.measure_c_rate * nominal_capacity_ah / cells_parallel
                                                      * r_cell * cells_parallel / cells)
                    flown = (t >= t[first]) & (t <= t[last]) & np.isfinite(v)
                    drawn_since = np.concatenate([[0.0], np.cumsum(0.5 * (i_filled[1:] + i_filled[:-1]) * np.diff(t))])
                    drawn_since = (drawn_since - drawn_since[max(first - 1, 0)]) / 3600.0 / cells_parallel
                    flight = (t[flown], i_filled[flown] / cells_parallel, v[flown] / cells, drawn_since[flown]) \
                        if flown.sum() >= 30 else None
                    got = electrodes.capacity(v0, v1, q, v1_sd, pol, flight)
                    if got is None:
                        why["capacity_ah"] = "no lithium inventory of the electrodes explains both rests"
                    else:
                        c, spread, how = got
                        capacity = c * cells_parallel
                        capacity_sd = cells_parallel * math.sqrt(spread ** 2 + (c * settings.current_gain_sd) ** 2
                                                                 + (c * settings.electrode_model_sd) ** 2)
                        dod = q / c if c > 0 else None
                        method["capacity"] = (f"lithium inventory from the rests: {q:.4g} Ah per cell drawn "
                                              f"between {v0:.4f} V and {v1:.4f} V, {how}; at "
                                              f"{settings.measure_c_rate:g}C ({pol * 1e3:.1f} mV drop)")
                else:
                    capacity = counted / used
                    noise0 = float(np.std(v[pre] / cells)) / math.sqrt(pre.sum())
                    sd_s0 = math.hypot(noise0 / max(curve.slope_at(s0), 1e-3), curve.soc_sd)
                    sd_s1 = math.hypot(v1_sd / max(curve.slope_at(s1), 1e-3), curve.soc_sd)
                    rel = math.sqrt((math.hypot(sd_s0, sd_s1) / used) ** 2 + settings.current_gain_sd ** 2)
                    capacity_sd = capacity * rel
                    dod = used
                    method["capacity"] = (f"charge counted between rests: {counted:.4g} Ah over SoC "
                                          f"{s0:.3f} -> {s1:.3f}")
    if dod is None:
        dod = min(charge_ah / nominal_capacity_ah, 1.0) if charge_ah > 0 else 0.0
        method["depth_of_discharge"] = "charge drawn / nominal capacity (no rested SoC)"

    # --- resistance from the current steps ---
    resistance = resistance_sd = None
    dt = np.diff(t)
    di = np.diff(i)
    dv = np.diff(v)
    step = ((np.abs(di) >= max(settings.min_step_c_rate * nominal_capacity_ah, 1e-3)) & (dt > 0)
            & (dt <= settings.max_step_dt_s) & np.isfinite(dv) & np.isfinite(di))
    if step.sum() < 1:
        why["resistance_25c_ohm"] = (f"no current step of {settings.min_step_c_rate:g}C within "
                                     f"{settings.max_step_dt_s:g} s in the record")
    else:
        r = -dv[step] / di[step]  # the pack's (the series string's) resistance
        r_med = float(np.median(r))
        mad = float(np.median(np.abs(r - r_med))) * 1.4826
        sd = (1.2533 * mad / math.sqrt(r.size)) if r.size >= 3 else abs(r_med) * 0.2
        temp_step = temp[1:][step]
        how = f"median dV/dI over {int(step.sum())} current step(s)"
        # the take-off step (the flight's first, within TAKEOFF_WINDOW_S of the first load), when
        # there is one: the same condition every flight (the pack at its starting charge, barely
        # loaded before), where the median mixes steps at every SoC
        k = int(np.flatnonzero(step)[0])
        first_load = loaded  # not sample by sample: one noisy sample in a long rest before is not the load
        before = (t < t[k] + 1e-9) & (t >= t[k] - 30.0) & np.isfinite(v)
        if (settings.resistance_at_takeoff and first_load.size and t[k] - t[first_load[0]] <= TAKEOFF_WINDOW_S
                and before.sum() >= 5):
            noise = float(np.std(np.diff(v[before]))) / math.sqrt(2.0)  # one sample's voltage noise
            r_med = float(r[0])
            sd = max(math.sqrt(2.0) * noise / abs(di[k]), 1e-6)  # one step: its two samples' noise
            temp_step = temp[1:][step][:1]
            how = f"the take-off step ({di[k]:+.3g} A)"
        t_c = float(np.nanmedian(temp_step)) if np.isfinite(temp_step).any() else None
        if t_c is None:
            factor = 1.0
            method["resistance_temperature"] = "no pack temperature: read as if at 25 °C"
        else:
            factor = math.exp(-settings.activation_energy_j_mol / GAS_CONSTANT
                              * (1.0 / (t_c + 273.15) - 1.0 / T25_K))
        resistance = r_med * factor
        resistance_sd = max(sd * factor, 1e-6)
        method["resistance"] = how + (f" at {t_c:.1f} °C" if t_c is not None else "")
    return HealthPoint(pack_id=pack_id, start_s=float(t[0]), end_s=float(t[-1]), capacity_ah=capacity,
                       capacity_sd_ah=capacity_sd, resistance_25c_ohm=resistance, resistance_sd_ohm=resistance_sd,
                       charge_ah=charge_ah, energy_wh=energy_wh,
                       equivalent_cycles=charge_ah / nominal_capacity_ah, depth_of_discharge=dod,
                       peak_temperature_c=peak, nominal_capacity_ah=float(nominal_capacity_ah), cells_series=cells,
                       method=method, why=why)
