"""What a pack's capacity is read on, by its chemistry: one choice for the live service, ``gcs-pdm
packs ingest``, the ageing evaluation (scripts/evaluate_pack_ageing.py) and the synthetic packs, so
the health point learned live is the one the evaluation measures.

* ``liion`` (NMC/graphite): the two **electrodes'** potentials against stoichiometry and their
  capacities (LG M50, Chen et al. 2020, as PyBaMM ships them: ``electrodes_lgm50.json``), scaled to
  the pack's rated capacity. A capacity is then read as lithium lost, which is what an ageing cell
  loses; its full-cell curve against its own SoC changes shape as it does (docs/packs.md).
* the others (``lipo``, ``lihv``, ``lifepo4``): the chemistry's full-cell open-circuit curve
  (``models.chemistry``), read with ``GENERIC_CURVE_SOC_SD`` more SoC uncertainty (the tables are
  approximations of a typical cell, not the pack's own). No electrode curves are known for them, so
  an aged pack's capacity reads high on them (measured on the ageing fixtures with a fresh full-cell
  curve: +5 % at 7 % fade).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from gcs_pdm.models.chemistry import CHEMISTRIES, SOC_GRID
from gcs_pdm.packs.health import (GENERIC_CURVE_SOC_SD, ElectrodeCurves, HealthPoint, HealthSettings, OcvCurve,
                                  health_point)

ELECTRODE_TABLES = {"liion": Path(__file__).with_name("electrodes_lgm50.json")}


@dataclass(frozen=True)
class CapacityReading:
    """The curve one pack's capacity is read on: ``electrodes`` where the chemistry has them, else ``ocv``."""
    chemistry: str
    ocv: OcvCurve | None = None
    electrodes: ElectrodeCurves | None = None


@lru_cache(maxsize=None)
def _electrode_table(chemistry: str) -> dict:
    return json.loads(ELECTRODE_TABLES[chemistry].read_text())


@lru_cache(maxsize=64)
def capacity_reading(chemistry: str, rated_capacity_ah: float) -> CapacityReading:
    """The reading for a pack of ``chemistry`` rated ``rated_capacity_ah`` (per series string of cells)."""
    if chemistry not in CHEMISTRIES:
        raise ValueError(f"chemistry {chemistry!r}: not one of {', '.join(CHEMISTRIES)}")
    if rated_capacity_ah <= 0:
        raise ValueError(f"rated capacity {rated_capacity_ah!r} Ah: must be positive")
    if chemistry in ELECTRODE_TABLES:
        t = _electrode_table(chemistry)
        electrodes = ElectrodeCurves(tuple(t["stoichiometry"]), tuple(t["negative_v"]), tuple(t["positive_v"]),
                                     t["negative_ah_per_rated_ah"] * rated_capacity_ah,
                                     t["positive_ah_per_rated_ah"] * rated_capacity_ah, t["lower_cutoff_v"],
                                     name=f"{chemistry} electrodes")
        return CapacityReading(chemistry, electrodes=electrodes)
    chem = CHEMISTRIES[chemistry]
    return CapacityReading(chemistry, ocv=OcvCurve(tuple(float(s) for s in SOC_GRID), chem.ocv_cell_v,
                                                   soc_sd=GENERIC_CURVE_SOC_SD, name=f"{chemistry} full cell"))


def rested_cell_voltage(reading: CapacityReading, capacity_ah: float, drawn_ah, full_cell_v: float | None = None):
    """The rested cell voltage of a pack of (true, C/20) ``capacity_ah`` charged full, after
    ``drawn_ah`` (array or scalar): what the synthetic packs sit on. On electrodes an aged pack has
    lost lithium: its inventory is the one whose capacity from the full charge (``full_cell_v``,
    default the chemistry's) is ``capacity_ah``."""
    drawn = np.asarray(drawn_ah, float)
    if reading.electrodes is None:
        curve = reading.ocv
        return np.interp(1.0 - drawn / capacity_ah, curve.soc, curve.voltage_v)
    el = reading.electrodes
    full_v = full_cell_v if full_cell_v is not None else CHEMISTRIES[reading.chemistry].full_cell_v
    x0, y0 = _full_state(el, float(capacity_ah), float(full_v))
    return el.u_p(y0 + drawn / el.positive_ah) - el.u_n(x0 - drawn / el.negative_ah)


@lru_cache(maxsize=256)
def _full_state(electrodes: ElectrodeCurves, capacity_ah: float, full_v: float) -> tuple[float, float]:
    return electrodes.full_state_for(capacity_ah, full_v)


def pack_health_point(pack_id: str, time_s, current_a, voltage_v, temperature_c=None, *, chemistry: str,
                      nominal_capacity_ah: float, cells_series: int = 1,
                      settings: HealthSettings = HealthSettings(), fit_curve: bool = False,
                      full_cell_v: float | None = None) -> HealthPoint:
    """A flight's health point read on its chemistry's curve (``capacity_reading``): the one call of
    the live service, ``packs ingest`` and the ageing evaluation. With ``fit_curve`` it also carries
    the flight's curve fit (``packs.flight_curve``; ``full_cell_v``: the declared charge voltage),
    what the pack's next flight starts its curve from (``packs.priors``)."""
    reading = capacity_reading(chemistry, float(nominal_capacity_ah))
    hp = health_point(pack_id, time_s, current_a, voltage_v, temperature_c, nominal_capacity_ah=nominal_capacity_ah,
                      cells_series=cells_series, ocv=reading.ocv, electrodes=reading.electrodes, settings=settings)
    if fit_curve:
        from gcs_pdm.estimation.calibration import PackPrior
        from gcs_pdm.packs.flight_curve import fit_flight_curve

        prior = PackPrior(chemistry, int(cells_series), float(nominal_capacity_ah) * 3600.0, full_cell_v=full_cell_v)
        hp.curve = fit_flight_curve(time_s, current_a, voltage_v, temperature_c, prior)
    return hp
