"""The next flight's estimator starts from each pack's latest health (issue 30).

A pack's latest health point (``trend.estimator_priors``: capacity and resistance at 25 °C, each
with its σ) replaces what the vehicle description alone would give the self-calibrating filter
(``estimation.calibration.PackPrior``): the capacity with the stored σ, the series resistance
with the stored σ and no less than what reading a 1-s pulse as a series resistance leaves open.

The health point's resistance is a 1-s pulse resistance (``packs.health``): the series resistance
R0 plus what the polarisation pair builds in that second, R0 ρ (1 − e^(−1/τ₁)) in the filter's own
model (``calibration``: v₁' = a v₁ + (1 − a) ρ R0 I). So R0 = R_pulse / (1 + ρ (1 − e^(−1/τ₁))),
with the pair's share of the pulse counted as its uncertainty (the pair's ρ and τ₁ are the
chemistry's, not this pack's).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

#: the pulse a health point's resistance is read over (s): one sample step at the autopilot's rate
PULSE_S = 1.0


def series_resistance_of_pulse(pulse_ohm: float, r1_ratio: float, tau1_s: float) -> tuple[float, float]:
    """(R0, the pair's share of the pulse as a fraction): R_pulse = R0 (1 + ρ (1 − e^(−t/τ₁)))."""
    pair = r1_ratio * (1.0 - math.exp(-PULSE_S / max(tau1_s, 1e-6)))
    return pulse_ohm / (1.0 + pair), pair / (1.0 + pair)


def prior_with_history(base, history: dict | None, pack_id: str | None = None):
    """``base`` (a ``PackPrior`` from the description) with the pack's latest health; ``base``
    itself when no flight has told (None, or no quantity known)."""
    if not history:
        return base
    changes = {}
    cap, cap_sd = history.get("capacity_ah"), history.get("capacity_sd_ah")
    if cap is not None and cap > 0 and cap_sd is not None and math.isfinite(cap_sd):
        borrowed = borrowed_curve_capacity_rel_sd(base, history.get("capacity_depth_of_discharge"))
        changes.update(capacity_c=float(cap) * 3600.0,
                       capacity_rel_sd=max(math.hypot(float(cap_sd) / float(cap), borrowed), 1e-4),
                       capacity_source=f"pack history ({pack_id or 'this pack'})"
                                       + (" read through its chemistry's curve" if borrowed else ""))
    changes.update(_curve_changes(base, history.get("curve"), changes.get("capacity_rel_sd"), pack_id))
    res, res_sd = history.get("resistance_25c_ohm"), history.get("resistance_sd_ohm")
    if res is not None and res > 0 and res_sd is not None and math.isfinite(res_sd):
        chem = base.chem
        r0, pair_share = series_resistance_of_pulse(float(res), chem.r1_ratio, chem.tau1_s)
        changes.update(r0_ohm=r0, r0_rel_sd=math.hypot(float(res_sd) / float(res), pair_share))
    return replace(base, **changes) if changes else base


def borrowed_curve_capacity_rel_sd(base, depth_of_discharge: float | None) -> float:
    """The relative σ a health point's capacity carries when its two rests were read through a
    curve that is not the pack's own (``base`` has no curve of its own: ``PackPrior.curve_family_spread``),
    on top of its own σ: each rest's SoC misread by the family's rest σ, over the SoC used between
    them (``depth_of_discharge``; unknown: the shallowest a capacity is read from). The health point's
    own σ is the flight's (noise, relaxation, gain); this part is the curve's, the same on every
    flight of the pack, so the pack's trend does not carry it, the filter's prior does. Measured on
    PyBaMM cells no fixture holds (docs/notes/2026-11-28-history-prior.md): read on the LG M50's
    electrodes, NCA_Kim2011 came out 7-23 % low with σ 1.6 %; its next flights' 2σ band then held
    the truth in 0.67-0.76 of samples."""
    from gcs_pdm.packs.health import HealthSettings

    spread = base.curve_family_spread
    if spread is None:
        return 0.0
    used = depth_of_discharge if depth_of_discharge and depth_of_discharge > 0 else HealthSettings().min_soc_used
    return math.sqrt(2.0) * spread.rest_soc_sd / float(used)


#: a curve hypothesis a flight's fit chose this surely is the next flight's one curve (below, the
#: next flight weighs them again: the bank, from its base rates)
CURVE_CHOSEN_WEIGHT = 0.95
#: the learned offset's and scale's σ are floored here: one flight's fit, next flight's temperature
MIN_OFFSET_SD = 0.005
MIN_SCALE_SD = 0.02


def _curve_changes(base, fit: dict | None, capacity_rel_sd: float | None, pack_id: str | None) -> dict:
    """What a flight's curve fit (``packs.flight_curve``) gives the next flight of a pack whose
    chemistry leaves the curve open (``models.curve_hypotheses``): the curve it chose (by the charge
    voltage that picks it), as that flight fitted it (shape, offset, scale), and its capacity where
    the health point's is unknown or looser. Nothing for a described pack's own curve (the fit read
    the chemistry's curves, not it), a chemistry with one curve, or a fit that could not tell."""
    from gcs_pdm.models.curve_hypotheses import curve_hypotheses

    if not fit or fit.get("why") or base.curve is not None or fit.get("weight", 0.0) < CURVE_CHOSEN_WEIGHT:
        return {}
    hyps = curve_hypotheses(base.chemistry)
    hyp = next((h.curve for h in hyps if h.curve.name == fit["curve"]), None)
    if hyp is None or len(hyps) < 2:
        # a chemistry with one published curve keeps it: a flight's shape fit absorbs the circuit's
        # misses too, and where the curve was right it made the next flight worse (PyBaMM Chen2020 on
        # its own published curve: 7/12 within 0.05 from the chemistry; 1/11 from three of its flights)
        return {}
    table = tuple(float(x) for x in fit["ocv_cell_v"])
    learned = replace(hyp, name=f"{hyp.name} (learned by {pack_id or 'this pack'}'s flight)", ocv_cell_v=table,
                      max_rest_cell_v=max(hyp.max_rest_cell_v, table[-1] + 0.02),
                      source=f"{hyp.source}, its shape fitted to an earlier flight of this pack")
    # the learned table carries the offset and scale: the filter's own start at 0, with the table's
    # typical σ over the span the flight covered
    out = {"curve": learned, "full_cell_v": float(fit["full_cell_v"]),
           "ocv_offset_v": 0.0, "ocv_offset_sd": max(float(np.median(fit["ocv_cell_sd"])), MIN_OFFSET_SD),
           "ocv_scale": 0.0, "ocv_scale_sd": MIN_SCALE_SD}
    cap, cap_sd = fit.get("capacity_ah"), fit.get("capacity_sd_ah")
    if cap and cap > 0 and cap_sd and (capacity_rel_sd is None or cap_sd / cap < capacity_rel_sd):
        out.update(capacity_c=float(cap) * 3600.0, capacity_rel_sd=float(cap_sd) / float(cap),
                   capacity_source=f"pack history ({pack_id or 'this pack'}): a flight's curve fit")
    return out


def start_from_history(estimator, priors_by_slot: dict[str, dict | None]) -> dict[str, str]:
    """Restart each self-calibrated pack's filter of ``estimator`` (a ``StateEstimator`` that has
    not yet taken a frame of that pack) from its pack's latest health; per pack slot, what it
    starts from. ``priors_by_slot``: ``Service.pack_priors()`` ({slot: estimator_priors + pack_id})."""
    from gcs_pdm.estimation.curve_bank import pack_calibrator

    calib = getattr(estimator, "calib", None)
    names = getattr(estimator, "pack_names", ())
    out = {}
    for b, slot in enumerate(names):
        cal = calib[b] if calib is not None and b < len(calib) else None
        history = priors_by_slot.get(slot)
        if cal is None:
            out[slot] = "not self-calibrated (the paper aircraft's fitted set): the description's priors"
        elif cal.initialised:
            out[slot] = "its filter has already started: the description's priors"
        elif not history:
            out[slot] = "no flight of this pack has told its health: the description's priors"
        else:
            prior = prior_with_history(cal.prior, history, history.get("pack_id"))
            if prior is cal.prior:
                out[slot] = "its health has no capacity or resistance known: the description's priors"
                continue
            calib[b] = pack_calibrator(prior, sigma_v=cal.sigma_v)
            out[slot] = f"pack history ({history.get('pack_id') or slot}, flight ending t={history.get('from_flight_end_s')})"
    return out
