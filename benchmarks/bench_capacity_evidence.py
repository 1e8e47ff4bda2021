"""Which evidence separates a PyBaMM cell's capacity from its dynamics (issue 29, Chen2020).

Each flight of a PyBaMM set (``fixtures/pybamm``, default Chen2020) goes through the
self-calibrating filter from the chemistry prior (the product) and from variants that differ in
how the capacity is learned:

- ``product``: the capacity learns from a loaded voltage only while the pack is within
  ``CAPACITY_TEMP_SPAN_K`` of the temperature its count started at (and from rested voltages);
- ``every_loaded_sample``: the gate off (the span infinite): every loaded sample once 10 % is drawn;
- ``never``: the capacity never learns (the nominal, σ 25 %);
- ``true_capacity``: the cell's true window capacity with σ 2 % (what perfect evidence would give).

Per flight it also says what the other evidence would have said: the drain fit's capacity (the
loaded voltage's fall per charge against the curve's, ``_Drain``) at the flight's end, and whether
a second rest settled after charge was drawn (two rests with charge between). The capacity is the
learned one over the truth's, its range after the first 5 min.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_capacity_evidence.py [--set Chen2020]`` (≈ 20 s).
Prints one line per flight and variant, then ONE JSON object.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("product", "every_loaded_sample", "never", "true_capacity")


def main() -> None:
    from gcs_pdm.estimation import calibration
    from gcs_pdm.estimation.calibration import PackCalibrator, PackPrior
    from gcs_pdm.replay.calibration_eval import PYBAMM_CHEMISTRY, pybamm_flight_soc

    ap = argparse.ArgumentParser()
    ap.add_argument("--set", default="Chen2020")
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # each suspended voltage model warns once; the figures say it
    root = ROOT / "fixtures" / "pybamm"
    manifest = json.loads((root / "manifest.json").read_text())
    s = manifest["sets"][args.set]
    cells = 5
    nominal_c = s["cell_capacity_ah"] * s["cells_parallel"] * 3600.0
    true_c = s["cell_window_capacity_ah"] * s["cells_parallel"] * 3600.0
    base = PackPrior(PYBAMM_CHEMISTRY[args.set], cells, nominal_c)
    seen: list = []

    class Recorded(PackCalibrator):
        """The calibrator the flight ran, kept to read its capacity, drain fit and rests."""

        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.rests_after_draw = 0
            #: the learned capacity's range (over the truth) after the first 5 min of the flight
            self.capacity_range = [math.inf, -math.inf]
            seen.append(self)

        def step(self, t, dt, current, voltage, temperature_c) -> None:
            super().step(t, dt, current, voltage, temperature_c)
            if t >= 300.0:
                ratio = self.q0 / self.x[calibration.I_G] / true_c
                self.capacity_range = [min(self.capacity_range[0], ratio), max(self.capacity_range[1], ratio)]

        def _anchor(self) -> None:
            if self.initialised and self.drawn_c > 0.05 * self.q0 and math.isfinite(self.rest_since):
                self.rests_after_draw += 1
            super()._anchor()

    calibration.PackCalibrator = Recorded
    span = calibration.CAPACITY_TEMP_SPAN_K
    learn_after = calibration.LEARN_AFTER_FRACTION
    result: dict = {"set": args.set, "flights": []}
    try:
        for flight in [f for f in manifest["flights"] if f["set"] == args.set]:
            row = {"flight": flight["flight"]}
            for name in VARIANTS:
                calibration.CAPACITY_TEMP_SPAN_K = math.inf if name == "every_loaded_sample" else span
                calibration.LEARN_AFTER_FRACTION = math.inf if name == "never" else learn_after
                prior = replace(base, capacity_c=true_c, capacity_rel_sd=0.02) if name == "true_capacity" else base
                track, _ = pybamm_flight_soc(root, flight, manifest["sets"], prior=prior, cells=cells)
                cal = seen[-1]
                row[name] = {"max_abs_error_after_5min": track.summary(300.0)["max_abs_error"],
                             "capacity_over_truth_after_5min": [round(c, 3) for c in cal.capacity_range]}
                if name == "product":
                    c, se = cal.drain.slope()
                    frac, s0 = cal.drawn_c / cal.q0, cal.count_start
                    expected = cells * (cal.chem.ocv(s0) - cal.chem.ocv(s0 - frac)) / frac if frac > 0 else math.nan
                    drain_g = -c / expected if math.isfinite(c) and expected > 0 else math.nan
                    row["drain_fit_capacity_over_truth"] = (round(nominal_c / drain_g / true_c, 3)
                                                            if drain_g > 0 else None)
                    row["second_settled_rest"] = cal.rests_after_draw > 0
                    temp = track_temperature(root, flight)
                    row["temperature_c"] = [round(float(np.nanmin(temp)), 1), round(float(np.nanmax(temp)), 1)]
            result["flights"].append(row)
            print(f"{row['flight']} {row['temperature_c'][0]}->{row['temperature_c'][1]} °C: "
                  + ", ".join(f"{n} {row[n]['max_abs_error_after_5min']} (C {row[n]['capacity_over_truth_after_5min'][0]}-{row[n]['capacity_over_truth_after_5min'][1]}x)"
                              for n in VARIANTS)
                  + f"; drain fit C {row['drain_fit_capacity_over_truth']}x, second rest {row['second_settled_rest']}")
    finally:
        calibration.PackCalibrator = PackCalibrator
        calibration.CAPACITY_TEMP_SPAN_K, calibration.LEARN_AFTER_FRACTION = span, learn_after
    for name in VARIANTS:
        errors = [r[name]["max_abs_error_after_5min"] for r in result["flights"]]
        result[name] = {"within_0.05_after_5min": f"{sum(e <= 0.05 for e in errors)}/{len(errors)}",
                        "worst": max(errors), "median": round(float(np.median(errors)), 4)}
        print(f"{name}: within 0.05 after 5 min {result[name]['within_0.05_after_5min']}, worst {result[name]['worst']}")
    print(json.dumps(result))


def track_temperature(root: Path, flight: dict) -> np.ndarray:
    import pyarrow.parquet as pq

    return np.asarray(pq.read_table(root / flight["file"], columns=["temperature_c"]).to_pydict()["temperature_c"],
                      dtype=float)


if __name__ == "__main__":
    main()
