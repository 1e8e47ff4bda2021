"""Learn a whole ParameterSet (four packs and the motors) from synthetic flights of a known vehicle.

Used to produce ``fixtures/params/learned_sim.json`` while no recorded flights of the simulated
vehicle exist: flights are flown with the simulated vehicle's hidden truth
(``gcs_pdm.sim.truth.true_parameters``), damaged as real logs are, split 8 / 2 / 2, and every pack
and the motor pair go through the full procedure. The provenance says all of this.
"""
from __future__ import annotations

from typing import Callable

from gcs_pdm.fitting.procedure import FitResult, FitSettings, fit_battery, fit_motor, merge_results
from gcs_pdm.fitting.synthetic import generate_flights
from gcs_pdm.models.params import PACK_NAMES, ParameterSet, builtin


def learn_from_synthetic(truth: ParameterSet, *, flights: int = 12, seed: int = 1, settings: FitSettings = FitSettings(model="paper"),
                         name: str = "learned_sim", progress: Callable[[float, str], None] | None = None,
                         ) -> tuple[ParameterSet, dict[str, FitResult]]:
    """(merged learned set over ``settings.base``, fit result per pack and ``"motor"``).

    The simulated vehicle's truth is a paper-variant set, so the default settings fit the paper
    variant (the learned set then drops into the planner and simulator unchanged)."""
    if flights < 3:
        raise ValueError("need at least 3 flights (train, validation, test)")
    syn = generate_flights(truth, flights, seed=seed)
    n_val = n_test = max(1, flights // 6)
    n_train = flights - n_val - n_test
    results: dict[str, FitResult] = {}
    parts = PACK_NAMES + ("motor",)
    for j, pack in enumerate(parts):
        def prog(f, stage, j=j, pack=pack):
            if progress is not None:
                progress((j + f) / len(parts), f"{pack}: {stage}")
        logs = [s.motor if pack == "motor" else s.packs[pack] for s in syn]
        split = (logs[:n_train], logs[n_train:n_train + n_val], logs[n_train + n_val:])
        if pack == "motor":
            results[pack] = fit_motor(*split, settings, progress=prog)
        else:
            results[pack] = fit_battery(*split, settings, pack=pack, progress=prog)
    merged = merge_results(
        builtin(settings.base), {p: results[p] for p in PACK_NAMES}, results["motor"], name=name,
        description=f"learned by gcs-pdm fit from {flights} synthetic flights of '{truth.name}' "
                    f"({n_train}/{n_val}/{n_test} train/validation/test)",
        provenance={"source": "synthetic flights (no recorded flights in fixtures/flights yet)",
                    "truth": truth.name, "flights": flights, "flight_seed": seed,
                    "generator": "gcs_pdm.fitting.synthetic.generate_flights (noise + default damage)"})
    return merged, results
