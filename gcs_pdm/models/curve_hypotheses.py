"""The rested curves a pack of one named chemistry may have (issue 29).

A user names a pack's chemistry; the name does not fix its curve. A cobalt-oxide pouch cell *is* a
"LiPo" to a hobbyist, and it may be charged to 4.20 V or to 4.10 V (a Li-ion charger mode, a cell
rated so): at 3.97 V per cell the first is 74 % full, the second 87-94 %. A rested voltage cannot
tell them apart (an offset and a SoC read the same); the voltage against the charge drawn can,
slowly. ``estimation.curve_bank`` runs one filter per hypothesis here and weighs them by how well
each explains the voltage.

Every curve is published data (docs/estimation.md names them), never a test cell's own:

* ``lipo`` — the hobby LiPo chart (``models.chemistry``), 4.20 V full;
* ``lco_4v10`` — an LCO/graphite *pouch* cell charged to 4.10 V: the Enertech cell of Ai et al.
  2020 (J. Electrochem. Soc. 167 013512; electrode curves from Rieger et al. 2016, J. Electrochem.
  Soc. 163 A1566) as PyBaMM ships it (set ``Ai2020``), its 3.0-4.2 V window cut where it reaches
  4.10 V (91 % of it). ``scripts/curve_hypotheses_pybamm.py`` recomputes the table. Its 4.20 V
  window rests within 0.05 V of the hobby chart between 10 and 95 %, so it adds no hypothesis there.

Chemistries with one curve (LiHV, Li-ion, LiFePO4) keep it: one filter, as before.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from gcs_pdm.models.chemistry import CHEMISTRIES, Chemistry, chemistry

#: Ai2020 (Enertech LCO/graphite pouch) charged to 4.10 V, on ``chemistry.SOC_GRID``
_LCO_POUCH_4V10 = (3.0, 3.5202, 3.6346, 3.6554, 3.6861, 3.7089, 3.7243, 3.739, 3.7523, 3.765, 3.778, 3.7932,
                   3.811, 3.8326, 3.8597, 3.895, 3.9349, 3.9729, 4.0135, 4.0559, 4.1)


#: PyBaMM's ``Prada2013`` (an A123 ANR26650 LFP/graphite cell: Prada et al. 2013, J. Electrochem. Soc. 160
#: A616), its cell curve over the set's stoichiometry window, on ``chemistry.SOC_GRID``: the LFP electrode of
#: Afshar et al. 2017 (arXiv:1709.03970) less the graphite of Chen et al. 2020 (J. Electrochem. Soc. 167
#: 080534), as PyBaMM composes them (``scripts/pybamm_curves.py --sets Prada2013``, then
#: ``replay.calibration_eval.pybamm_cell_curve``). Its plateau sits 20-80 mV below the ``lifepo4`` table's
#: between 20 and 95 % (122 mV at 15 %): on a plateau of a few mV per 10 %, the two read one rested voltage 0.2-0.4 apart
_LFP_A123_PRADA2013 = (1.9998, 2.7853, 2.9781, 3.108, 3.1685, 3.1857, 3.2058, 3.2324, 3.2525, 3.2621, 3.266, 3.2678,
                       3.2688, 3.27, 3.274, 3.2926, 3.3097, 3.3132, 3.3142, 3.3164, 3.6006)


@dataclass(frozen=True)
class CurveHypothesis:
    """One curve a pack of a named chemistry may rest on, and how likely it is before any flight."""

    curve: Chemistry
    prior_weight: float


def _lco_pouch_4v10() -> Chemistry:
    # the circuit priors stay the LiPo's (the same cells); only the curve and its limits change
    return replace(CHEMISTRIES["lipo"], name="lco_4v10", ocv_cell_v=_LCO_POUCH_4V10, full_cell_v=4.10,
                   max_rest_cell_v=4.12,
                   source="LCO/graphite pouch (Enertech; Ai et al. 2020, J. Electrochem. Soc. 167 013512, via "
                          "PyBaMM Ai2020) charged to 4.10 V")


def _lfp_a123_prada2013() -> Chemistry:
    # only its rested readings are used (``CurveFamilySpread.curves``). Its full cell is the table's: both are
    # cells charged to 3.6 V, the table's end is where a charged cell rests, and PyBaMM's window ends on the
    # charge's own 3.60 V, so a declared charge voltage must not pick one of them (``given_full``)
    return replace(CHEMISTRIES["lifepo4"], name="lfp_a123_prada2013", ocv_cell_v=_LFP_A123_PRADA2013,
                   source="A123 ANR26650 LFP/graphite (Prada et al. 2013, J. Electrochem. Soc. 160 A616; LFP "
                          "electrode Afshar et al. 2017, graphite Chen et al. 2020; via PyBaMM Prada2013)")


#: per chemistry name with more than one curve: the hypotheses, their prior weights summing to 1.
#: A hobby LiPo is charged to 4.20 V far more often than to 4.10 V; the weight is a base rate, not
#: a measurement. At 0.5 (the bank's SoC then the weighted mean) the chemistry-curve presets of
#: bench_soc_calibration went 22 -> 7 of 24 met (0.07-0.12 off); at 0.1, the lead's SoC, 23 of 24
CURVE_HYPOTHESES: dict[str, tuple[CurveHypothesis, ...]] = {
    "lipo": (CurveHypothesis(CHEMISTRIES["lipo"], 0.9), CurveHypothesis(_lco_pouch_4v10(), 0.1)),
}


#: a declared full voltage picks the curves whose full cell is within this of it (a charger's end
#: voltage is set to 0.01-0.05 V)
DECLARED_FULL_MATCH_V = 0.05


def curve_hypotheses(name: str, full_cell_v: float | None = None) -> tuple[CurveHypothesis, ...]:
    """The curves a pack named ``name`` may rest on (one, the chemistry table's, for most). With
    ``full_cell_v`` (the description declares what the pack is charged to) only those full within
    ``DECLARED_FULL_MATCH_V`` of it, their weights renormalised; all of them if none is."""
    hyps = CURVE_HYPOTHESES.get(name, (CurveHypothesis(chemistry(name), 1.0),))
    if full_cell_v is None:
        return hyps
    kept = [h for h in hyps if abs(h.curve.full_cell_v - full_cell_v) <= DECLARED_FULL_MATCH_V + 1e-9]
    if not kept or len(kept) == len(hyps):
        return hyps
    total = sum(h.prior_weight for h in kept)
    return tuple(replace(h, prior_weight=h.prior_weight / total) for h in kept)


#: what a chemistry's name leaves open about the SoC when the pack's curve is only its published
#: table's (no curve of its own, none learned from its history; with a declared charge voltage,
#: ``given_full``): the published curves of one chemistry read each other's cells 0.10-0.23 of SoC
#: apart at rest (Li-ion: Chen2020, Ecker2015, Mohtat2020, Kim2011), and in flight they differ by only 1-5 mV rms, so no
#: flight shrinks it. ``rest_soc_sd``: that spread at a rested start, as a σ; ``slope_rel_sd``: the
#: relative spread of their slopes, which the voltage turns into an error in the charge it reads as
#: drawn (the filter learned 0.77-1.49x the true capacity through a curve of the wrong slope).
#: Measured in docs/notes/2026-11-27-honest-soc-sigma.md; a chemistry not listed has no measured
#: spread and adds nothing (its σ is the filter's alone). Li-ion's table is the four curves' mean
#: (``models.liion_family``): a cell read at rest through the mean of the OTHER three is 0.079 rms
#: off (10-95 %), the 0.08 below (docs/notes/2026-11-27-liion-family.md).
#: ``count_in_flight``: the filter holds the capacity at its prior and, under load, lets the voltage
#: teach only the circuit — the SoC is the rested start plus the charge counted (its σ the capacity's)
#: — instead of reading it through a slope it does not know (Li-ion: PyBaMM Chen2020 8 -> 12/12,
#: held-out cells 2 -> 4/18 within 0.05 after 5 min; docs/notes/2026-11-27-curve-uncertainty.md).
#: Not for ``lipo``: its bank carries its curves, and its simulated presets need the capacity learned
#: from the voltage (chemistry-curve presets 30 -> 17/32 with it).
#: ``curves``: published curves of the chemistry whose readings of one rested voltage set the start's
#: σ where they part by more than ``rest_soc_sd`` (``rest_sd_at``): on a flat stretch a few mV move
#: the SoC far. The hobby LiPo chart and an LCO cell charged to 4.10 V read a rested cell 0.11-0.18
#: apart between 3.70 and 4.10 V (0.15-0.18 at 3.76-3.84 V), and PyBaMM's Marquis2019 (an LCO pouch,
#: not one of them) rests at 3.83-3.90 V 0.29 above the chart's reading: with 0.08 its 2σ band held
#: the truth in 40 % of flight 09 (docs/notes/2026-11-27-takeover-curve.md).
@dataclass(frozen=True)
class CurveFamilySpread:
    rest_soc_sd: float
    slope_rel_sd: float
    count_in_flight: bool = False
    curves: tuple[Chemistry, ...] = ()

    def rest_sd_at(self, cell_v: float) -> float:
        """The start's σ at a rested ``cell_v``: ``rest_soc_sd``, or the spread of the SoCs the
        family's ``curves`` read there (their largest less their smallest), whichever is larger."""
        readings = [c.soc_at(cell_v) for c in self.curves]
        return max(self.rest_soc_sd, max(readings) - min(readings)) if readings else self.rest_soc_sd

    def given_full(self, full_cell_v: float) -> CurveFamilySpread:
        """What is left open once the pack's charge voltage is declared: only the ``curves`` that end
        there (within ``DECLARED_FULL_MATCH_V``; all of them if none does) still read it. The
        declaration settles the curve's end, not its flat middle, so ``rest_soc_sd`` and
        ``slope_rel_sd`` stay: the family's curves that share an end still part by them (Li-ion's four,
        all ending at 4.20 V, misread each other's cells 0.08 rms at rest), and the one published
        4.10 V LCO curve misreads PyBaMM's Marquis2019, charged to 4.10 V too, by 30-80 mV per cell
        on its middle (docs/notes/2026-11-27-declared-sigma.md)."""
        kept = tuple(c for c in self.curves if abs(c.full_cell_v - full_cell_v) <= DECLARED_FULL_MATCH_V + 1e-9)
        return replace(self, curves=kept or self.curves)


CURVE_FAMILY_SPREAD: dict[str, CurveFamilySpread] = {
    "liion": CurveFamilySpread(rest_soc_sd=0.08, slope_rel_sd=0.25, count_in_flight=True),
    "lipo": CurveFamilySpread(rest_soc_sd=0.08, slope_rel_sd=0.5,
                              curves=tuple(h.curve for h in CURVE_HYPOTHESES["lipo"])),
    # LiFePO4: its plateau holds 15-95 % within 0.1-0.2 V, so the table and the one published cell
    # (Prada2013) read a rested cell there 0.2-0.4 apart; before this the filter read PyBaMM's Prada2013
    # 0.19-0.32 low with a σ of 0.05-0.06 (2σ held the truth in a median 26 % of samples). In flight the
    # plateau teaches the circuit only, as Li-ion's curve does (docs/notes/2026-11-28-lfp-curve.md)
    "lifepo4": CurveFamilySpread(rest_soc_sd=0.08, slope_rel_sd=0.25, count_in_flight=True,
                                 curves=(CHEMISTRIES["lifepo4"], _lfp_a123_prada2013())),
}


def is_published_table_curve(name: str, curve: Chemistry | None) -> bool:
    """Whether ``curve`` (a ``PackPrior.curve``; None: the table's) is one of chemistry ``name``'s
    published table curves, not a pack's own (described, or learned from its history)."""
    return curve is None or any(h.curve == curve for h in CURVE_HYPOTHESES.get(name, ())) or curve == chemistry(name)
