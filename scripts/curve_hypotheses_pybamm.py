"""The published LCO/graphite pouch curve behind ``models.curve_hypotheses`` (issue 29).

Development tool (PyBaMM, in its own venv, as ``pybamm_curves.py``):

    /work/venv-pybamm/bin/python scripts/curve_hypotheses_pybamm.py

PyBaMM's ``Ai2020`` set: the Enertech LCO/graphite pouch cell of Ai et al. 2020 (J. Electrochem.
Soc. 167 013512) and Rieger et al. 2016 (J. Electrochem. Soc. 163 A1566), its electrode curves as
measured there. The cell's rested curve is U_p(y) − U_n(x) along its stoichiometry window (PyBaMM's
``get_min_max_stoichiometries``: 3.0 V empty, 4.2 V full). Charged to 4.10 V instead, the same cell
stops where that line reaches 4.10 V: its SoC is the charge from 3.0 V over the charge to 4.10 V.
Prints both curves on the chemistry tables' 21-point SoC grid (4 decimals).
"""
from __future__ import annotations

import numpy as np

T_REF_K = 298.15
SET = "Ai2020"


def main() -> int:
    import pybamm

    values = pybamm.ParameterValues(SET)
    x_0, x_100, y_100, y_0 = pybamm.lithium_ion.get_min_max_stoichiometries(values)

    def potential(name: str, sto: float) -> float:
        fn = values[name]
        try:
            e = fn(pybamm.Scalar(sto))
        except TypeError:
            e = fn(pybamm.Scalar(sto), pybamm.Scalar(T_REF_K))
        return float(np.asarray(values.evaluate(e)).ravel()[0])

    def cell(s: float) -> float:
        return (potential("Positive electrode OCP [V]", y_0 + s * (y_100 - y_0))
                - potential("Negative electrode OCP [V]", x_0 + s * (x_100 - x_0)))

    lo, hi = 0.5, 1.0  # bisection for the window's 4.10 V point (the curve rises monotonically)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cell(mid) < 4.10 else (lo, mid)
    top = 0.5 * (lo + hi)
    grid = np.linspace(0.0, 1.0, 21)
    print(f"{SET}: x {x_0:.4f}-{x_100:.4f}, y {y_0:.4f}-{y_100:.4f}; 4.10 V at {top:.4f} of the 4.2 V window")
    print("4.20 V window:", tuple(round(cell(s), 4) for s in grid))
    print("4.10 V window:", tuple(round(cell(s * top), 4) for s in grid))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
