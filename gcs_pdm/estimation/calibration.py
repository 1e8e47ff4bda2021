"""Self-calibrating pack estimation: state and parameters of a pack nobody has fitted (issue 29).

Per pack, one extended Kalman filter over the joint state

    x = [SoC, v₁, R₀, ΔV, k, g, R₁, v₂, R₂, E]

— state of charge; the series resistance at 25 °C (pack, Ω); two polarisation pairs, a fast one
(voltage v₁, resistance R₁, the chemistry's τ₁ scaled by R₁ / its prior: the pair keeps its
capacitance) and a slow one (v₂, R₂, τ₂ = ``TAU2_FACTOR`` τ₁: an SPMe cell's diffusion sag grows for
minutes); the open-circuit curve's offset (V per cell) and scale (about the curve's mid-point); the
inverse capacity scale g = Q_prior / Q; and the resistances' Arrhenius factor E (K) — with the
chemistry's rested curve (``models.chemistry``) as the open-circuit voltage:

    OCV_cell(SoC) = ocv(SoC) + ΔV + k (ocv(SoC) − ocv(½))
    V = S · OCV_cell(SoC) − v₁ − v₂ − R₀ f(T) I,      f(T) = exp(E (1/T − 1/298.15))
    SoC' = SoC − g I Δt / Q_prior,   vⱼ' = aⱼ vⱼ + (1 − aⱼ) Rⱼ f(T) I,   aⱼ = exp(−Δt/τⱼ)

E is observable only while the pack's temperature moves (a pack at 25 °C, or one with no
temperature, keeps its prior, the chemistry's).

The parameters are random walks with small steps; their priors come from the chemistry, the
description (cells, capacity: the autopilot's BATT_CAPACITY when the description was derived from
it) and, when given, the pack's own history (``PackPrior``). After every update they are held
inside what the chemistry allows (``PARAM_BOUNDS``: a LiPo never rests above 4.25 V per cell).
The capacity and the curve's scale learn only from evidence that separates them from the dynamics
(``capacity_separable``): a span of the curve drawn, and a loaded voltage only while the pack's
temperature stays near where the count started; a rested voltage at any temperature.
A pack whose curve is only its chemistry's table, where the chemistry's published curves differ
more than the capacity's prior (``CurveFamilySpread.count_in_flight``: Li-ion), learns neither: its
capacity stays at its prior and under load the voltage teaches only the circuit — the SoC is the
rested voltage's plus the charge counted.

**The charge count is the floor.** The filter's SoC is a charge count (SoC' above) that the
voltage corrects. The voltage is trusted only while it carries information the model can follow:

* *it falls as charge is drawn*: from 30 s after the pack left rest, a least-squares fit of the
  loaded voltage on [1, I, charge drawn / Q_prior] gives the voltage's fall per unit of charge; once
  ``DRAIN_MIN_FRACTION`` of the capacity has been drawn it must be at least ``DRAIN_MIN_RATIO`` of
  the fall the chemistry's curve has over that span (ArduPlane SITL's battery never drains: its
  voltage holds while the autopilot's count falls 99 % → 48 %);
* *the model follows it*: the mean normalised squared innovation over the last
  ``NIS_WINDOW`` updates stays under ``NIS_RAISE``;
* *it does not contradict the charge count beyond the capacity's uncertainty*: the filter's SoC
  stays within ``REFEREE_SIGMAS`` σ of a pure charge count from the same start (prior capacity).

Otherwise the voltage updates stop (``voltage_model`` leaves the evidence, the reason is kept) and
the SoC follows the charge drawn from where the charge count stands, its σ growing with the
capacity's uncertainty (g's variance). A mismatch never withholds the SoC: it is an advisory.

**On the ground** (current under ``rest_current_a`` for ``REST_SETTLE_S``) the rested voltage sets
the SoC through the chemistry curve (the filter's voltage updates at zero current do it, the
curve's offset bounding how sure they make it), and the charge count's start is re-anchored there:
take-off continues from it, without a jump.

``evidence`` says what the SoC rests on now: ``rest_voltage`` (the start came from a rested
voltage), ``loaded_voltage`` (from a voltage under load: no rest seen), ``coulomb`` (the charge
drawn is counted), ``voltage_model`` (the voltage is correcting it now), ``prior`` (the capacity and
curve are the prior's, not yet learned).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from gcs_pdm.models.chemistry import Chemistry, chemistry
from gcs_pdm.models.curve_hypotheses import CURVE_FAMILY_SPREAD, CurveFamilySpread, is_published_table_curve

# state indices. The last, the charge count's start, is never updated (its gain is zero): it is in
# the state so that the filter's covariance carries how the filter's SoC and the count's start err
# together, which the consistency check (``_referee``) needs
I_SOC, I_V1, I_R0, I_DV, I_K, I_G, I_R1, I_V2, I_R2, I_E, I_COUNT0 = range(11)
N_STATE = 11
STATE_NAMES = ("soc", "v1", "r0", "ocv_offset", "ocv_scale", "inv_capacity_scale", "r1", "v2", "r2", "activation_k",
               "count_start")
#: the resistance's Arrhenius factor E starts at the chemistry's with this relative σ; it is learned
#: where the pack's temperature moves (a PyBaMM LG M50 heating 32 -> 68 °C keeps more of its
#: resistance than E = 3000 K says: fixed, the lost sag read as charge, SoC 0.27 low)
ACTIVATION_REL_SD = 0.5
#: the slow pair (diffusion in the particles: an SPMe cell's sag grows for minutes): its time
#: constant a multiple of the fast pair's; its resistance starts at 0 with σ = the fast pair's prior
#: (a pack that has none, as the kernel's, keeps it near 0)
TAU2_FACTOR = 10.0
R2_SD = 1.0

#: voltage trusted only once this much of the capacity has been drawn with the voltage falling
DRAIN_MIN_FRACTION = 0.06
#: ... by at least this share of the chemistry curve's fall over the same span
DRAIN_MIN_RATIO = 0.3
DRAIN_SIGMAS = 3.0
#: the drain fit is solved every this many loaded samples (its sums grow at every one)
DRAIN_CHECK_EVERY = 5
#: seconds after leaving rest before loaded samples enter the drain fit (the polarisation settles)
DRAIN_SETTLE_S = 30.0
NIS_WINDOW = 60
NIS_RAISE = 4.0
NIS_CLEAR = 1.5
REFEREE_SIGMAS = 4.0
REST_SETTLE_S = 10.0
#: the capacity and the curve's scale learn once this share of the capacity is drawn since the rest
LEARN_AFTER_FRACTION = 0.1
#: ... and, under load, only while the pack is within this many K of its temperature where that
#: count started: a cell that heats moves its resistance, its curve and its diffusion, the circuit
#: models only the first (Arrhenius), and the rest of the voltage's drift read as charge — PyBaMM LG
#: M50 flights heating 20-40 K learned 0.6-1.45x the truth's capacity (4-12 K measure the same on
#: them). The simulated presets' packs warm 3-5 K in 15 min, and a 30 % small pack must still be
#: learned there. A rested voltage (no sag to confuse) still teaches the capacity at any temperature
#: (notes/2026-11-27-capacity-evidence.md)
CAPACITY_TEMP_SPAN_K = 8.0
#: share of the loaded sag counted as model error (measurement noise) in a voltage update
LOAD_MODEL_SIGMA = 0.5
#: the series resistance's random walk, share of its prior per √s (more lets the SoC trade
#: against it: 0.01 met 3 of quad-4s's 8 off-prior cases where 0.002 meets 7)
R0_WALK = 0.002
#: the pairs' voltages' random walk, V per √s (more, 0.005-0.02 per cell, lets them take the SoC's
#: evidence: no better on the PyBaMM flights)
V1_WALK = 0.002
#: the capacity prior's relative σ when nothing tighter is known (a pack's history can give one)
CAPACITY_PRIOR_REL_SD = 0.25
#: an innovation beyond this many σ is not applied (a spike), counted
GATE_SIGMAS = 5.0
#: the recent load a time-to-cut-off prediction holds (``calibrated_cutoff``): the loaded current
#: and the model's voltage shortfall at it, means over about this long, s
RECENT_LOAD_TAU_S = 60.0
#: how far back the recent load's spread is measured (its minute-to-minute moves, the model's
#: shortfall's variability): about five held means, s
LOAD_SPREAD_TAU_S = 300.0


@dataclass(frozen=True)
class PackPrior:
    """Where a pack's estimate starts: the chemistry, cells, capacity (C) and its relative σ, and —
    from the pack's own history when the pack-life records give it — a resistance, curve offset and
    scale, and a capacity with a tighter σ. ``soc``/``soc_sd``: a known starting SoC (else the first
    voltage sets it)."""

    chemistry: str
    cells: int
    capacity_c: float
    #: a label's or BATT_CAPACITY's capacity can be 30 % off an aged or mislabelled pack (issue 29's
    #: range): at 0.15 that was a 2.9σ capacity (g = 1/0.7) the filter would not learn in time
    capacity_rel_sd: float = CAPACITY_PRIOR_REL_SD
    r0_ohm: float | None = None
    r0_rel_sd: float = 1.0
    ocv_offset_v: float = 0.0
    ocv_offset_sd: float = 0.015
    ocv_scale: float = 0.0
    ocv_scale_sd: float = 0.05
    soc: float | None = None
    soc_sd: float = 0.05
    #: what the capacity rests on, said in the evidence (e.g. "BATT_CAPACITY")
    capacity_source: str = "description"
    #: the curve and circuit priors when they are not the chemistry table's: a described pack's own
    #: model (``described_chemistry``)
    curve: Chemistry | None = None
    #: what the description declares the pack is charged to, V per cell (None: not declared): picks
    #: among a chemistry's curves (``models.curve_hypotheses``)
    full_cell_v: float | None = None

    @property
    def chem(self) -> Chemistry:
        return self.curve if self.curve is not None else chemistry(self.chemistry)

    @property
    def curve_family_spread(self) -> CurveFamilySpread | None:
        """What the chemistry's published curves leave open about the SoC when this pack's curve is
        only its chemistry's table (``models.curve_hypotheses.CURVE_FAMILY_SPREAD``); None when the
        pack has a curve of its own. A declared charge voltage picks among curves that end at
        different voltages (a LiPo at 4.20 V or an LCO cell at 4.10 V) and so removes their parting
        at rest, but not how far a cell with that end lies from the published curve
        (``CurveFamilySpread.given_full``): before, a LiPo declared at 4.10 V lost the whole term and
        PyBaMM's Marquis2019 sat inside its 2σ band on 49 % of samples."""
        if not is_published_table_curve(self.chemistry, self.curve):
            return None
        spread = CURVE_FAMILY_SPREAD.get(self.chemistry)
        if spread is None or self.full_cell_v is None:
            return spread
        return spread.given_full(self.full_cell_v)

    @property
    def r0_prior(self) -> float:
        if self.r0_ohm is not None:
            return self.r0_ohm
        return self.cells * self.chem.r0_cell_ah / max(self.capacity_c / 3600.0, 1e-3)


