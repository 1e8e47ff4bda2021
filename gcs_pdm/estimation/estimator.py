"""The state estimator: telemetry frames in, pack and motor state (with uncertainty) out.

Frames arrive asynchronously, one pack or one motor at a time; each component is advanced by
*message* time from its own previous frame. Inputs are guarded before they reach the filters:

- a pack current that disagrees wildly with what the other pack of its series string and its
  motor report (they carry the same current) is a spike and is replaced by their value;
- a missing current holds the last one (the string-mate's or the motor's if fresher);
- frames older than the component's last one are dropped and counted (a link re-ordering);
- a sensor not heard from for ``stale_after_s`` is reported in ``Estimate.missing``.

Core: no clocks, no I/O — ``consume`` is all there is.
"""
from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from gcs_pdm.estimation.calibration import PackCalibrator, prior_of_spec
from gcs_pdm.estimation.curve_bank import CurveBank, pack_calibrator
from gcs_pdm.estimation.fitted_prior import FittedPackWatch, fitted_prior
from gcs_pdm.estimation.motor_filter import MotorFilterConfig, MotorThermalFilter
from gcs_pdm.estimation.pack_filter import CHANNELS, ExtendedPackFilterBank, PackFilterBank, PackFilterConfig
from gcs_pdm.frames import AmbientFrame, MotorFrame, PackFrame
from gcs_pdm.models import kernel
from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES, ParameterSet
from gcs_pdm.models.powertrain import PowertrainState
from gcs_pdm.vehicle.description import VehicleDescription
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS

log = logging.getLogger(__name__)

#: outside these the estimate is not a state the model can be in: report a mismatch instead
SOC_RANGE = (0.0, 1.0)
TEMPERATURE_RANGE_C = (-100.0, 100.0)
#: how far (plus RANGE_SIGMAS σ) a SoC may sit outside SOC_RANGE before it is a mismatch rather than
#: noise to clip: a full pack read a little high is not a broken model, a SoC of 1.13 or -4.5 is
RANGE_SIGMAS = 3.0
SOC_SLACK = 0.05
#: a pack filter whose re-locks leave a variance over this many times one re-lock's inflation of
#: its initial value is restarted (``StateEstimator._relock_left_sane``): one re-lock from the
#: initial state stays under it, compounded re-locks do not
RELOCK_CEILING = 4.0
#: a self-calibrated pack's resistance follows its temperature, so a reading a pack's thermal mass
#: cannot reach (faster than this slew, K/s, beyond the slack, K) is held at the last one believed: a
#: loose thermistor flapping 30 <-> 100 °C would otherwise move the calibrator's SoC by 0.5
CALIBRATOR_TEMP_SLEW_K_PER_S = 2.0
CALIBRATOR_TEMP_SLACK_K = 3.0
#: a temperature no sensor measures is the thermal model's: its rise over the air carries the
#: model's own doubt — an unfitted description's heat capacity, cooling and resistance can each be
#: off by half (1σ of the rise), and the air temperature is a default unless one was heard
MODELLED_RISE_REL_SIGMA = 0.4
UNKNOWN_AMBIENT_SIGMA_C = 5.0
HEARD_AMBIENT_SIGMA_C = 1.0
#: an ambient reading older than this is no longer the air's
AMBIENT_FRESH_S = 30.0


@dataclass(frozen=True)
class EstimatorConfig:
    pack: PackFilterConfig = PackFilterConfig()
    motor: MotorFilterConfig = MotorFilterConfig()
    default_ambient_c: float = 20.0
    #: a pack current this far from its string's other readings is a spike, A (or half the reading)
    current_spike_a: float = 8.0
    #: how recent a corroborating reading must be, s
    corroborate_within_s: float = 2.0
    stale_after_s: float = 5.0
    #: longest gap the filters integrate through in one step; longer gaps are still integrated,
    #: but logged, because the held current is then a guess
    long_gap_s: float = 30.0
    #: a gap longer than this restarts the component's filter from its next reading: the held current
    #: (or heat) says nothing about hours of silence — the vehicle was parked, charged or swapped
    restart_after_s: float = 600.0
    #: relative uncertainty of the parameter set's capacity against the real pack (1σ). No
    #: telemetry can remove it within a flight — the voltage-to-charge map carries the same
    #: mismatch — so it is added to the filter's SoC spread: σ² = σ_filter² + (σ_cap (1 - SoC))².
    #: 0.12: the SoC error follows C_b, ±15 % log-uniform in the simulated vehicle's truth (close to
    #: an uncalibrated set's spread), which alone is 0.087; the other parameters' mismatch in the
    #: voltage-to-charge map adds to it, and with 0.12 the measured 2σ coverage is still only
    #: 89-94 % (docs/estimation.md), so a smaller value would be overconfident
    capacity_rel_sigma: float = 0.12
    #: a described vehicle's packs (not the paper aircraft's fitted set) are estimated by the
    #: self-calibrating filter (``estimation.calibration``): chemistry curve, adapted capacity,
    #: resistance and curve, the charge count as its floor (issue 29)
    self_calibrate: bool = True
    #: a fitted pack (edge540's, a parameter set's) is watched by a self-calibrating filter whose
    #: prior is its set; the filter takes over when the flight contradicts the set
    #: (``estimation.fitted_prior``). Off: the set is flown as it is, whatever the flight says
    fitted_set_as_prior: bool = True


@dataclass(frozen=True)
class Estimate:
    """Snapshot of the estimator at message time ``time_s`` (PACK_NAMES / MOTOR_NAMES order)."""

    time_s: float
    soc: np.ndarray
    soc_sd: np.ndarray
    pack_temp_c: np.ndarray
    pack_temp_sd: np.ndarray
    pack_voltage_v: np.ndarray
    motor_temp_c: np.ndarray
    motor_temp_sd: np.ndarray
    ambient_c: float
    missing: tuple[str, ...] = ()
    counters: dict = field(default_factory=dict)
    pack_names: tuple[str, ...] = PACK_NAMES
    motor_names: tuple[str, ...] = MOTOR_NAMES
    #: packs whose temperature is the thermal model's, not a sensor's (the sd says how well)
    modelled_temperature: tuple[str, ...] = ()
    #: estimates the model cannot hold (SoC outside [0, 1], temperature outside ±100 °C): withheld
    mismatch: tuple[str, ...] = ()
    motor_current_a: np.ndarray | None = None
    motor_rpm: np.ndarray | None = None
    #: per pack name: the model-consistency test and its evidence (``StateEstimator.model_check``)
    model_mismatch: dict = field(default_factory=dict)
    #: per self-calibrated pack name: what its SoC rests on (``calibration.PackCalibrator.evidence``)
    evidence: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        def r(a, nd=4):
            return [None if not math.isfinite(float(x)) else round(float(x), nd) for x in a]

        return {
            "time_s": self.time_s,
            "packs": {n: {"soc": r([self.soc[i]])[0], "soc_sd": r([self.soc_sd[i]])[0],
                          "temperature_c": r([self.pack_temp_c[i]], 2)[0], "temperature_sd": r([self.pack_temp_sd[i]], 2)[0],
                          "voltage_v": r([self.pack_voltage_v[i]], 3)[0],
                          **({"temperature_source": "model"} if n in self.modelled_temperature else {}),
                          **({"model_mismatch": self.model_mismatch[n]} if n in self.model_mismatch else {}),
                          **({"evidence": list(self.evidence[n])} if n in self.evidence else {})}
                      for i, n in enumerate(self.pack_names)},
            "motors": {n: {"temperature_c": r([self.motor_temp_c[i]], 2)[0],
                           "temperature_sd": r([self.motor_temp_sd[i]], 2)[0],
                           **({} if self.motor_current_a is None else
                              {"current_a": r([self.motor_current_a[i]], 2)[0], "rpm": r([self.motor_rpm[i]], 0)[0]})}
                       for i, n in enumerate(self.motor_names)},
            "ambient_c": self.ambient_c,
            "missing": list(self.missing),
            "counters": dict(self.counters),
            **({"mismatch": list(self.mismatch)} if self.mismatch else {}),
        }


