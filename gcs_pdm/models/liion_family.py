"""The published Li-ion (NMC/NCA on graphite) rested curves the ``liion`` table is made of (issue 29).

A pack named "Li-ion" may be any of them or none: the product is used on cells nobody measured.
No one published curve reads the others to 0.05 of SoC (they misread each other's cells at rest by
0.10-0.23), so the ``liion`` table is their mean on ``chemistry.SOC_GRID`` (``family_mean``): measured
leave-one-out (each cell read through the mean of the OTHER curves, as if it were unknown), the
family's mean reads a cell's rested start to a median 0.013 of SoC where one cell's curve (Chen2020's,
the table before) read the others to 0.050 (docs/notes/2026-11-27-liion-family.md).

Each curve is the positive minus the negative electrode potential (25 °C) over the cell's
stoichiometry window, as PyBaMM's parameter sets publish them (``scripts/pybamm_curves.py`` writes
the electrode curves; ``replay.calibration_eval.pybamm_cell_curve`` turns them into these tables;
tests/test_soc_calibration.py recomputes Chen2020's from ``fixtures/pybamm/curves.json``,
benchmarks/bench_heldout_cells.py the other three from the held-out sets' ``curves.json``). Every
one is full at 4.20 V.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PublishedCurve:
    """One published cell's rested curve: V per cell on the 21-point SoC grid (0, 0.05, …, 1)."""

    pybamm_set: str
    cell: str
    source: str
    ocv_cell_v: tuple[float, ...]


LIION_PUBLISHED_CURVES: tuple[PublishedCurve, ...] = (
    PublishedCurve("Chen2020", "LG M50 21700, NMC811 / graphite-SiOx",
                   "Chen et al. 2020, J. Electrochem. Soc. 167 080534",
                   (2.4999, 3.1094, 3.2959, 3.4339, 3.4852, 3.5286, 3.5814, 3.629, 3.667, 3.7054, 3.7509, 3.7983,
                    3.8406, 3.8896, 3.9479, 3.9943, 4.0421, 4.0809, 4.0967, 4.1236, 4.2)),
    PublishedCurve("Ecker2015", "Kokam SLPB 75106100 pouch, NMC / graphite",
                   "Ecker et al. 2015, J. Electrochem. Soc. 162 A1836 and A1849",
                   (2.4966, 3.2938, 3.4586, 3.5277, 3.587, 3.6565, 3.7094, 3.743, 3.77, 3.7805, 3.7873, 3.7979,
                    3.8155, 3.8417, 3.8823, 3.94, 3.9868, 4.0304, 4.0789, 4.1353, 4.2)),
    PublishedCurve("Mohtat2020", "5 Ah pouch, NMC / graphite",
                   "Mohtat et al. 2020, J. Electrochem. Soc. 167 110561",
                   (2.7996, 3.462, 3.5107, 3.5395, 3.5847, 3.6202, 3.6389, 3.6538, 3.671, 3.6914, 3.7155, 3.7446,
                    3.7968, 3.8399, 3.8797, 3.9232, 3.9705, 4.0216, 4.0767, 4.136, 4.2)),
    PublishedCurve("NCA_Kim2011", "NCA / graphite",
                   "Kim et al. 2011, J. Electrochem. Soc. 158 A955",
                   (2.6996, 3.1939, 3.2471, 3.3099, 3.3721, 3.4331, 3.4918, 3.5472, 3.5978, 3.643, 3.6846, 3.7253,
                    3.7678, 3.8163, 3.8742, 3.93, 3.9803, 4.0295, 4.0803, 4.1354, 4.2)),
)


def family_mean(curves: tuple[PublishedCurve, ...] = LIION_PUBLISHED_CURVES) -> tuple[float, ...]:
    """The mean of ``curves``' rested voltages at each SoC grid point, V per cell (4 decimals)."""
    return tuple(round(sum(c.ocv_cell_v[k] for c in curves) / len(curves), 4) for k in range(len(curves[0].ocv_cell_v)))