def described_chemistry(spec, pack_vector: np.ndarray) -> Chemistry:
    """The priors a described pack's own model gives (``kernel.PACK_PARAMS`` vector): its rested
    curve (the bulk voltage over the cells: the paper variant's is linear in charge), its series
    resistance and its concentration pair — what a vehicle the user described, or a simulated vehicle
    flying its description, is. Bounds from the chemistry the description names."""
    from gcs_pdm.models import kernel

    grid = np.linspace(0.0, 1.0, 21)
    rows = np.repeat(np.asarray(pack_vector, dtype=np.float64)[None], grid.size, axis=0)
    rest = kernel.terminal_voltage(rows, kernel.initial_pack_state(rows, grid, 25.0, 0.0)) / spec.cells_series
    base = chemistry(spec.chemistry)
    q_ah = float(spec.capacity_c) / 3600.0
    r_s, r_cp = float(pack_vector[kernel.I_RS]), float(kernel.concentration_resistance(rows[:1], 0.5)[0])
    return Chemistry(f"{base.name} (described model)", tuple(float(v) for v in rest), float(rest[-1]),
                     base.cutoff_cell_v, max(base.max_rest_cell_v, float(rest[-1]) + 0.05),
                     r_s * q_ah / spec.cells_series, r_cp / r_s, float(r_cp * pack_vector[kernel.I_CCP]),
                     base.r_activation_k, "the description's own pack model (its parameter set's rested curve)")