class _ArrayCopy:
    """A read-only property giving a float64 array copy of the instance's list attribute ``name``."""

    def __init__(self, name: str, doc: str | None = None):
        self.name, self.__doc__ = name, doc

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return np.array(getattr(obj, self.name), dtype=np.float64)

    def __set__(self, obj, value):
        raise AttributeError(f"read-only: the estimator keeps {self.name} itself")


class StateEstimator:
    """Per-pack UKF and per-motor thermal filter, driven frame by frame.

    The packs and motors are ``vehicle``'s (a ``VehicleDescription``; the paper's aircraft is the
    ``edge540`` preset), in its order, on its buses. ``params``: a parameter set (the paper's, a
    learned one) whose values are flown over the description's (``model_inputs(vehicle, params)``:
    each pack's by its name, extended packs on their extended filter); such packs are flown as the
    set has them until the flight contradicts the set (``fitted_watch``, ``estimation.fitted_prior``)."""

    def __init__(self, params: ParameterSet | None = None, config: EstimatorConfig = EstimatorConfig(), *,
                 vehicle: VehicleDescription = PRESETS[DEFAULT_PRESET]):
        #: the parameter set flown over the description's values (None: the description's own)
        self.params = params
        #: the vehicle description the packs and motors come from
        self.vehicle = vehicle
        self.config = config
        inputs = self.inputs = model_inputs(vehicle, params)
        #: which bus each pack and motor is on, and how each bus joins its packs
        self.topology = inputs.topology
        self.pack_names, self.motor_names = inputs.pack_names, inputs.motor_names
        pack_matrix, motor_matrix = inputs.pack_matrix, inputs.motor_matrix
        self._mates = {b: inputs.series_mates(b) for b in range(inputs.n_packs)}
        self._motors_of_pack = {b: inputs.motors_of_pack(b) for b in range(inputs.n_packs)}
        self._packs_of_motor = {q: inputs.packs_of_motor(q) for q in range(inputs.n_motors)}
        self._pack_reports_temp = np.array([p.reports_temperature for p in vehicle.packs])
        self._motor_reports = {m.name: m.readings for m in vehicle.motors}
        self._min_references = vehicle.current_references
        # a derived (provisional) description's packs start from the chemistry table's curve; a
        # described pack from its own model's; a pack described as fitted (edge540's) keeps it, and so
        # does every pack of a parameter set flown over the description
        calib = [pack_calibrator(prior_of_spec(p, None if vehicle.provisional else pack_matrix[b]))
                 if config.self_calibrate and p.self_calibrate and not inputs.from_parameter_set else None
                 for b, p in enumerate(vehicle.packs)]
        ext_vectors = inputs.extended_packs
        self._base_pack_matrix = np.array(pack_matrix, copy=True)
        #: per pack: its self-calibrating filter (None: the paper filter's SoC: a pack described
        #: with ``self_calibrate`` off, as edge540's, or a parameter set's). The paper filter then
        #: carries the pack's temperature and, for the users of its layout (predictions, the
        #: planner), the calibrated SoC (``_sync_paper``)
        self.calib: list[PackCalibrator | CurveBank | None] = calib
        #: per fitted pack (no calibrator of its own, paper variant): the self-calibrating filter that
        #: runs beside its paper filter and becomes its ``calib`` when the flight contradicts the set
        self.fitted_watch: list[FittedPackWatch | None] = [
            FittedPackWatch(fitted_prior(prior_of_spec(p, pack_matrix[b])), capacity_rel_sd=config.capacity_rel_sigma,
                            chemistry_prior=prior_of_spec(p))
            if config.fitted_set_as_prior and calib[b] is None and b not in ext_vectors else None
            for b, p in enumerate(vehicle.packs)]
        n_packs, n_motors = len(self.pack_names), len(self.motor_names)
        self.packs = PackFilterBank(pack_matrix, config.pack)
        # packs of the extended variant (docs/model.md) are estimated by their own filter; the paper
        # filter keeps running on their paper values for the users of the paper layout (the
        # diagnoser's pack-health fit, the planner's state)
        self.ext_row = {b: r for r, b in enumerate(sorted(ext_vectors))}
        self.ext = (ExtendedPackFilterBank(np.stack([ext_vectors[b] for b in sorted(ext_vectors)]), config.pack)
                    if ext_vectors else None)
        self._base_ext_matrix = None if self.ext is None else self.ext.params.copy()
        self.motors = MotorThermalFilter(motor_matrix, n_motors, config.motor)
        self.ambient_c = config.default_ambient_c
        self.time_s = -math.inf
        self._pack_index = {n: i for i, n in enumerate(self.pack_names)}
        self._motor_index = {n: i for i, n in enumerate(self.motor_names)}
        # per pack and motor: the message time of its last frame, its cleaned current and when it was
        # last set, the latest measured current as measured (and when), the motors' rpm, the charge
        # drawn since the filter started (cleaned current × dt, C). Python lists of floats: every frame
        # reads and writes a few of them, and a numpy scalar costs several times a list item; the
        # public names (``pack_current`` etc.) are read-only numpy copies
        self._pack_time = [-math.inf] * n_packs
        self._pack_current = [math.nan] * n_packs
        self._pack_current_time = [-math.inf] * n_packs
        # message time of each pack's latest current that was read, its own or a mate's or motor's
        # (not held over): a prediction needs a current that is still being read
        self._current_read_time = [-math.inf] * n_packs
        self._reading = [math.nan] * n_packs
        self._reading_time = [-math.inf] * n_packs
        self._motor_time = [-math.inf] * n_motors
        self._motor_current = [math.nan] * n_motors
        self._motor_current_time = [-math.inf] * n_motors
        self._motor_rpm = [math.nan] * n_motors
        self._charge_c = [0.0] * n_packs
        #: per pack: (time, °C) of the last temperature reading the calibrator believed
        self._calibrator_temp = [(-math.inf, math.nan)] * n_packs
        # currents of the frames that arrived while message time stood still (a link that stamps
        # untimed messages with the last timed one): their mean is the current over the next step
        self._i_sum = [0.0] * n_packs
        self._i_n = [0] * n_packs
        # per pack: the motor whose current is the pack's own (it feeds that motor alone, and the
        # motor is fed by the pack's series string alone), else None
        self._own_motor = [
            self._motors_of_pack[b][0] if len(self._motors_of_pack[b]) == 1
            and len(self._packs_of_motor[self._motors_of_pack[b][0]]) == 1 + len(self._mates[b]) else None
            for b in range(n_packs)]
        # the ``seen`` keys of each pack's and motor's channels (built once, not per frame)
        self._pack_keys = [tuple(f"{n}.{c}" for c in ("current", "voltage", "temperature")) for n in self.pack_names]
        self._motor_keys = [tuple(f"{n}.{c}" for c in ("current", "rpm", "temperature")) for n in self.motor_names]
        # frame type -> handler (``consume``); a type not seen before is looked up once by isinstance
        self._handlers: dict[type, object] = {}
        # per sensor channel: last message time it carried a value
        self.seen: dict[str, float] = {}
        self.counters: Counter = Counter()
        self._failed_filters: set[str] = set()  # components whose filter failure was logged
        # a pack filter's re-lock multiplies its covariance (the states the channel does not see
        # too); re-locks that keep coming before updates shrink it again (a sensor flapping between
        # two in-range readings) compound without bound. After each re-lock the row is checked
        # against a ceiling of its initial variances (``_relock_left_sane``)
        self._pack_relocks_seen = [0] * n_packs
        self._ext_relocks_seen = [0] * len(self.ext_row)
        self._pack_cov_ceiling = np.full((n_packs, self.packs.cov.shape[-1]), np.inf)
        self._ext_cov_ceiling = np.full((len(self.ext_row), self.ext.cov.shape[-1] if self.ext is not None else 0),
                                        np.inf)
        # model-consistency test per pack (pack_filter.ConsistencyWindow): whether it is raised and
        # the message time it was raised or cleared (a list of bools: read on every pack frame)
        self._mismatch_active = [False] * n_packs
        self._mismatch_since = np.full(n_packs, np.nan)
        # per-frame reads, as Python values: the extended filter's row of each pack (-1: none), the
        # config's floats
        self._ext_row_of = [self.ext_row.get(b, -1) for b in range(n_packs)]
        self._spike_a = float(config.current_spike_a)
        self._within_s = float(config.corroborate_within_s)
        self._long_gap_s = float(config.long_gap_s)
        self._restart_after_s = float(config.restart_after_s)

    # ---- frames ----------------------------------------------------------------------------------
    def consume(self, frame) -> None:
        handler = self._handlers.get(type(frame))
        if handler is None:
            handler = self.handler_for(frame)
        handler(frame)

    def handler_for(self, frame):
        """What ``consume`` does with a frame of this type (a callable taking the frame; looked up
        once per type). A frame that carries nothing the estimator uses (position, air data, status,
        mission progress: most of a log) gets ``ignore_frame``, so it costs one dictionary look-up."""
        handler = self._handlers.get(type(frame))
        if handler is None:
            handler = ignore_frame
            for kind, fn in ((PackFrame, self._pack), (MotorFrame, self._motor), (AmbientFrame, self._ambient)):
                if isinstance(frame, kind):
                    handler = fn
                    break
            self._handlers[type(frame)] = handler
        return handler

    def _ambient(self, frame: AmbientFrame) -> None:
        if frame.temperature_c is not None and math.isfinite(frame.temperature_c):
            self.ambient_c = float(frame.temperature_c)
            self.seen["ambient"] = frame.time_s
        self._advance_time(frame.time_s)

    def _advance_time(self, t) -> None:
        if t > self.time_s:
            self.time_s = float(t)

    # read-only numpy copies of the per-frame state (the estimator keeps it in lists: a frame's
    # update is a few float stores, and readers that want arrays are rare)
    pack_time = _ArrayCopy("_pack_time")
    pack_current = _ArrayCopy("_pack_current", "(packs,) the latest cleaned current of each pack, A (NaN before any).")
    pack_current_time = _ArrayCopy("_pack_current_time")
    motor_time = _ArrayCopy("_motor_time")
    motor_current = _ArrayCopy("_motor_current")
    motor_current_time = _ArrayCopy("_motor_current_time")
    motor_rpm = _ArrayCopy("_motor_rpm")
    current_read_time = _ArrayCopy("_current_read_time", "(packs,) message time of each pack's latest current "
                                   "read (its own, a string-mate's or its motor's; not a held one).")
    charge_c = _ArrayCopy("_charge_c", "(packs,) charge drawn from each pack since its filter started "
                                       "(cleaned current × dt), C.")

    def latest_pack_current(self, b: int) -> float:
        """Pack ``b``'s latest cleaned current, A, as a float (a per-frame read of the diagnoser)."""
        return self._pack_current[b]

    def motor_readings(self) -> tuple[list[float], list[float], list[float]]:
        """(message time of each motor's latest current, that current, its latest rpm): the
        estimator's own lists, for per-frame readers — read them, never change them."""
        return self._motor_current_time, self._motor_current, self._motor_rpm

    def _reference_current(self, b: int, t: float, own: float = math.nan) -> float:
        """What the rest of pack b's series string says its current is (NaN if nobody recent).

        With two or more references the pack's ``own`` reading votes too: the median of three
        survives a spike in any one of them, where the references' own median (the mean of two)
        let one spiked reference replace a good reading."""
        within = self._within_s
        reading, reading_time = self._reading, self._reading_time
        refs = []
        for mate in self._mates[b]:
            # the mate's own reading, not what it was cleaned to: when the whole string's current
            # steps (a throttle chop), a mate cleaned to its pre-step reference would hold every
            # pack of the string at the old current, frame after frame
            if t - reading_time[mate] <= within:
                r = reading[mate]
                if math.isfinite(r):
                    refs.append(r)
        # a motor's current is its pack's only when the pack feeds that motor alone
        q = self._own_motor[b]
        if q is not None and t - self._motor_current_time[q] <= within:
            r = self._motor_current[q]
            if math.isfinite(r):
                refs.append(r)
        if len(refs) < self._min_references:
            return math.nan
        if len(refs) == 1:
            return refs[0]
        if math.isfinite(own):
            refs.append(own)
        return _median(refs)

    def _pack(self, f: PackFrame) -> int:
        """One BATTERY_STATUS frame: the per-frame path of a replay (issue 18), so locals instead of
        repeated attribute look-ups and the config's floats read once.
        Returns the pack's index, -1 for an unknown pack (the diagnoser's per-frame work needs it)."""
        b = self._pack_index.get(f.pack)
        if b is None:
            self._skip("unknown_pack", f"pack frame for unknown pack {f.pack!r} skipped")
            self._advance_time(f.time_s)
            return -1
        t = float(f.time_s)
        last = self._pack_time[b]
        if not t >= last:
            self._skip("out_of_order", f"pack {f.pack}: frame at {t} s older than the last ({last} s) skipped")
            self._advance_time(f.time_s)
            return b
        keys = self._pack_keys[b]
        seen = self.seen
        cur = f.current_a
        if type(cur) is not float:  # None, or a number of another type: ``_num`` (a plain float is itself)
            cur = _num(cur)
        measured = math.isfinite(cur)
        ref = self._reference_current(b, t, cur)
        if measured:
            seen[keys[0]] = t
            self._reading[b] = cur
            self._reading_time[b] = t
            if math.isfinite(ref) and abs(cur - ref) > max(self._spike_a, 0.5 * abs(ref)):
                self.counters["current_spikes"] += 1
                cur = ref
        else:
            cur = ref if math.isfinite(ref) else self._pack_current[b]
            self.counters["current_held"] += 1
        cur_finite = math.isfinite(cur)
        if measured or math.isfinite(ref):
            self._current_read_time[b] = t
        if measured or cur_finite:
            self._pack_current[b] = cur
            self._pack_current_time[b] = t
        v, temp = f.voltage_v, f.temperature_c
        if type(v) is not float:
            v = _num(v)
        if type(temp) is not float:
            temp = _num(temp)
        if math.isfinite(v):
            seen[keys[1]] = t
        if math.isfinite(temp):
            seen[keys[2]] = t
        packs = self.packs
        initialised = packs.initialised[b]
        ext_row = self._ext_row_of[b]
        cal = self.calib[b]
        v_paper = v if cal is None else math.nan
        if initialised and t - last > self._restart_after_s:
            self._restart("pack", f.pack, t - last)
            packs.initialised[b] = initialised = False
            if cal is not None:
                cal.initialised = False
            watch = self.fitted_watch[b]
            if watch is not None:
                watch.calibrator.initialised = False
            if ext_row >= 0:
                self.ext.initialised[ext_row] = False
            self._i_sum[b], self._i_n[b] = 0.0, 0
        if not initialised:
            if math.isfinite(v):  # else nothing to start from yet
                packs.initialise(np.array([b]), np.array([v]), np.array([cur]), np.array([temp]), self.ambient_c)
                self._pack_cov_ceiling[b] = np.diag(packs.cov[b]) * (RELOCK_CEILING * packs.config.relock_inflation)
                if ext_row >= 0:
                    self.ext.initialise(np.array([ext_row]), np.array([v]), np.array([cur]), np.array([temp]),
                                        self.ambient_c)
                    self._ext_cov_ceiling[ext_row] = (np.diag(self.ext.cov[ext_row])
                                                      * (RELOCK_CEILING * self.ext.config.relock_inflation))
                if cal is not None:
                    if not cal.initialised:
                        # a fitted pack's calibrator that took over starts again through its watch,
                        # which keeps where the chemistry's curves would start from
                        watch = self.fitted_watch[b]
                        (watch if watch is not None and cal is watch.calibrator else cal).initialise(
                            t, v, cur, temp if math.isfinite(temp) else float(packs.mean[b, kernel.S_T]))
                        self._calibrator_temp[b] = (t, temp)
                    self._sync_paper(b)
                elif self.fitted_watch[b] is not None and not self.fitted_watch[b].calibrator.initialised:
                    self.fitted_watch[b].initialise(
                        t, v, cur, temp if math.isfinite(temp) else float(packs.mean[b, kernel.S_T]))
                    self._calibrator_temp[b] = (t, temp)
                self._pack_time[b] = t
            if t > self.time_s:
                self.time_s = t
            return b
        dt = t - last
        i_sum, i_n = self._i_sum, self._i_n
        if cur_finite:
            i_sum[b] += cur
            i_n[b] += 1
        if dt > 0 and i_n[b] > 0:
            cur = i_sum[b] / i_n[b]
            i_sum[b], i_n[b] = 0.0, 0
        if dt > self._long_gap_s:
            self.counters["long_gaps"] += 1
            log.info("pack %s: %.1f s without telemetry; integrating through at %.1f A", f.pack, dt, cur)
        i_used = cur if math.isfinite(cur) else 0.0
        ambient = self.ambient_c
        # the compiled steps say when a consistency state flipped (nearly never): only then is it read
        try:
            flipped = packs.step_one(b, dt, i_used, ambient, v_paper, temp)
            if ext_row >= 0:
                flipped = self.ext.step_one(ext_row, dt, i_used, ambient, v, temp)
            broken = None
            if packs.relocks[b] != self._pack_relocks_seen[b] or (
                    ext_row >= 0 and self.ext.relocks[ext_row] != self._ext_relocks_seen[ext_row]):
                broken = self._relock_left_sane(b, ext_row, t - seen.get(keys[2], -math.inf) <= self.config.stale_after_s)
        except np.linalg.LinAlgError as err:
            broken = str(err)
        if broken is not None:
            # the filter's state cannot be trusted (re-locks compounded, or its covariance broke): it
            # restarts from the next reading, as after a long silence
            self._filter_failed("pack", f.pack, t, broken)
            # a self-calibrated pack's calibrator keeps its state (and its charge count): the paper
            # filter that broke only carries the calibrator's SoC for the kernel's users
            packs.initialised[b] = False
            if ext_row >= 0:
                self.ext.initialised[ext_row] = False
            self._i_sum[b], self._i_n[b] = 0.0, 0
            self._pack_time[b] = t
            if t > self.time_s:
                self.time_s = t
            return b
        self._charge_c[b] += i_used * dt
        self._pack_time[b] = t
        if cal is not None:
            temp_used = self._calibrator_temperature(b, t, temp)
            watch = self.fitted_watch[b]
            if watch is not None and cal is watch.calibrator:  # a fitted set overturned: its curve judged too
                watch.step(t, dt, i_used, v, temp_used)
                self._watch_set_curve(b, t, i_used, v, temp_used)
            else:
                cal.step(t, dt, i_used, v, temp_used)
            self._sync_paper(b)
            flipped = self._calibrated_mismatch(b) != self._mismatch_active[b]
        elif self.fitted_watch[b] is not None:
            self._watch_fitted(b, t, dt, i_used, v, temp)
        if flipped or self._mismatch_active[b]:
            self._mismatch_changed(b, t)
        if t > self.time_s:
            self.time_s = t
        return b

    def _calibrator_temperature(self, b: int, t: float, temp: float, count: bool = True) -> float:
        """The pack temperature the calibrator steps with: the reading, unless it jumped further than
        the pack can heat or cool since the last reading believed (then that one, counted unless
        ``count`` is off: a fitted pack's watch leaves the estimator's counters as the set's filter
        has them); the thermal model's temperature when nothing is read."""
        if not math.isfinite(temp):
            return float(self.packs.mean[b, kernel.S_T])
        last_t, last = self._calibrator_temp[b]
        if math.isfinite(last) and abs(temp - last) > (CALIBRATOR_TEMP_SLEW_K_PER_S * (t - last_t)
                                                       + CALIBRATOR_TEMP_SLACK_K):
            if count:
                self.counters["temperature_jumps_held"] += 1
            return last
        self._calibrator_temp[b] = (t, temp)
        return temp

    def _watch_fitted(self, b: int, t: float, dt: float, current: float, v: float, temp: float) -> None:
        """Step fitted pack ``b``'s watching calibrator; when the flight contradicts its set, the
        calibrator becomes the pack's filter from this frame on (``estimation.fitted_prior``)."""
        watch = self.fitted_watch[b]
        cal = watch.calibrator
        if not cal.initialised:
            return
        temp_used = self._calibrator_temperature(b, t, temp, count=False)
        watch.step(t, dt, current, v, temp_used)
        window = self.packs.consistency
        why = watch.contradiction(t, *self.paper_soc(b), window.statistic_at(b, 0) / window.raise_at)
        if why is None:
            return
        watch.contradicted_at_s, watch.reason = t, why
        self.calib[b] = cal
        self.counters["fitted_set_contradicted"] += 1
        log.warning("pack %s at t=%.1f s: %s; its SoC is the self-calibrating filter's from now on",
                    self.pack_names[b], t, why)
        self._sync_paper(b)

    def _watch_set_curve(self, b: int, t: float, current: float, v: float, temp: float) -> None:
        """A fitted pack whose set the flight contradicted, its calibrator (on the set's curve) now
        its filter: when the curve itself is contradicted, the pack's filter becomes its chemistry's
        from this frame on (``FittedPackWatch.curve_contradiction``, ``chemistry_filter``)."""
        watch = self.fitted_watch[b]
        why = watch.curve_contradiction(t)
        if why is None:
            return
        watch.curve_contradicted_at_s, watch.curve_reason = t, why
        self.calib[b] = watch.chemistry_filter(t, current, v, temp)
        self.counters["fitted_curve_contradicted"] += 1
        log.warning("pack %s at t=%.1f s: %s", self.pack_names[b], t, why)

    def paper_soc(self, b: int) -> tuple[float, float]:
        """Pack ``b``'s SoC and σ as its paper filter reports them (``estimate`` of a fitted pack):
        the σ with the set's capacity's (``capacity_rel_sigma``)."""
        # scalars, not ``kernel.state_of_charge`` and ``_with_capacity_sd``: this runs on every pack
        # frame of a fitted pack (its watch), where NumPy's calls on one element cost more than the sums
        p = self.packs.params[b]
        c_max = float(p[kernel.I_CMAX])
        soc = 1.0 - (float(p[kernel.I_QMAX]) - float(self.packs.mean[b, kernel.S_QB])) / c_max
        sd = math.sqrt(max(float(self.packs.cov[b, kernel.S_QB, kernel.S_QB]), 0.0)) / c_max
        return soc, math.hypot(sd, self.config.capacity_rel_sigma * min(max(1.0 - soc, 0.0), 1.0))

    def _with_capacity_sd(self, soc, soc_sd):
        """A paper filter's SoC σ as reported: its own, with the set's capacity's uncertainty, which
        the filter cannot see (``capacity_rel_sigma`` of the charge drawn)."""
        return np.hypot(soc_sd, self.config.capacity_rel_sigma * np.clip(1.0 - soc, 0.0, 1.0))

    def _sync_paper(self, b: int) -> None:
        """The paper filter of a self-calibrated pack carries its SoC (mean and variance of q_b) for
        the users of the kernel's layout: predictions fly the kernel from it. The filter's own σ
        (``filter_soc_sd``), not the reported one: the chemistry's curve family widens only what is
        shown, as the count-down and the route risk draw without it; in the paper filter's
        covariance it would move that filter's other states (its temperature) through their
        cross-covariance."""
        cal = self.calib[b]
        soc, sd = cal.soc, cal.filter_soc_sd
        if not math.isfinite(soc):
            return
        p, mean, cov = self.packs.params[b], self.packs.mean, self.packs.cov
        mean[b, kernel.S_QB] = p[kernel.I_QMAX] - (1.0 - soc) * p[kernel.I_CMAX]
        cov[b, kernel.S_QB, :] = 0.0
        cov[b, :, kernel.S_QB] = 0.0
        cov[b, kernel.S_QB, kernel.S_QB] = (sd * p[kernel.I_CMAX]) ** 2

    def _mismatch_changed(self, b: int, t: float) -> None:
        cal = self.calib[b]
        if cal is not None:
            now = self._calibrated_mismatch(b)
        else:
            window, row = self._window_of(b)
            now = bool(window.active[row].any())
        if now == self._mismatch_active[b]:
            return
        self._mismatch_active[b] = now
        self._mismatch_since[b] = t
        self.counters["model_mismatch_raised" if now else "model_mismatch_cleared"] += 1
        ev = self.model_check(b)
        if now:
            log.warning("pack %s does not match its model at t=%.1f s: %s", self.pack_names[b], t, ev["reason"])
        else:
            log.info("pack %s matches its model again at t=%.1f s", self.pack_names[b], t)

    def _motor(self, f: MotorFrame) -> int:
        """One ESC frame (the per-frame path of a replay, like ``_pack``). Returns the motor's
        index, -1 for an unknown motor (the diagnoser's per-frame work needs it)."""
        q = self._motor_index.get(f.motor)
        if q is None:
            self._skip("unknown_motor", f"motor frame for unknown motor {f.motor!r} skipped")
            self._advance_time(f.time_s)
            return -1
        t = float(f.time_s)
        last = self._motor_time[q]
        if not t >= last:
            self._skip("out_of_order", f"motor {f.motor}: frame at {t} s older than the last ({last} s) skipped")
            self._advance_time(f.time_s)
            return q
        keys = self._motor_keys[q]
        seen = self.seen
        cur = f.current_a
        if type(cur) is not float:  # None, or a number of another type: ``_num`` (a plain float is itself)
            cur = _num(cur)
        if math.isfinite(cur):
            seen[keys[0]] = t
            self._motor_current[q] = cur
            self._motor_current_time[q] = t
        else:
            # the string's pack currents are the motor's current
            packs = [b for b in self._packs_of_motor[q] if len(self._motors_of_pack[b]) == 1]
            fresh = [self._pack_current[b] for b in packs
                     if t - self._pack_current_time[b] <= self._within_s]
            cur = float(np.nanmedian(fresh)) if fresh and np.isfinite(fresh).any() else self._motor_current[q]
        rpm = f.rpm
        if type(rpm) is not float:
            rpm = _num(rpm)
        if math.isfinite(rpm):
            self._motor_rpm[q] = rpm
            seen[keys[1]] = t
        temp = f.temperature_c
        if type(temp) is not float:
            temp = _num(temp)
        if math.isfinite(temp):
            seen[keys[2]] = t
        motors = self.motors
        initialised = motors.initialised[q]
        if initialised and t - last > self._restart_after_s:
            self._restart("motor", f.motor, t - last)
            motors.initialised[q] = initialised = False
        if not initialised:
            readings = self._motor_reports.get(f.motor)
            if not math.isfinite(temp) and readings is not None and not readings.temperature:
                # no sensor: the thermal model from ambient, with its wider uncertainty
                motors.initialise(np.array([q]), np.array([self.ambient_c]), self.config.motor.initial_sigma_c)
                self._motor_time[q] = t
            elif math.isfinite(temp):
                motors.initialise(np.array([q]), np.array([temp]), self.config.motor.temperature_sigma_c)
                self._motor_time[q] = t
        else:
            try:
                motors.step_one(q, t - last, cur if math.isfinite(cur) else 0.0, self.ambient_c, temp)
            except np.linalg.LinAlgError as err:  # as for a pack (``_pack``)
                self._filter_failed("motor", f.motor, t, str(err))
                motors.initialised[q] = False
            self._motor_time[q] = t
        if t > self.time_s:
            self.time_s = t
        return q

    def adopt_pack_scales(self, pack: str, resistance_scale: float, capacity_scale: float) -> None:
        """Run pack ``pack`` on its parameter set's values with R_s, R_cp0 scaled by
        ``resistance_scale`` and C_b, q_max, C_max by ``capacity_scale`` — the diagnoser's estimate
        of its degradation — so SoC and predictions stop inheriting the mismatch. SoC is then a
        fraction of the *degraded* capacity."""
        b = self.pack_names.index(pack)
        row = self._base_pack_matrix[b].copy()
        row[[kernel.I_RS, kernel.I_RCP0]] *= float(resistance_scale)
        row[[kernel.I_CB, kernel.I_QMAX, kernel.I_CMAX]] *= float(capacity_scale)
        self.packs.set_params(b, row)
        if b in self.ext_row:
            r = self.ext_row[b]
            ext = self._base_ext_matrix[r].copy()
            ext[[kernel.E_R0, kernel.E_R1, kernel.E_R2]] *= float(resistance_scale)
            ext[kernel.E_CMAX] *= float(capacity_scale)
            self.ext.set_params(r, ext)
        self.counters["parameter_updates"] += 1

    def capacity_c(self) -> np.ndarray:
        """(packs,) usable capacity (C) each pack is run on: its extended C_max for a pack of the
        extended variant, else the paper C_max (after any adopted degradation)."""
        cap = self.packs.params[:, kernel.I_CMAX].copy()
        for b, r in self.ext_row.items():
            cap[b] = self.ext.params[r, kernel.E_CMAX]
        return cap

    # ---- model consistency -------------------------------------------------------------------------
    def _window_of(self, b: int):
        """Pack ``b``'s consistency window and its row there: its own variant's filter's."""
        if b in self.ext_row:
            return self.ext.consistency, self.ext_row[b]
        return self.packs.consistency, b

    def model_check(self, b: int) -> dict:
        """Pack ``b``'s model-consistency test with its evidence, JSON-ready: ``active`` (the pack
        does not behave like its model), the window (updates), per channel the statistic (mean
        squared normalised innovation, clipped; ≈ 0.3-0.5 on a pack that matches) against its bound,
        the mean residual (measured − predicted, mV and K), the message time of the last raise or
        clear, the factor applied to the prediction's state spread, and what to do about it."""
        if self.calib[b] is not None:
            return self._calibration_check(b)
        w, row = self._window_of(b)
        stat, res = w.statistic()[row], w.mean_residual()[row]
        name = self.pack_names[b]
        active = self._mismatch_active[b]

        def num(x, nd):
            return None if not math.isfinite(float(x)) else round(float(x), nd)

        out = {"active": active, "model": "extended" if b in self.ext_row else "paper",
               "window_updates": w.size, "updates": int(w.count[row, 0]),
               "statistic": num(stat[0], 3), "bound": round(w.raise_at, 3), "clear_below": round(w.clear_at, 3),
               "false_alarm_per_window": w.false_alarm,
               "voltage_residual_mv": num(1000.0 * res[0], 1),
               "temperature_statistic": num(stat[1], 3), "temperature_residual_k": num(res[1], 2),
               "channels": [c for c, on in zip(CHANNELS, w.active[row]) if on],
               "since_s": num(self._mismatch_since[b], 3),
               "prediction_inflation": round(float(self.prediction_inflation()[b]), 3)}
        if not self.packs.initialised[b] or not math.isfinite(stat[0]):
            out["state"] = "unknown"
            out["reason"] = (f"not judged yet: {int(w.count[row, 0])} of {w.size} voltage updates since the pack's "
                             f"filter started")
        elif active:
            out["state"] = "mismatch"
            parts = [f"{c} innovations {stat[k]:.2f}× their expected variance (bound {w.raise_at:.2f}, "
                     f"mean residual {1000 * res[k]:+.0f} mV)" if k == 0 else
                     f"{c} innovations {stat[k]:.2f}× their expected variance (bound {w.raise_at:.2f}, "
                     f"mean residual {res[k]:+.2f} K)" for k, c in enumerate(CHANNELS) if w.active[row, k]]
            out["reason"] = (f"pack {name} does not behave like its model over the last {w.size} updates: "
                             + "; ".join(parts))
            out["suggestion"] = refit_suggestion(name)
        else:
            out["state"] = "matches"
        return out

    def _calibrated_mismatch(self, b: int) -> bool:
        """Whether self-calibrated pack ``b`` fails its model-consistency test: its calibrator does
        not trust the voltage, or it is a fitted pack whose set the flight contradicted (the set no
        longer describes it: the advisory says so, and to refit it)."""
        watch = self.fitted_watch[b]
        return not self.calib[b].voltage_trusted or (watch is not None and watch.reason is not None)

    def _calibration_check(self, b: int) -> dict:
        """``model_check`` of a self-calibrated pack: whether its voltage is trusted, and why not."""
        cal = self.calib[b]
        rep = cal.report()
        active = self._mismatch_active[b]
        out = {"active": active, "model": f"chemistry:{cal.chem.name}", "statistic": None, "bound": None,
               "channels": ["voltage"] if active else [],
               "since_s": None if not math.isfinite(self._mismatch_since[b]) else round(float(self._mismatch_since[b]), 3),
               "prediction_inflation": 1.0, "calibration": rep}
        watch = self.fitted_watch[b]
        if watch is not None:  # a fitted pack whose set the flight contradicted
            out["fitted_set"] = {"contradicted_at_s": round(float(watch.contradicted_at_s), 3), "reason": watch.reason}
            if watch.curve_reason is not None:  # and then its curve: the chemistry's filter is the pack's
                out["fitted_set"].update(curve_contradicted_at_s=round(float(watch.curve_contradicted_at_s), 3),
                                         curve_reason=watch.curve_reason)
        if not cal.initialised:
            out["state"], out["reason"] = "unknown", "not judged yet: no voltage reading"
        elif active:
            out["state"] = "mismatch"
            why = [f"{watch.reason}; its SoC is the self-calibrating filter's"] if watch is not None else []
            if not cal.voltage_trusted:
                why.append(f"{cal.why_not_voltage}; its SoC follows the charge drawn (σ grows with the capacity's "
                           f"uncertainty)")
            out["reason"] = f"pack {self.pack_names[b]}: " + "; ".join(why)
            out["suggestion"] = refit_suggestion(self.pack_names[b])
        else:
            out["state"] = "matches"
        return out

    def evidence(self) -> dict[str, list[str]]:
        """What each self-calibrated pack's SoC rests on now (``PackCalibrator.evidence``)."""
        return {n: cal.evidence() for n, cal in zip(self.pack_names, self.calib) if cal is not None}

    @property
    def model_mismatch_active(self) -> np.ndarray:
        """(packs,) bool: the pack fails its model-consistency test now (a copy)."""
        return np.array(self._mismatch_active, dtype=bool)

    def mismatch_active(self, b: int) -> bool:
        """Pack ``b`` fails its model-consistency test now (a per-frame read of the diagnoser)."""
        return self._mismatch_active[b]

    def model_mismatch(self) -> dict[str, dict]:
        """``model_check`` of every pack, by name."""
        return {n: self.model_check(b) for b, n in enumerate(self.pack_names)}

    def prediction_inflation(self) -> np.ndarray:
        """(packs,) factor on the state covariance a prediction starts from: 1 while a pack matches
        its model; while it does not, its channel statistic (≥ 1) — the innovations are that many
        times more variable than the filter believes, so its state is that much less certain
        (covariance matching). ``prediction.predict_from_estimator`` applies it."""
        worst = np.ones(len(self.pack_names))
        for b in (b for b, on in enumerate(self._mismatch_active) if on and self.calib[b] is None):
            w, row = self._window_of(b)
            worst[b] = np.nanmax(np.where(w.active[row], w.statistic()[row], 1.0))
        return np.maximum(worst, 1.0)

    def _restart(self, kind: str, name: str, gap_s: float) -> None:
        self.counters["restarts"] += 1
        log.warning("%s %s: %.0f s without telemetry; its filter restarts from the next reading", kind, name, gap_s)

    def _relock_left_sane(self, b: int, ext_row: int, temperature_measured: bool) -> str | None:
        """After a re-lock of pack ``b``'s filter (and its extended row): None if its state is finite
        and no variance is over its ceiling, else why not. The temperature's variance is judged only
        while the pack's temperature is measured: unmeasured, nothing ever shrinks it, and each
        voltage re-lock grows it (harmlessly: the model's temperature is all there is)."""
        self._pack_relocks_seen[b] = int(self.packs.relocks[b])
        rows = [(self.packs, b, self._pack_cov_ceiling[b])]
        if ext_row >= 0:
            self._ext_relocks_seen[ext_row] = int(self.ext.relocks[ext_row])
            rows.append((self.ext, ext_row, self._ext_cov_ceiling[ext_row]))
        for bank, row, ceiling in rows:
            mean, cov = bank.mean[row], bank.cov[row]
            if not (np.isfinite(mean).all() and np.isfinite(cov).all()):
                return "its state is not finite after a re-lock"
            over = np.diag(cov) > ceiling
            if not temperature_measured:
                over[kernel.S_T] = False  # the same column in both variants (S_T == X_T)
            if bank is self.packs and self.calib[b] is not None:
                # a self-calibrated pack's charge state is its calibrator's, copied in (``_sync_paper``)
                # with the calibrator's own bounded spread: not something this filter's re-locks grew
                over[kernel.S_QB] = False
            if over.any():
                return (f"re-locks compounded its variances past {RELOCK_CEILING:g}x one re-lock's inflation "
                        f"of their initial values (states {np.flatnonzero(over).tolist()}): a sensor flapping "
                        f"between two readings?")
        return None

    def _filter_failed(self, kind: str, name: str, t: float, err: Exception | str) -> None:
        """Count a filter whose step failed; warn on each component's first failure (a flapping
        sensor can break it again every few minutes: the counter tells the rest)."""
        self.counters["filter_failures"] += 1
        key = f"{kind}:{name}"
        if key not in self._failed_filters:
            self._failed_filters.add(key)
            log.warning("%s %s: its filter failed at t=%.1f s (%s); it restarts from the next reading "
                        "(further failures counted in Estimate.counters['filter_failures'])", kind, name, t, err)

    def _skip(self, kind: str, message: str) -> None:
        """Count a skipped frame; warn on the first of each kind (the counters tell the rest)."""
        if not self.counters[kind]:
            log.warning("%s (further ones counted in Estimate.counters[%r])", message, kind)
        self.counters[kind] += 1

    # ---- read-outs --------------------------------------------------------------------------------
    def missing(self, now: float | None = None) -> tuple[str, ...]:
        now = self.time_s if now is None else now
        channels = [f"{p}.{c}" for b, p in enumerate(self.pack_names) for c in ("voltage", "current", "temperature")
                    if c != "temperature" or self._pack_reports_temp[b]]
        channels += [f"{m}.{c}" for m in self.motor_names for c in ("current", "rpm", "temperature")
                     if m not in self._motor_reports or getattr(self._motor_reports[m], c)]
        return tuple(c for c in channels if now - self.seen.get(c, -math.inf) > self.config.stale_after_s)

    def estimate(self, *, details: bool = True) -> Estimate:
        """The estimate now. ``details=False`` leaves out the per-pack model checks and the list of
        missing channels (``model_mismatch`` and ``missing`` empty): the numbers alone, for a reader
        that needs only the state (the prognosis, every check), at a fraction of the cost."""
        soc, soc_sd = self.packs.soc()
        tp, tp_sd = self.packs.temperature()
        v, _ = self.packs.voltage()
        if self.ext is not None:
            rows = np.array(sorted(self.ext_row))
            e_soc, e_sd = self.ext.soc()
            e_t, e_tsd = self.ext.temperature()
            order = [self.ext_row[b] for b in rows]
            soc[rows], soc_sd[rows], tp[rows], tp_sd[rows] = e_soc[order], e_sd[order], e_t[order], e_tsd[order]
            v[rows] = self.ext.voltage(np.nan_to_num(self.pack_current[rows]))[order]
        soc_sd = self._with_capacity_sd(soc, soc_sd)
        for b, cal in enumerate(self.calib):
            if cal is not None:  # its σ carries the capacity's uncertainty itself
                soc[b], soc_sd[b] = cal.soc, cal.soc_sd
                watch = self.fitted_watch[b]
                if watch is not None and cal is watch.calibrator:  # and a fitted set's curve in question
                    soc_sd[b] = math.hypot(soc_sd[b], watch.curve_doubt())
        tm, tm_sd = self.motors.temperature()
        modelled = tuple(n for b, n in enumerate(self.pack_names)
                         if not self._pack_reports_temp[b] or f"{n}.temperature" not in self.seen)
        self._modelled_spread(tp, tp_sd, [b for b, n in enumerate(self.pack_names) if n in modelled])
        self._modelled_spread(tm, tm_sd, [q for q, n in enumerate(self.motor_names)
                                          if f"{n}.temperature" not in self.seen])
        none = ~self.packs.initialised
        for a in (soc, soc_sd, tp, tp_sd, v):
            a[none] = np.nan
        mismatch = self._range_guard(soc, soc_sd, tp, tp_sd, v)
        counters = dict(self.counters)
        counters["voltage_gated"] = int(self.packs.rejected_total[:, 0].sum())
        counters["pack_temperature_gated"] = int(self.packs.rejected_total[:, 1].sum())
        counters["motor_temperature_gated"] = int(self.motors.rejected_total.sum())
        counters["relocks"] = int(self.packs.relocks.sum() + self.motors.relocks.sum())
        return Estimate(self.time_s, soc, soc_sd, tp, tp_sd, v, tm, tm_sd, self.ambient_c,
                        self.missing() if details else (), counters,
                        pack_names=self.pack_names, motor_names=self.motor_names, modelled_temperature=modelled,
                        mismatch=mismatch, motor_current_a=self.motor_current, motor_rpm=self.motor_rpm,
                        model_mismatch=self.model_mismatch() if details else {},
                        evidence=self.evidence() if details else {})

    def _modelled_spread(self, temp: np.ndarray, sd: np.ndarray, rows: list[int]) -> None:
        """A temperature no sensor measures (``rows``): its σ is the thermal model's, not the
        filter's (which only knows the process noise): the rise over the air ×
        ``MODELLED_RISE_REL_SIGMA``, and the air's own doubt (a default, or a reading)."""
        if not rows:
            return
        heard = self.time_s - self.seen.get("ambient", -math.inf) <= AMBIENT_FRESH_S
        air = HEARD_AMBIENT_SIGMA_C if heard else UNKNOWN_AMBIENT_SIGMA_C
        for k in rows:
            if math.isfinite(temp[k]):
                rise = abs(float(temp[k]) - self.ambient_c)
                sd[k] = math.sqrt(float(sd[k]) ** 2 + (MODELLED_RISE_REL_SIGMA * rise) ** 2 + air ** 2)

    def _range_guard(self, soc, soc_sd, tp, tp_sd, v) -> tuple[str, ...]:
        """Clip a SoC that is in [0, 1] within its noise; withhold (NaN) and report a pack whose
        SoC or temperature the model cannot hold — its parameters do not describe the real pack."""
        out = []
        lo, hi = SOC_RANGE
        for b, name in enumerate(self.pack_names):
            if not np.isfinite(soc[b]):
                continue
            bad = []
            if (soc[b] + RANGE_SIGMAS * soc_sd[b] < lo - SOC_SLACK
                    or soc[b] - RANGE_SIGMAS * soc_sd[b] > hi + SOC_SLACK):
                bad.append(f"SoC {soc[b]:.3g} ± {soc_sd[b]:.2g} outside [0, 1]")
            if not TEMPERATURE_RANGE_C[0] <= tp[b] <= TEMPERATURE_RANGE_C[1]:
                bad.append(f"temperature {tp[b]:.3g} °C outside ±100 °C")
            if bad:
                out.append(f"pack {name}: {', '.join(bad)}: the model does not fit this pack "
                           f"(check its cells, capacity and parameter set)")
                # a self-calibrated pack's SoC rests on its own evidence (at worst the charge count):
                # a temperature the thermal model cannot hold withholds the temperature alone
                withheld = (tp, tp_sd) if self.calib[b] is not None else (soc, soc_sd, tp, tp_sd, v)
                for a in withheld:
                    a[b] = np.nan
                self.counters["model_mismatch"] += 1
            if np.isfinite(soc[b]):
                soc[b] = min(max(soc[b], lo), hi)
        return tuple(out)

    def ready(self) -> bool:
        return bool(self.packs.initialised.all() and self._motors_ready())

    def _motors_ready(self) -> bool:
        # a motor the description says reports nothing is carried by the model alone
        silent = np.array([m in self._motor_reports and not any(
            (self._motor_reports[m].current, self._motor_reports[m].rpm, self._motor_reports[m].temperature))
            for m in self.motor_names])
        return bool((self.motors.initialised | silent).all())

    def readiness(self) -> dict[str, str]:
        """What the estimator can support now, and why not (said out loud, for /status and logs):
        ``{"state": ..., "prediction": ..., "motor_telemetry": ...}``, "ready" or the reason."""
        waiting = [f"pack {n} voltage" for b, n in enumerate(self.pack_names) if not self.packs.initialised[b]]
        waiting += [f"motor {n} temperature" for q, n in enumerate(self.motor_names)
                    if not self.motors.initialised[q]
                    and not (n in self._motor_reports and not self._motor_reports[n].temperature)]
        state = "ready" if not waiting else "waiting for " + ", ".join(waiting)
        mismatch = self.estimate(details=False).mismatch if not waiting else ()
        # a self-calibrated pack's mismatch is an advisory: its SoC (at worst the charge count) still
        # supports a prediction and a plan
        calibrated = tuple(f"pack {n}:" for n, cal in zip(self.pack_names, self.calib) if cal is not None)
        mismatch = tuple(m for m in mismatch if not m.startswith(calibrated)) if calibrated else mismatch
        prediction = state if not mismatch else "model mismatch: " + "; ".join(mismatch)
        # the filters integrate a held current through a silence, but a prediction from it would be
        # a guess: say whose current is not being read
        held = [f"pack {n} current not read for {self.time_s - self._current_read_time[b]:.0f} s (held)"
                for b, n in enumerate(self.pack_names)
                if self.packs.initialised[b] and self.time_s - self._current_read_time[b] > self.config.stale_after_s]
        if held and prediction == "ready":
            prediction = "; ".join(held)
        heard = [n for n in self.motor_names if f"{n}.current" in self.seen or f"{n}.rpm" in self.seen]
        if not heard:
            motors = "no ESC telemetry"
        elif len(heard) < len(self.motor_names):
            motors = "ESC telemetry from " + ", ".join(heard) + " only"
        else:
            motors = "ready"
        return {"state": state, "prediction": prediction, "motor_telemetry": motors}

    def powertrain_state(self) -> PowertrainState:
        """The mean state in the kernel's layout (what the planner simulates from)."""
        tm = self.motors.mean[:, 0]
        return PowertrainState(pack_state=self.packs.mean.copy(),
                               motor_temp_c=np.where(np.isfinite(tm), tm, self.ambient_c))


def refit_suggestion(pack: str) -> str:
    """What the operator can do about a pack that no longer matches its model."""
    which = f"--pack {pack} " if pack in PACK_NAMES else ""
    logs = "LOG" if pack in PACK_NAMES else "TABLE"
    return (f"fit this pack on recent logs: gcs-pdm fit battery {which}--train {logs} [{logs} ...] --val {logs} "
            f"--test {logs} --out DIR (docs/fitting.md), then activate the new parameter set")


def _median(values: list[float]) -> float:
    """np.median of a few finite floats, without the array round trip (a per-frame call)."""
    v = sorted(values)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def ignore_frame(frame) -> None:
    """The handler of a frame the estimator does not use."""


def _num(x) -> float:
    if x is None:
        return math.nan
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan
