"""Cell chemistries: the priors a pack nobody has fitted starts from (docs/estimation.md).

Per chemistry: the rested open-circuit voltage of one cell against its state of charge (a table,
interpolated linearly), the full and cut-off cell voltages, the highest voltage a rested cell of
that chemistry can show (a pack reading above it is another chemistry or a sensor fault, never a
fuller pack), and the circuit priors the self-calibrating estimator starts from (series resistance
of a 1 Ah cell, its Arrhenius temperature factor, one R–C polarisation pair).

Where the curves come from (docs/estimation.md says the same):

* ``lipo`` — the rested LiPo cell chart published with hobby chargers and RC battery guides
  (4.20 V full, 3.84 V at 50 %, 3.27 V empty: the one table most ground stations show); an
  approximation of a typical cobalt-oxide polymer cell, not one maker's cell.
* ``lihv`` — the same cell charged to 4.35 V: the LiPo table with the extra 0.15 V spread over
  the upper half of the curve (where a LiHV cell's curve differs), an approximation.
* ``liion`` — the mean of four published NMC/NCA-on-graphite cells' rested curves
  (``models.liion_family``: Chen2020's LG M50, Ecker2015's Kokam pouch, Mohtat2020's 5 Ah pouch,
  Kim2011's NCA cell; each the positive − negative electrode potential over its stoichiometry window
  as PyBaMM ships it). Not one cell's: they read each other 0.10-0.23 of SoC apart at rest, and a
  cell nobody measured reads closer to their mean (leave-one-out, docs/notes/2026-11-27-liion-family.md).
* ``lifepo4`` — a typical LFP/graphite rest curve (plateau 3.28–3.34 V between 20 % and 90 %,
  3.45 V full, 2.5 V empty), an approximation of published A123-type cell curves; its plateau
  carries little SoC information, so its estimate rests on the charge count there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gcs_pdm.models.liion_family import family_mean

#: the SoC grid of every table
SOC_GRID = np.round(np.linspace(0.0, 1.0, 21), 3)


@dataclass(frozen=True)
class Chemistry:
    name: str
    #: rested cell voltage at each SOC_GRID point, V
    ocv_cell_v: tuple[float, ...]
    full_cell_v: float
    cutoff_cell_v: float
    #: the highest voltage a rested, full cell of this chemistry shows (charger tolerance, a SITL's
    #: 4.24 V included); above it the pack is not this chemistry
    max_rest_cell_v: float
    #: series resistance of a 1 Ah cell, Ω (a cell of Q Ah: this / Q), and the polarisation pair
    r0_cell_ah: float
    r1_ratio: float
    tau1_s: float
    #: Arrhenius factor of the resistance: R(T) = R(25 °C) exp(k (1/T − 1/298.15)), K
    r_activation_k: float
    source: str

    def ocv(self, soc: float) -> float:
        """Rested cell voltage at ``soc`` (clipped to [0, 1]), V."""
        return float(np.interp(min(max(soc, 0.0), 1.0), SOC_GRID, self.ocv_cell_v))

    def soc_at(self, cell_v: float) -> float:
        """The SoC at which a rested cell shows ``cell_v`` (clipped to the table's span)."""
        return float(np.interp(cell_v, self.ocv_cell_v, SOC_GRID))

    def slope(self, soc: float) -> float:
        """dOCV/dSoC at ``soc``, V per unit SoC (the table's segment slope)."""
        k = int(min(max(math.floor(min(max(soc, 0.0), 1.0) * 20.0), 0), 19))
        return (self.ocv_cell_v[k + 1] - self.ocv_cell_v[k]) * 20.0

    @property
    def table(self) -> np.ndarray:
        return np.asarray(self.ocv_cell_v, dtype=np.float64)


_LIPO = (3.27, 3.61, 3.69, 3.71, 3.73, 3.75, 3.77, 3.79, 3.80, 3.82, 3.84, 3.85, 3.87, 3.91, 3.95, 3.98, 4.02,
         4.08, 4.11, 4.15, 4.20)

CHEMISTRIES: dict[str, Chemistry] = {
    "lipo": Chemistry("lipo", _LIPO, 4.20, 3.5, 4.25, 0.020, 0.5, 20.0, 2500.0,
                      "rested LiPo cell chart of hobby chargers and RC battery guides (approximation)"),
    "lihv": Chemistry("lihv", tuple(round(v + 0.15 * max(0.0, (s - 0.5) / 0.5), 4) for s, v in zip(SOC_GRID, _LIPO)),
                      4.35, 3.5, 4.40, 0.020, 0.5, 20.0, 2500.0,
                      "the LiPo chart with the 0.15 V of a 4.35 V charge spread over its upper half (approximation)"),
    "liion": Chemistry("liion", family_mean(), 4.20, 3.0, 4.25, 0.030, 0.6, 30.0, 3000.0,
                       "mean of the published NMC/NCA curves of Chen et al. 2020, Ecker et al. 2015, Mohtat et "
                       "al. 2020 and Kim et al. 2011, via PyBaMM"),
    "lifepo4": Chemistry("lifepo4", (2.50, 3.00, 3.20, 3.23, 3.25, 3.265, 3.28, 3.285, 3.29, 3.295, 3.30, 3.305,
                                     3.31, 3.315, 3.32, 3.325, 3.33, 3.335, 3.34, 3.36, 3.45),
                         3.45, 2.8, 3.65, 0.015, 0.5, 30.0, 3000.0,
                         "typical LFP/graphite rest curve (A123-type cells; approximation)"),
}


def chemistry(name: str) -> Chemistry:
    try:
        return CHEMISTRIES[name]
    except KeyError:
        raise ValueError(f"chemistry {name!r}: not one of {', '.join(CHEMISTRIES)}") from None


def chemistry_of_rest_voltage(cell_v: float, default: str = "lipo") -> str:
    """The chemistry a pack resting at ``cell_v`` per cell can be, starting from ``default``:
    a LiPo can rest up to its ``max_rest_cell_v``; above that only a LiHV can (4.35 V full). A
    reading above every chemistry's limit stays the default's (the caller says it is implausible)."""
    if cell_v <= CHEMISTRIES[default].max_rest_cell_v:
        return default
    if cell_v <= CHEMISTRIES["lihv"].max_rest_cell_v:
        return "lihv"
    return default