def prior_of_spec(spec, pack_vector: np.ndarray | None = None,
                  capacity_rel_sd: float = CAPACITY_PRIOR_REL_SD) -> PackPrior:
    """A description's pack (``vehicle.description.PackSpec``) as a prior: its chemistry, cells and
    capacity; with ``pack_vector`` (a described, not derived, pack) the curve and circuit of its own
    model, else the chemistry table's."""
    return PackPrior(chemistry=spec.chemistry, cells=int(spec.cells_series), capacity_c=float(spec.capacity_c),
                     capacity_rel_sd=capacity_rel_sd, full_cell_v=spec.full_cell_voltage,
                     curve=None if pack_vector is None else described_chemistry(spec, pack_vector))


@dataclass
class _Drain:
    """Running normal equations of V ≈ a + b I + c (drawn / Q_prior) over loaded samples."""

    vv: float = 0.0
    n: int = 0

    #: plain-float running sums (a per-frame call): Σi, Σf, Σi², Σif, Σf², Σv, Σiv, Σfv
    sums: list = field(default_factory=lambda: [0.0] * 8)

    def add(self, current: float, frac: float, v: float) -> None:
        s = self.sums
        s[0] += current
        s[1] += frac
        s[2] += current * current
        s[3] += current * frac
        s[4] += frac * frac
        s[5] += v
        s[6] += current * v
        s[7] += frac * v
        self.vv += v * v
        self.n += 1

    def slope(self) -> tuple[float, float]:
        """(c, its standard error): the voltage's change per unit of capacity drawn (NaN while not
        determined). The error treats the residuals as independent: a lower bound, so a fall
        judged missing is missing by more than it says."""
        if self.n < 20:
            return math.nan, math.nan
        return _drain_fit(float(self.n), np.array(self.sums), self.vv)


class PackCalibrator:
    """One pack's joint state and parameter filter (see the module doc)."""

    def __init__(self, prior: PackPrior, *, sigma_v: float | None = None):
        self.prior = prior
        self.chem = prior.chem
        self.cells = prior.cells
        self.q0 = prior.capacity_c
        self.table = self.chem.table
        self.mid = self.chem.ocv(0.5)
        self.r0p = prior.r0_prior
        self.r1p = self.chem.r1_ratio * self.r0p
        self.r2p = 0.0
        self.sigma_v = sigma_v if sigma_v is not None else 0.02 + 0.012 * self.cells
        self.rest_current_a = max(0.3, 0.05 * self.q0 / 3600.0)
        self.family = prior.curve_family_spread
        #: the family's σ at the last rest (or start): ``CurveFamilySpread.rest_sd_at`` its voltage
        self.family_rest_sd = self.family.rest_soc_sd if self.family is not None else 0.0
        # bounds: what the chemistry allows
        top = self.chem.ocv(1.0)
        self.lo = np.array([0.0, -5.0, 0.2 * self.r0p, -0.10, -0.25, 1.0 / 1.6, 0.2 * self.r1p, -5.0, 0.0, 0.0, -math.inf])
        self.hi = np.array([1.0, 5.0, 5.0 * self.r0p, self.chem.max_rest_cell_v - top, 0.25, 1.0 / 0.5, 5.0 * self.r1p, 5.0, 5.0 * self.r1p, 3.0 * self.chem.r_activation_k, math.inf])
        self.x = np.zeros(N_STATE)
        self.P = np.zeros((N_STATE, N_STATE))
        self.initialised = False
        self.time_s = -math.inf
        # charge count from the last rest (the referee): its start SoC and variance, charge drawn since
        self.count_start = math.nan
        self.count_start_var = math.nan
        self.drawn_c = 0.0
        self.total_drawn_c = 0.0
        self.rest_since = math.nan
        self.left_rest_s = math.nan
        self.start_kind = ""
        self.drain = _Drain()
        self.nis: list[float] = []
        self.voltage_trusted = True
        self.why_not_voltage: str | None = None
        self.drain_failed = False
        self.counters = {"voltage_updates": 0, "voltage_gated": 0, "voltage_suspended": 0, "rest_anchors": 0,
                         "voltage_relaxing": 0}
        self.last_voltage_update_s = -math.inf
        #: message time of the last frame at which the pack was rested and settled (the rested
        #: voltage set the SoC and the count started again there; -inf: none yet)
        self.rested_at_s = -math.inf
        #: the sum of the voltage's innovation log-likelihoods so far (every voltage the filter read)
        self.log_likelihood = 0.0
        self.last_u = 0.0
        self._forget_recent_load()
        #: the last temperature read (°C) and the one where the charge count started (NaN: none yet)
        self.temp_c = math.nan
        self.count_temp_c = math.nan

    def _forget_recent_load(self) -> None:
        """No load seen yet (a start, or a start again after a gap in which the pack may have been
        swapped: the shortfall is the old state's model against the old pack, and the old load's
        polarisation has relaxed over the gap, which no step counted)."""
        #: the recent load, A: the present current, or an earlier larger one decaying with the slow
        #: pair's time constant (the polarisation it left is still relaxing)
        self.load_memory_a = 0.0
        #: the recent loaded current (A) and the model's loaded voltage less the measured one at it
        #: (V), means over ``RECENT_LOAD_TAU_S`` (NaN before any load): what the model does not explain now
        self.recent_current_a = math.nan
        self.recent_miss_v = math.nan
        #: how the recent load varies (``calibrated_cutoff`` draws the future from it): the variance
        #: of the shortfall about its mean (V², over ``LOAD_SPREAD_TAU_S``), and of the log of the
        #: held mean's move over each ``RECENT_LOAD_TAU_S`` of load (NaN until one whole span is seen)
        self.recent_miss_var = 0.0
        self.current_move_log_var = math.nan
        self.loaded_s = 0.0
        self._span_start_s = 0.0
        self._span_start_a = math.nan

    # ---- model ---------------------------------------------------------------------------------
    def _ocv(self, soc: float) -> tuple[float, float]:
        """(chemistry ocv, its slope) at soc."""
        s = min(max(soc, 0.0), 1.0)
        return float(np.interp(s, _GRID, self.table)), self.chem.slope(s)

    def _temp_u(self, temperature_c: float) -> float:
        """1/T − 1/298.15 of the pack's temperature (the Arrhenius factor's argument); a missing
        reading is the last one (0 — 25 °C — before any)."""
        if math.isfinite(temperature_c):
            self.last_u = 1.0 / (temperature_c + 273.15) - 1.0 / 298.15
            self.temp_c = temperature_c
            if not math.isfinite(self.count_temp_c):
                self.count_temp_c = temperature_c
        return self.last_u

    def _temp_factor(self, temperature_c: float) -> float:
        """The learned Arrhenius factor at ``temperature_c`` (the last reading's when NaN)."""
        u = 1.0 / (temperature_c + 273.15) - 1.0 / 298.15 if math.isfinite(temperature_c) else self.last_u
        return math.exp(self.x[I_E] * u)

    # ---- frames --------------------------------------------------------------------------------
    def initialise(self, t: float, voltage: float, current: float, temperature_c: float) -> None:
        p = self.prior
        ft = math.exp(self.chem.r_activation_k * self._temp_u(temperature_c))
        i = current if math.isfinite(current) else 0.0
        at_rest = abs(i) < self.rest_current_a
        # the fast pair settled at the present current (a log that starts in flight); the slow pair
        # starts empty (its prior resistance is 0)
        v1 = self.r1p * ft * i
        ocv_cell = (voltage + self.r0p * ft * i + v1) / self.cells - p.ocv_offset_v
        soc = p.soc if p.soc is not None else self.chem.soc_at(ocv_cell)
        soc_sd = p.soc_sd if p.soc is not None else (0.05 if at_rest else 0.15)
        self._to_prior(soc, soc_sd ** 2, v1, (0.5 * v1) ** 2 + 0.01 ** 2)
        self.start_kind = "history" if p.soc is not None else ("rest_voltage" if at_rest else "loaded_voltage")
        self.initialised = True
        self.time_s = t
        self.rest_since = t if at_rest else math.nan
        self._anchor()
        self.voltage_trusted, self.why_not_voltage, self.drain_failed = True, None, False
        self.nis.clear()
        # the recent shortfall is measured against the state just replaced (a restart after a gap:
        # a swapped pack's count-down read its predecessor's sag, 291 s against 646 s fresh)
        self._forget_recent_load()
        self._clip()
        if math.isfinite(voltage):
            self._update(voltage, i, self.last_u, t)

    def _anchor(self) -> None:
        """The charge count starts again from the filter's SoC (at rest, or a start): the count's
        start is the filter's SoC, with the same error."""
        self.count_start = float(self.x[I_SOC])
        self.count_start_var = float(self.P[I_SOC, I_SOC])
        if self.family is not None:
            self.family_rest_sd = self.family.rest_sd_at(self.chem.ocv(self.count_start))
        self.x[I_COUNT0] = self.x[I_SOC]
        self.P[I_COUNT0, :] = self.P[I_SOC, :]
        self.P[:, I_COUNT0] = self.P[:, I_SOC]
        self.P[I_COUNT0, I_COUNT0] = self.P[I_SOC, I_SOC]
        self.drawn_c = 0.0
        self.count_temp_c = self.temp_c
        self.drain = _Drain()
        self.left_rest_s = math.nan

    def step(self, t: float, dt: float, current: float, voltage: float, temperature_c: float) -> None:
        """Advance by ``dt`` at ``current`` (A, discharge positive), then take ``voltage`` (NaN: none)."""
        i = current if math.isfinite(current) else 0.0
        u = self._temp_u(temperature_c)
        if dt > 0:
            self.load_memory_a = max(abs(i), self.load_memory_a * math.exp(-dt / (TAU2_FACTOR * self.chem.tau1_s)))
            self._predict(dt, i, u)
            self.drawn_c += i * dt
            self.total_drawn_c += i * dt
        self.time_s = t
        at_rest = abs(i) < self.rest_current_a
        if at_rest:
            if not math.isfinite(self.rest_since):
                self.rest_since = t
            self.left_rest_s = math.nan
        else:
            if math.isfinite(self.rest_since):  # take-off: the count starts from the rested SoC
                self._anchor()
                self.left_rest_s = t
            elif not math.isfinite(self.left_rest_s):  # a log that starts under load
                self.left_rest_s = t
            self.rest_since = math.nan
        # a pack that has just stopped is not rested: the polarisation its load left relaxes for
        # minutes (diffusion), and read as a rested voltage it is charge that was not drawn (a PyBaMM
        # LG M50 after landing: SoC 0.05-0.08 low within a minute). Until the recent load has decayed
        # (the slow pair's time constant) the count carries the SoC
        relaxing = at_rest and self.load_memory_a > self.rest_current_a
        settled = at_rest and not relaxing and t - self.rest_since >= REST_SETTLE_S
        if settled:
            # on the ground: the rested voltage speaks; the count starts from here
            if not self.voltage_trusted:
                self.counters["rest_anchors"] += 1
            self.voltage_trusted, self.why_not_voltage, self.drain_failed = True, None, False
            self.nis.clear()
        if math.isfinite(voltage):
            if not at_rest and math.isfinite(self.left_rest_s) and t - self.left_rest_s >= DRAIN_SETTLE_S:
                # the polarisation the filter carries is added back: a fit of the raw voltage on
                # [1, I, drawn] reads the pair's slow settling after each step as a flatter fall
                # (quad-4s, C x1.2 from half: 0.27 where the curve falls 1.23, judged not falling)
                self.drain.add(i, self.drawn_c / self.q0, voltage + (self.x.item(I_V1) + self.x.item(I_V2)))
                self._check_drain()
            if relaxing:
                self.counters["voltage_relaxing"] += 1
            else:
                self._update(voltage, i, u, t)
        if settled:
            self._anchor()
            self.start_kind = "rest_voltage"
            self.rested_at_s = t
        elif self.voltage_trusted:
            self._referee()
        if not at_rest and math.isfinite(voltage) and dt > 0:
            self._track_recent_load(dt, i, voltage, u)

    def _track_recent_load(self, dt: float, i: float, voltage: float, u: float) -> None:
        """The recent loaded current and the model's shortfall at it (its mean state after this
        frame's update: the pairs as they are, not settled)."""
        miss = _loaded_voltage(self.x, self.table, self.cells, self.mid, i, u) - voltage
        self.loaded_s += dt
        if not math.isfinite(self.recent_current_a):
            self.recent_current_a, self.recent_miss_v = i, miss
            self._span_start_s = self.loaded_s
            return
        # a plain mean over the load seen while that is shorter than the span: an exponential mean
        # started at the first loaded sample kept 56 % of it at 35 s (a taxi's draw held after take-off)
        w = max(1.0 - math.exp(-dt / RECENT_LOAD_TAU_S), dt / self.loaded_s)
        self.recent_current_a += w * (i - self.recent_current_a)
        self.recent_miss_v += w * (miss - self.recent_miss_v)
        w_spread = 1.0 - math.exp(-dt / LOAD_SPREAD_TAU_S)
        self.recent_miss_var += w_spread * ((miss - self.recent_miss_v) ** 2 - self.recent_miss_var)
        if self.loaded_s - self._span_start_s >= RECENT_LOAD_TAU_S:
            # the held mean's move over one span: how far a held current is from the next span's.
            # The first span's end is the first held mean (its start was one sample: a taxi's 0.5 A
            # against a cruise's 12 A read as a factor of 24)
            if math.isfinite(self._span_start_a):
                move = math.log(max(self.recent_current_a, 1e-6) / max(self._span_start_a, 1e-6)) ** 2
                spans = RECENT_LOAD_TAU_S / LOAD_SPREAD_TAU_S
                self.current_move_log_var = (move if not math.isfinite(self.current_move_log_var) else
                                             self.current_move_log_var + spans * (move - self.current_move_log_var))
            self._span_start_s, self._span_start_a = self.loaded_s, self.recent_current_a

    def _predict(self, dt: float, i: float, u: float) -> None:
        _predict_core(self.x, self.P, dt, i, u, self.q0, self.chem.tau1_s, TAU2_FACTOR * self.chem.tau1_s, self.r0p, self.r1p,
                      R0_WALK, V1_WALK, self.lo, self.hi)

    def _update(self, v: float, i: float, u: float, t: float) -> None:
        # under load the model's error grows with the current: its circuit is a first-order guess
        # of a cell's dynamics (diffusion, a second time constant); LOAD_MODEL_SIGMA of the loaded
        # sag is counted as measurement noise, so a loaded voltage cannot drag the SoC far
        r_meas = self.sigma_v ** 2 + (LOAD_MODEL_SIGMA * (self.r0p + self.r1p) * i) ** 2
        # the capacity and the curve's scale are not observable until a span of the curve has been
        # drawn: earlier, every model error would be read as them (measured: the capacity halved
        # within 200 s on a PyBaMM cell). Held (their gain zero; the Joseph form keeps the covariance
        # right for any gain) until LEARN_AFTER_FRACTION is drawn, and under load while the pack's
        # temperature has moved far from the count's start (``capacity_separable``)
        hold = not self.capacity_separable(i) or self._capacity_held_by_curve()
        reading_held = self._curve_reading_held(i)
        # one compiled call: the innovation, and the update when a trusted filter's gate passes it.
        # Applied before the window below is read: a window that then stops trusting the voltage
        # puts every state back at its prior (``_suspend``), so what the update did is dropped
        trusted = self.voltage_trusted
        nis, s, updated = _innovate_update(self.x, self.P, self.table, self.cells, self.mid, v, i, u, r_meas, hold,
                                           reading_held, self.lo, self.hi, trusted, GATE_SIGMAS ** 2)
        # how well this filter's curve explains the voltage (a Gaussian innovation's log-likelihood,
        # the squared term capped as the window's is): ``curve_bank`` weighs curve hypotheses by it
        self.log_likelihood -= 0.5 * (min(nis, 25.0) + math.log(s))
        self.nis.append(min(nis, 25.0))
        if len(self.nis) > NIS_WINDOW:
            del self.nis[0]
        if len(self.nis) == NIS_WINDOW:
            mean = sum(self.nis) / NIS_WINDOW
            if self.voltage_trusted and mean > NIS_RAISE:
                self._suspend(f"the model cannot follow the voltage (mean normalised innovation {mean:.1f} over "
                              f"{NIS_WINDOW} updates, bound {NIS_RAISE:g})")
            elif not self.voltage_trusted and not self.drain_failed and mean < NIS_CLEAR:
                self.voltage_trusted, self.why_not_voltage = True, None
        if not self.voltage_trusted:
            return
        if nis > GATE_SIGMAS ** 2:
            self.counters["voltage_gated"] += 1
            return
        if not updated:  # trusted again by this very innovation: its update was not applied above
            # (through the same compiled call, whose signature the warm-up has compiled)
            _innovate_update(self.x, self.P, self.table, self.cells, self.mid, v, i, u, r_meas, hold, reading_held,
                             self.lo, self.hi, True, math.inf)
        self.counters["voltage_updates"] += 1
        if not reading_held:  # the evidence's ``voltage_model``: the voltage corrects the SoC
            self.last_voltage_update_s = t

    def capacity_separable(self, current: float) -> bool:
        """Whether a voltage at ``current`` can teach the capacity (and the curve's scale) now: a
        span of the curve has been drawn since the count started (``LEARN_AFTER_FRACTION``), and,
        under load, the pack is within ``CAPACITY_TEMP_SPAN_K`` of the temperature it started at —
        else the sag's drift with temperature, which the circuit does not fully model, is what the
        voltage's fall would teach. At rest there is no sag: a rested voltage after charge drawn is
        the capacity's cleanest evidence at any temperature."""
        if self.drawn_c < LEARN_AFTER_FRACTION * self.q0:
            return False
        if abs(current) < self.rest_current_a:
            return True
        moved = abs(self.temp_c - self.count_temp_c)
        return not moved > CAPACITY_TEMP_SPAN_K  # no temperature read: nothing moved

    # ---- a curve known only as its chemistry's (``CurveFamilySpread.count_in_flight``) -----------
    def _capacity_held_by_curve(self) -> bool:
        """The capacity (and the curve's scale) stays at its prior: the voltage's fall per charge
        drawn is read through the table's slope, and the chemistry's published slopes differ more
        than the capacity's prior (learned 0.77-1.49x the truth through the Li-ion table)."""
        return self.family is not None and self.family.count_in_flight

    def _curve_reading_held(self, current: float) -> bool:
        """Under load the voltage does not move the SoC or the curve's offset (the charge count
        carries the SoC from the rested start); it still teaches the circuit. A rested voltage reads
        the SoC through the table as before."""
        return self._capacity_held_by_curve() and abs(current) >= self.rest_current_a

    def _to_prior(self, soc: float, soc_var: float, v1: float, v1_var: float) -> None:
        """State and covariance at ``soc`` and fast-pair voltage ``v1``, every parameter at its prior."""
        p, ea = self.prior, self.chem.r_activation_k
        self.x = np.array([soc, v1, self.r0p, p.ocv_offset_v, p.ocv_scale, 1.0, self.r1p, 0.0, self.r2p, ea, soc])
        self.P = np.diag([soc_var, v1_var, (p.r0_rel_sd * self.r0p) ** 2, p.ocv_offset_sd ** 2, p.ocv_scale_sd ** 2,
                          p.capacity_rel_sd ** 2, (p.r0_rel_sd * self.r1p) ** 2, 0.01 ** 2, (R2_SD * self.r1p) ** 2,
                          (ACTIVATION_REL_SD * ea) ** 2, soc_var])
        self.P[I_SOC, I_COUNT0] = self.P[I_COUNT0, I_SOC] = soc_var

    def _clip(self) -> None:
        np.clip(self.x, self.lo, self.hi, out=self.x)

    def _count(self) -> tuple[float, float]:
        """The pure charge count from the last anchor: (SoC, variance) with the prior capacity."""
        frac = self.drawn_c / self.q0
        return (self.count_start - frac,
                self.count_start_var + (frac * self.prior.capacity_rel_sd) ** 2)

    def charge_count(self) -> tuple[float, float]:
        """The pure charge count from the last rest (or start): (SoC, variance), prior capacity."""
        return self._count()

    def count_difference_sd(self) -> float:
        """σ of (filter SoC − the charge count from the last anchor). The start's error is common to
        both and cancels, as far as the voltage has not corrected it (P[SoC, count start] says how
        far); the count's own error is its capacity's. Adding the two variances counted the start
        twice: a bound of 0.25-0.55 SoC that almost never tripped."""
        frac = self.drawn_c / self.q0
        p = self.P  # ``item``: Python floats (a per-frame read, via ``_referee``)
        var = (p.item(I_SOC, I_SOC) + p.item(I_COUNT0, I_COUNT0) - 2.0 * p.item(I_SOC, I_COUNT0)
               + (frac * self.prior.capacity_rel_sd) ** 2)
        return math.sqrt(max(var, 0.0))

    def _referee(self) -> None:
        soc, _ = self._count()
        sd = self.count_difference_sd()
        if abs(self.x.item(I_SOC) - soc) > REFEREE_SIGMAS * sd + 0.03:
            self._suspend(f"the voltage contradicts the charge count beyond the capacity's uncertainty "
                          f"(voltage {self.x[I_SOC]:.2f}, count {soc:.2f} ± {sd:.2f})")

    def _check_drain(self) -> None:
        if self.drain.n % DRAIN_CHECK_EVERY or self.drain_failed:  # the cheap tests first: a per-frame call
            return
        frac = self.drawn_c / self.q0
        if frac < DRAIN_MIN_FRACTION:
            return
        c, se = self.drain.slope()
        if not math.isfinite(c):
            return
        s0 = self.count_start
        expected = self.cells * (self.chem.ocv(s0) - self.chem.ocv(s0 - frac)) / frac
        # missing beyond its own noise (DRAIN_SIGMAS standard errors), not a noisy slope's luck
        if -c + DRAIN_SIGMAS * se < DRAIN_MIN_RATIO * expected:
            self.drain_failed = True
            self._suspend(f"the voltage does not fall as charge is drawn ({-c:.2f} V per capacity drawn, the "
                          f"{self.chem.name} curve falls {expected:.2f} over {frac:.0%} drawn)")

    def _suspend(self, why: str) -> None:
        """Stop trusting the voltage: the SoC continues as the charge count from the last anchor
        (prior capacity, its σ growing with the capacity's uncertainty); the learned parameters go
        back to their priors (what they learned followed a voltage the model could not)."""
        if not self.voltage_trusted:
            return
        self.voltage_trusted, self.why_not_voltage = False, why
        self.counters["voltage_suspended"] += 1
        soc, var = self._count()
        p = self.prior
        self._to_prior(soc, self.count_start_var, 0.0, 0.01 ** 2)
        frac = self.drawn_c / self.q0
        # the SoC's dependence on the capacity since the anchor: SoC = start − g·frac
        self.P[I_SOC, I_G] = self.P[I_G, I_SOC] = -frac * p.capacity_rel_sd ** 2
        self.P[I_SOC, I_SOC] = var
        # the SoC is now the count: it errs with the count's start
        self.x[I_COUNT0] = self.count_start
        self.P[I_COUNT0, I_COUNT0] = self.P[I_SOC, I_COUNT0] = self.P[I_COUNT0, I_SOC] = self.count_start_var
        self._clip()

    # ---- read-outs -----------------------------------------------------------------------------
    @property
    def soc(self) -> float:
        return float(self.x[I_SOC]) if self.initialised else math.nan

    @property
    def soc_sd(self) -> float:
        """The filter's σ, and, when the curve is only the chemistry's table, what that curve cannot
        tell (``curve_family_sd``): the filter's covariance cannot hold it, as no voltage of the
        flight separates the chemistry's published curves."""
        if not self.initialised:
            return math.nan
        return math.sqrt(max(self.P.item(I_SOC, I_SOC), 0.0) + self.curve_family_sd() ** 2)

    @property
    def filter_soc_sd(self) -> float:
        """The filter's own σ (its covariance), without the curve family: what the count-down and
        the route risk draw from (they do not carry the family yet: issue 29's follow-up)."""
        return math.sqrt(max(float(self.P[I_SOC, I_SOC]), 0.0)) if self.initialised else math.nan

    def curve_family_sd(self) -> float:
        """The SoC σ the chemistry's family of published curves leaves (0 for a pack's own curve):
        their spread at the rested start, and their slopes' spread times the charge drawn since it
        (the voltage read through a curve of the wrong slope reads that share of it wrong)."""
        if self.family is None:
            return 0.0
        if self.family.count_in_flight:
            # the voltage does not read the SoC in flight: the count's error is the capacity's,
            # which the filter's covariance holds (its capacity is held at the prior's σ)
            return self.family_rest_sd
        return math.hypot(self.family_rest_sd, self.family.slope_rel_sd * self.drawn_c / self.q0)

    def evidence(self, now: float | None = None) -> list[str]:
        if not self.initialised:
            return []
        now = self.time_s if now is None else now
        out = [self.start_kind] if self.start_kind else []
        if self.total_drawn_c > 0:
            out.append("coulomb")
        if self.voltage_trusted and now - self.last_voltage_update_s <= 10.0:
            out.append("voltage_model")
        if self.P[I_G, I_G] > 0.8 * self.prior.capacity_rel_sd ** 2:
            out.append("prior")
        return out

    def report(self) -> dict:
        """JSON-ready: SoC, σ, evidence, the learned parameters with their σ, why the voltage is not
        trusted (None while it is)."""
        sd = np.sqrt(np.maximum(np.diag(self.P), 0.0))

        def r(v, nd=4):
            return round(float(v), nd) if math.isfinite(float(v)) else None

        return {"soc": r(self.soc), "soc_sd": r(self.soc_sd), "evidence": self.evidence(),
                "chemistry": self.chem.name, "voltage_trusted": self.voltage_trusted,
                "voltage_not_trusted_because": self.why_not_voltage,
                "capacity_ah": r(self.q0 / 3600.0 / self.x[I_G], 3),
                "capacity_rel_sd": r(sd[I_G] / self.x[I_G], 3),
                "capacity_source": self.prior.capacity_source,
                "series_resistance_ohm": r(self.x[I_R0], 5), "series_resistance_sd": r(sd[I_R0], 5),
                "polarisation_resistance_ohm": r(self.x[I_R1], 5), "polarisation_resistance_sd": r(sd[I_R1], 5),
                "slow_polarisation_resistance_ohm": r(self.x[I_R2], 5), "slow_polarisation_resistance_sd": r(sd[I_R2], 5),
                "resistance_activation_k": r(self.x[I_E], 0), "resistance_activation_sd": r(sd[I_E], 0),
                "ocv_offset_v_per_cell": r(self.x[I_DV]), "ocv_offset_sd": r(sd[I_DV]),
                "ocv_scale": r(self.x[I_K]), "ocv_scale_sd": r(sd[I_K]),
                "counters": dict(self.counters)}


