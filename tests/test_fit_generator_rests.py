"""The PyBaMM generator's experiment options (scripts/generate_pybamm_flights.py, off by default): where
the training flights' rests go and what a profile with rests looks like. Pure numpy: PyBaMM is not needed."""
import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "generate_pybamm_flights.py"
spec = importlib.util.spec_from_file_location("generate_pybamm_flights", SCRIPT)
gen = importlib.util.module_from_spec(spec)
spec.loader.exec_module(gen)


def plan(name, soc0, c_rate=1.5, seed=0):
    rng = np.random.default_rng(seed)
    current = gen.flight_profile(rng, c_rate, 1800, 2.2)
    return {"name": name, "current": current, "soc0": soc0, "samples": current.size}


def test_rests_are_inserted_and_the_loaded_part_is_the_plain_flights():
    p = plan("a", 0.9)
    at = [400, 900]
    out = gen.with_rests(p["current"], at, 300)
    assert out.size == p["current"].size + 600
    assert np.all(out[400:700] == 0) and np.all(out[1200:1500] == 0)
    # without the rests, sample for sample the plain profile: the charge count up to each rest is unchanged
    kept = np.concatenate([out[:400], out[700:1200], out[1500:]])
    np.testing.assert_array_equal(kept, p["current"])


def test_rests_go_where_the_planned_charge_count_reaches_targets_spread_over_the_range():
    plans = [plan(f"f{k}", soc0, seed=k) for k, soc0 in enumerate((0.99, 0.95, 0.9, 0.85))]
    at = gen.plan_rests(plans, 2, 300, (0.6, 0.9))
    placed = sorted(float(gen.planned_soc(p["current"], p["soc0"])[k]) for p in plans for k in at[p["name"]])
    targets = np.linspace(0.6, 0.9, 8)
    # every target some flight passes in its cruise is placed, within one sample's charge of it
    assert len(placed) == 8 and all(np.min(np.abs(targets - s)) < 0.002 for s in placed)
    assert len(set(np.round(placed, 3))) == len(placed)
    for p in plans:
        a, _ = gen.cruise_span(p["current"])
        assert len(at[p["name"]]) <= 2 and all(k > a for k in at[p["name"]])  # after take-off, at most 2 each
