"""A pack whose chemistry name leaves its curve open: one filter per curve, weighed by the voltage.

``models.curve_hypotheses`` lists the published curves a named chemistry may rest on (a "LiPo" may
be a hobby cell charged to 4.20 V or an LCO pouch charged to 4.10 V). ``CurveBank`` runs one
``calibration.PackCalibrator`` per curve on the same frames and weighs them by how well each
explains the voltage (the sum of its innovations' log-likelihoods, tempered: at 1 Hz the
innovations of a first-order circuit on a real cell are far from independent, and counted as
independent one minute of a circuit's miss would decide between curves that differ by 0.1 V).
A hypothesis is ruled out outright when the pack rests above what a cell on that curve can show
(a 4.10 V-charged cell never rests at 4.2 V).

What it says: the leading hypothesis's SoC, with a σ that covers the others in proportion to their
weight (Σ w (σ² + (SoC − the lead's)²)), so while they disagree the σ says so; everything else
(evidence, the voltage's trust, the learned parameters) is the leading hypothesis's, and the
report lists every hypothesis with its weight and SoC.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from gcs_pdm.estimation.calibration import PackCalibrator, PackPrior
from gcs_pdm.models.curve_hypotheses import CurveHypothesis, curve_hypotheses

#: each innovation's log-likelihood counts this much in the weights (about one independent sample
#: per 5 s). Measured (docs/notes/2026-11-27-curve-hypotheses.md): at 1, LiPos of 2-3x their
#: resistance missed (chemistry-curve presets 22 -> 19 of 24 met); at 1/30 a simulated 4.10 V cell
#: drained for up to 30 min was hardly recognised (its weight 0.1 -> 0.11-0.23)
LIKELIHOOD_TEMPERING = 0.2
#: no hypothesis falls further than this (natural log) below the leading one: it can come back
#: when the voltage turns (an IMM's mixing, in its simplest form)
LOG_WEIGHT_FLOOR = math.log(1e-4)
#: while the leading hypothesis weighs less than this, the evidence says the curve is open
CURVE_SETTLED_WEIGHT = 0.95


def pack_calibrator(prior: PackPrior, *, sigma_v: float | None = None):
    """The filter for a pack: a ``CurveBank`` when its chemistry leaves the curve open (a chemistry
    table's prior, more than one published curve), else one ``PackCalibrator``."""
    hyps = curve_hypotheses(prior.chemistry, prior.full_cell_v) if prior.curve is None else ()
    if len(hyps) == 1:
        return PackCalibrator(replace(prior, curve=hyps[0].curve), sigma_v=sigma_v)
    if len(hyps) < 2:
        return PackCalibrator(prior, sigma_v=sigma_v)
    return CurveBank(prior, hyps, sigma_v=sigma_v)


class CurveBank:
    """One ``PackCalibrator`` per curve hypothesis, weighed by the voltage (module doc). Offers what
    the estimator reads of a ``PackCalibrator``."""

    def __init__(self, prior: PackPrior, hypotheses: tuple[CurveHypothesis, ...], *, sigma_v: float | None = None):
        self.prior = prior
        self.hypotheses = hypotheses
        self.members = [PackCalibrator(replace(prior, curve=h.curve), sigma_v=sigma_v) for h in hypotheses]
        self.sigma_v = self.members[0].sigma_v
        self.log_weight = [math.log(h.prior_weight) for h in hypotheses]
        self.ruled_out = [False] * len(hypotheses)
        self._scored = [0.0] * len(hypotheses)

    def __getattr__(self, name: str):
        # Anything else a reader takes from a ``PackCalibrator`` (its state and covariance, its
        # priors' resistances, the recent load the count-down holds: the planner's spread, the
        # calibrated pack) is the leading curve's filter's, as the reported SoC is. Only called for
        # names the bank does not have itself; never before ``__init__`` has set the members (copy).
        if name.startswith("__") or "members" not in self.__dict__ or "log_weight" not in self.__dict__:
            raise AttributeError(name)
        return getattr(self.lead, name)

    # ---- what the estimator sets and calls ------------------------------------------------------
    @property
    def initialised(self) -> bool:
        return self.members[0].initialised

    @initialised.setter
    def initialised(self, value: bool) -> None:
        for m in self.members:
            m.initialised = value

    def initialise(self, t: float, voltage: float, current: float, temperature_c: float) -> None:
        """Start (or, after a gap in which the pack may have been swapped, start again) from the
        priors: the weights too."""
        self.log_weight = [math.log(h.prior_weight) for h in self.hypotheses]
        self.ruled_out = [False] * len(self.hypotheses)
        self._scored = [m.log_likelihood for m in self.members]
        for m in self.members:
            m.initialise(t, voltage, current, temperature_c)
        self._weigh(voltage, current)

    def step(self, t: float, dt: float, current: float, voltage: float, temperature_c: float) -> None:
        # a ruled-out curve's filter stops (its weight stays 0 until a restart): a full LiPo costs one
        for m, out in zip(self.members, self.ruled_out):
            if not out:
                m.step(t, dt, current, voltage, temperature_c)
        self._weigh(voltage, current)

    def _weigh(self, voltage: float, current: float) -> None:
        # plain floats: a per-frame call on two or three hypotheses (with numpy arrays the bank's
        # own bookkeeping cost 3x its two filters)
        members, lw = self.members, self.log_weight
        scores = [m.log_likelihood for m in members]
        if all(m.voltage_trusted for m, out in zip(members, self.ruled_out) if not out):
            # scored only while every hypothesis follows the voltage: a filter that stopped (its
            # circuit could not follow a pack of 3x the resistance) scores its priors, not its curve
            for k, (now, before) in enumerate(zip(scores, self._scored)):
                lw[k] += LIKELIHOOD_TEMPERING * (now - before)
        self._scored = scores
        if math.isfinite(voltage) and abs(current) < members[0].rest_current_a:
            # a pack resting above what a cell on a curve can show is not on that curve
            over = [voltage / m.cells > m.chem.max_rest_cell_v for m in members]
            if not all(over):
                for k, above in enumerate(over):
                    self.ruled_out[k] = self.ruled_out[k] or above
        top = max(w for w, out in zip(lw, self.ruled_out) if not out)
        # the floor keeps a hypothesis the voltage has not yet ruled out within reach
        for k, out in enumerate(self.ruled_out):
            lw[k] = -math.inf if out else max(lw[k] - top, LOG_WEIGHT_FLOOR)

    # ---- read-outs -----------------------------------------------------------------------------
    @property
    def weights(self) -> np.ndarray:
        w = [math.exp(x) for x in self.log_weight]  # the lead's log-weight is 0
        total = sum(w)
        return np.array([x / total for x in w])

    @property
    def lead(self) -> PackCalibrator:
        lw = self.log_weight
        return self.members[lw.index(max(lw))]

    @property
    def soc(self) -> float:
        """The leading curve's SoC: the weighted mean would be a SoC no curve holds, and it read
        simulated 4.20 V LiPos up to 0.02 further off (quad-4s, C 0.8x from 85 %: 0.031 -> 0.051)."""
        return self.lead.soc

    @property
    def soc_sd(self) -> float:
        """The spread of the hypotheses about the reported SoC: √Σ w (σ² + (SoC − the lead's)²), the
        expected squared error of the lead's SoC if the weights are right."""
        return self._spread(lambda m: m.soc_sd)

    @property
    def filter_soc_sd(self) -> float:
        """That spread with each filter's own σ, without the chemistry's curve family
        (``PackCalibrator.filter_soc_sd``): what the count-down draws from."""
        return self._spread(lambda m: m.filter_soc_sd)

    def _spread(self, member_sd) -> float:
        if not self.initialised:
            return math.nan
        lead = self.lead.soc
        return math.sqrt(sum(w * (member_sd(m) ** 2 + (m.soc - lead) ** 2)
                             for w, m, out in zip(self.weights, self.members, self.ruled_out) if not out))

    @property
    def chem(self):
        return self.lead.chem

    @property
    def q0(self) -> float:
        """The prior capacity, C (every hypothesis's)."""
        return self.members[0].q0

    @property
    def voltage_trusted(self) -> bool:
        return self.lead.voltage_trusted

    @property
    def why_not_voltage(self) -> str | None:
        return self.lead.why_not_voltage

    @property
    def counters(self) -> dict:
        return self.lead.counters

    def evidence(self, now: float | None = None) -> list[str]:
        out = self.lead.evidence(now)
        if out and self.weights.max() < CURVE_SETTLED_WEIGHT:
            out.append("curve_open")
        return out

    def report(self) -> dict:
        """The leading hypothesis's report with the bank's σ, and every hypothesis's
        curve, weight and SoC."""
        out = self.lead.report()
        out["soc"] = round(self.soc, 4) if math.isfinite(self.soc) else None
        out["soc_sd"] = round(self.soc_sd, 4) if math.isfinite(self.soc_sd) else None
        out["evidence"] = self.evidence()
        out["curve_hypotheses"] = [
            {"curve": m.chem.name, "weight": round(float(w), 4), "ruled_out": bool(r),
             "soc": round(m.soc, 4) if math.isfinite(m.soc) and not r else None}
            for m, w, r in zip(self.members, self.weights, self.ruled_out)]
        return out