_GRID = np.linspace(0.0, 1.0, 21)


# ---- the compiled numeric core (one pack, one frame; the class keeps the bookkeeping) ---------------
@njit(cache=True, nogil=True)
def _curve(table, soc):
    """(chemistry ocv, its segment slope) at soc on the 21-point grid."""
    s = min(max(soc, 0.0), 1.0)
    k = min(int(s * 20.0), 19)
    slope = (table[k + 1] - table[k]) * 20.0
    return table[k] + slope * (s - k / 20.0), slope


@njit(cache=True, nogil=True)
def _clip_into(x, lo, hi):
    """``np.clip(x, lo, hi, out=x)`` inside the compiled steps (a NumPy call from Python costs more
    than the step's arithmetic)."""
    for r in range(x.size):
        if x[r] < lo[r]:  # comparisons, not min/max: a NaN stays NaN, as np.clip leaves it
            x[r] = lo[r]
        elif x[r] > hi[r]:
            x[r] = hi[r]


@njit(cache=True, nogil=True)
def _loaded_voltage(x, table, cells, mid, i, u):
    """The model's loaded voltage at the mean state (the pairs as they are, not settled)."""
    ocv, _ = _curve(table, x[0])
    return cells * (ocv + x[3] + x[4] * (ocv - mid)) - x[1] - x[7] - x[2] * math.exp(x[9] * u) * i


