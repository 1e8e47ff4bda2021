"""The open-circuit curves behind the PyBaMM fixtures: each electrode's potential and the cell's window.

Development tool (PyBaMM, in its own venv, as ``generate_pybamm_flights.py``):

    /work/venv-pybamm/bin/python scripts/pybamm_curves.py --out fixtures/pybamm/curves.json

Per parameter set: the stoichiometry windows PyBaMM's ``set_initial_state`` uses (negative x_0 at
SoC 0 to x_100 at SoC 1; positive y_0 to y_100), and the negative and positive electrode potentials
(V, at 25 °C) on a stoichiometry grid. The cell's open-circuit voltage at SoC s is then
U_p(y_0 + s (y_100 - y_0)) - U_n(x_0 + s (x_100 - x_0)), which is what the generator's flights start
from. ``scripts/diagnose_model_structure.py`` fits circuits with these curves held (docs/fitting.md,
"What limits the extended circuit").
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

SETS = ("Chen2020", "Marquis2019")
GRID = np.round(np.linspace(0.001, 0.999, 999), 6)
T_REF_K = 298.15


def electrode_potential(pybamm, values, name: str, sto: float) -> float:
    fn = values[name]
    try:
        return float(values.evaluate(fn(pybamm.Scalar(sto))))
    except TypeError:  # parameter sets whose potentials take the temperature too
        return float(values.evaluate(fn(pybamm.Scalar(sto), pybamm.Scalar(T_REF_K))))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="fixtures/pybamm/curves.json")
    ap.add_argument("--sets", nargs="+", default=list(SETS), metavar="SET",
                    help="PyBaMM parameter sets (default: the fixtures'; e.g. Prada2013 for an LFP cell)")
    args = ap.parse_args(argv)
    import pybamm

    out = {"generator": "scripts/pybamm_curves.py", "pybamm": pybamm.__version__, "temperature_k": T_REF_K,
           "stoichiometry": GRID.tolist(), "sets": {}}
    for set_name in args.sets:
        values = pybamm.ParameterValues(set_name)
        x_0, x_100, y_100, y_0 = pybamm.lithium_ion.get_min_max_stoichiometries(values)
        out["sets"][set_name] = {
            "x_0": float(x_0), "x_100": float(x_100), "y_0": float(y_0), "y_100": float(y_100),
            "negative_v": [round(electrode_potential(pybamm, values, "Negative electrode OCP [V]", x), 6) for x in GRID],
            "positive_v": [round(electrode_potential(pybamm, values, "Positive electrode OCP [V]", y), 6) for y in GRID],
        }
        print(f"{set_name}: x {x_0:.4f}-{x_100:.4f}, y {y_0:.4f}-{y_100:.4f}")
    Path(args.out).write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