@njit(cache=True, nogil=True)
def _predict_core(x, P, dt, i, u, q0, tau1, tau2, r0p, r1p, r0_walk, v1_walk, lo, hi):
    # the pair keeps its prior's capacitance: its time constant follows its learned resistance
    # (tau = tau1 R1 / R1_prior), as the pack model's own concentration pair does (tau_cp = R_cp C_cp).
    # With tau fixed, a pack of 3x the resistance sags 3x slower than the filter expects and the
    # slow part of its sag reads as charge drawn (SoC 0.18 low, quad-4s R x3)
    n = x.size
    ft = math.exp(x[9] * u)
    r1 = max(x[6], 1e-9)
    tau = tau1 * r1 / r1p
    a = math.exp(-dt / tau)
    f_sg = -i * dt / q0
    # d v1'/d R1: the steady state's (1 - a) f I and the time constant's a dt / (tau R1) (v1 - R1 f I)
    f_vr = (1.0 - a) * ft * i + a * dt / (tau * r1) * (x[1] - r1 * ft * i)
    a2 = math.exp(-dt / tau2)
    f_v2r = (1.0 - a2) * ft * i
    # d/dE of the pairs' steady states: R f(T) I (1/T − 1/298.15)
    f_v1e = (1.0 - a) * r1 * ft * i * u
    f_v2e = (1.0 - a2) * x[8] * ft * i * u
    x[0] += x[5] * f_sg
    x[1] = a * x[1] + (1.0 - a) * r1 * ft * i
    x[7] = a2 * x[7] + (1.0 - a2) * x[8] * ft * i
    # P <- F P F' with F = I except F[0,5] = f_sg, F[1,1] = a, F[1,6] = f_vr: rows then columns
    for c in range(n):
        P[0, c] += f_sg * P[5, c]
        P[1, c] = a * P[1, c] + f_vr * P[6, c] + f_v1e * P[9, c]
        P[7, c] = a2 * P[7, c] + f_v2r * P[8, c] + f_v2e * P[9, c]
    for r in range(n):
        P[r, 0] += f_sg * P[r, 5]
        P[r, 1] = a * P[r, 1] + f_vr * P[r, 6] + f_v1e * P[r, 9]
        P[r, 7] = a2 * P[r, 7] + f_v2r * P[r, 8] + f_v2e * P[r, 9]
    P[0, 0] += (0.002 * abs(i) * dt / q0) ** 2 + 1e-9 * dt
    P[1, 1] += v1_walk ** 2 * dt
    P[2, 2] += (r0_walk * r0p) ** 2 * dt
    P[3, 3] += 2e-5 ** 2 * dt
    P[4, 4] += 2e-5 ** 2 * dt
    P[5, 5] += 2e-5 ** 2 * dt
    P[6, 6] += (r0_walk * r1p) ** 2 * dt
    P[7, 7] += v1_walk ** 2 * dt
    P[8, 8] += (r0_walk * r1p) ** 2 * dt
    _clip_into(x, lo, hi)


@njit(cache=True, nogil=True)
def _measurement(x, table, cells, mid, i, u, h):
    ocv, slope = _curve(table, x[0])
    ft = math.exp(x[9] * u)
    h[0] = cells * slope * (1.0 + x[4])
    h[1] = -1.0
    h[2] = -ft * i
    h[3] = cells
    h[4] = cells * (ocv - mid)
    h[5] = 0.0
    h[6] = 0.0
    h[7] = -1.0
    h[8] = 0.0
    h[9] = -x[2] * ft * i * u
    h[10] = 0.0
    return cells * (ocv + x[3] + x[4] * (ocv - mid)) - x[1] - x[2] * ft * i - x[7]


@njit(cache=True, nogil=True)
def _innovation_core(x, P, table, cells, mid, v, i, u, r_meas):
    """(ν²/S, S) of the voltage ``v`` against the mean state."""
    h = np.empty(x.size)
    pred = _measurement(x, table, cells, mid, i, u, h)
    s = r_meas
    for r in range(x.size):
        for c in range(x.size):
            s += h[r] * P[r, c] * h[c]
    nu = v - pred
    return nu * nu / s, s


@njit(cache=True, nogil=True)
def _update_core(x, P, table, cells, mid, v, i, u, r_meas, hold, hold_reading, lo, hi):
    """The Kalman update of the voltage (Joseph form; with ``hold`` the capacity's and the curve
    scale's gains are zero, with ``hold_reading`` the SoC's and the curve offset's)."""
    n = x.size
    h = np.empty(n)
    pred = _measurement(x, table, cells, mid, i, u, h)
    ph = P @ h
    s = r_meas
    for r in range(n):
        s += h[r] * ph[r]
    k = ph / s
    k[10] = 0.0  # the count's start: never updated, only its covariance with the rest is carried
    if hold:
        k[5] = 0.0
        k[4] = 0.0
    if hold_reading:
        k[0] = 0.0
        k[3] = 0.0
    nu = v - pred
    for r in range(n):
        x[r] += k[r] * nu
    ikh = np.eye(n)
    for r in range(n):
        for c in range(n):
            ikh[r, c] -= k[r] * h[c]
    newp = ikh @ P @ ikh.T
    for r in range(n):
        for c in range(n):
            P[r, c] = newp[r, c] + k[r] * k[c] * r_meas
    _clip_into(x, lo, hi)


@njit(cache=True, nogil=True)
def _innovate_update(x, P, table, cells, mid, v, i, u, r_meas, hold, hold_reading, lo, hi, apply, gate):
    """``_innovation_core``'s (ν²/S, S), and ``_update_core`` applied when ``apply`` and ν²/S ≤
    ``gate`` (the third value says whether it was): one call from Python instead of two."""
    nis, s = _innovation_core(x, P, table, cells, mid, v, i, u, r_meas)
    if apply and nis <= gate:
        _update_core(x, P, table, cells, mid, v, i, u, r_meas, hold, hold_reading, lo, hi)
        return nis, s, True
    return nis, s, False


@njit(cache=True, nogil=True)
def _drain_fit(n, sums, vv):
    """``_Drain.slope``'s least squares, compiled (every few loaded frames, where NumPy's
    ``inv`` and the arrays around it cost ten times the arithmetic): the normal equations
    (+1e-12 on the diagonal) solved by Gaussian elimination with partial pivoting, as LAPACK's
    ``gesv`` (a constant current leaves the intercept and the current's term inseparable, but not
    the slope), against [Aᵀv, e₂] for the solution and the inverse's last diagonal element."""
    a = np.empty((3, 3))
    a[0, 0], a[0, 1], a[0, 2] = n + 1e-12, sums[0], sums[1]
    a[1, 0], a[1, 1], a[1, 2] = sums[0], sums[2] + 1e-12, sums[3]
    a[2, 0], a[2, 1], a[2, 2] = sums[1], sums[3], sums[4] + 1e-12
    b = np.zeros((3, 2))
    b[0, 0], b[1, 0], b[2, 0], b[2, 1] = sums[5], sums[6], sums[7], 1.0
    for k in range(3):
        p = k
        for r in range(k + 1, 3):
            if abs(a[r, k]) > abs(a[p, k]):
                p = r
        if not a[p, k] != 0.0:  # singular, or not a number
            return math.nan, math.nan
        if p != k:
            for c in range(3):
                a[k, c], a[p, c] = a[p, c], a[k, c]
            for c in range(2):
                b[k, c], b[p, c] = b[p, c], b[k, c]
        for r in range(k + 1, 3):
            f = a[r, k] / a[k, k]
            for c in range(k, 3):
                a[r, c] -= f * a[k, c]
            for c in range(2):
                b[r, c] -= f * b[k, c]
    x = np.zeros((3, 2))
    for r in range(2, -1, -1):
        for c in range(2):
            acc = b[r, c]
            for j in range(r + 1, 3):
                acc -= a[r, j] * x[j, c]
            x[r, c] = acc / a[r, r]
    s2 = max(vv - (x[0, 0] * sums[5] + x[1, 0] * sums[6] + x[2, 0] * sums[7]), 0.0) / (n - 3.0)
    return x[2, 0], math.sqrt(max(s2 * x[2, 1], 0.0))
