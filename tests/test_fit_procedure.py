"""The fit as an API and a command: serialisation, outputs, reproducibility, progress, cancellation,
merging, the search pieces, and the CLI on CSV files."""
import json

import numpy as np
import pandas as pd
import pytest

from gcs_pdm.cli import main
from gcs_pdm.fitting.errors import error_stats
from gcs_pdm.fitting.logs import write_outputs, write_table
from gcs_pdm.fitting.problem import initial_soc
from gcs_pdm.fitting.procedure import FitSettings, fit_battery, merge_results
from gcs_pdm.fitting.search import FitCancelled, SearchSettings, anneal, levenberg_marquardt
from gcs_pdm.fitting.synthetic import NO_DAMAGE, generate_flights, synthetic_truth
from gcs_pdm.models import kernel
from gcs_pdm.models.params import ParameterSet, builtin

SMALL = FitSettings(search=SearchSettings(starts=3, sa_generations=20, lm_max_nfev=8, seed=5), model="paper")


@pytest.fixture(scope="module")
def flights():
    return generate_flights(synthetic_truth(seed=4), 4, seed=300, duration_s=900.0)


@pytest.fixture(scope="module")
def fit(flights):
    fl = [f.packs["ULA20"] for f in flights]
    return fit_battery(fl[:2], fl[2:3], fl[3:], SMALL, pack="ULA20")


def test_result_json_round_trip_and_fields(fit):
    d = json.loads(json.dumps(fit.to_dict(), allow_nan=False))  # strict JSON
    assert d["component"] == "battery" and d["pack"] == "ULA20"
    assert set(d["learned"]) == {"R_s", "R_p", "R_cp0", "R_cp1", "R_cp2", "C_s", "C_b", "C_cp", "C_t", "h"}
    for which in ("learned", "reference"):
        for split in ("train", "validation", "test"):
            o = d["errors"][which][split]["overall"]
            assert {"rmse", "mae", "max"} <= set(o["voltage"])
            assert o["temperature"]["rmse_f"] == pytest.approx(1.8 * o["temperature"]["rmse"])
    assert [s["stage"] for s in d["stages"]] == ["electrical", "thermal"]
    assert d["provenance"]["seed"] == 5 and d["provenance"]["seconds"] > 0
    assert len(d["cleaning"]) == 4


def test_predictions_csv_recompute_the_errors(fit, tmp_path):
    written = write_outputs(fit, tmp_path, plots=True)
    assert (tmp_path / "result.json").is_file()
    test_name = fit.flights["test"][0]
    df = pd.read_csv(tmp_path / "predictions" / f"{test_name}.csv")
    e = error_stats(df["predicted_voltage_v"].to_numpy(), df["measured_voltage_v"].to_numpy())
    assert e["rmse"] == pytest.approx(fit.errors["learned"]["test"]["flights"][0]["voltage"]["rmse"])
    png = written[f"plots/{test_name}"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_reproducible_with_seed_and_progress_monotone(flights, fit):
    fl = [f.packs["ULA20"] for f in flights]
    seen = []
    again = fit_battery(fl[:2], fl[2:3], fl[3:], SMALL, pack="ULA20", progress=lambda f, s: seen.append(f))
    assert again.parameters == fit.parameters
    assert seen[0] == 0.0 and seen[-1] == 1.0 and all(b >= a for a, b in zip(seen, seen[1:]))


def test_should_stop_cancels(flights):
    fl = [f.packs["ULA20"] for f in flights]
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 3

    with pytest.raises(FitCancelled):
        fit_battery(fl[:2], fl[2:3], fl[3:], SMALL, pack="ULA20", should_stop=stop)


def test_merge_results_gives_parameter_set_with_provenance(fit):
    ps = merge_results(builtin("previous_si"), {"ULA20": fit}, name="learned_test")
    assert ps.packs["ULA20"] == fit.pack_params
    assert ps.packs["LLF20"] == builtin("previous_si").packs["LLF20"]
    assert ps.provenance["packs"]["ULA20"]["flights"] == fit.flights
    assert ParameterSet.from_json(ps.to_json()).packs["ULA20"] == fit.pack_params
    with pytest.raises(ValueError, match="unknown pack"):
        merge_results(builtin("previous_si"), {"XYZ": fit})


def test_anneal_finds_a_batched_quadratic_minimum():
    target = np.array([0.2, 0.7, 0.9])
    res = anneal(lambda U: np.sum((U - target) ** 2, axis=1) + 1e-6, 3, SearchSettings(starts=4, sa_generations=150),
                 np.random.default_rng(0))
    best = res.best_u[np.argmin(res.best_mse)]
    np.testing.assert_allclose(best, target, atol=0.03)
    assert res.evaluations == 4 + 4 * 4 * 150


def test_levenberg_marquardt_fits_an_exponential():
    t = np.linspace(0, 5, 50)
    y = 0.3 + 0.5 * np.exp(-t / (0.2 + 2 * 0.6))

    def residuals(U):
        return 0.3 + U[:, [0]] * np.exp(-t / (0.2 + 2 * U[:, [1]])) - y

    r = levenberg_marquardt(residuals, np.array([0.2, 0.2]), SearchSettings(lm_max_nfev=100))
    np.testing.assert_allclose(r.u, [0.5, 0.6], atol=1e-5)


def test_initial_soc_inverts_the_model():
    P = builtin("paper_si").pack_matrix()
    socs = np.array([0.95, 0.6, 0.3, 0.08])
    x0 = kernel.initial_pack_state(P, socs, 20.0, 12.0)
    v = kernel.terminal_voltage(P, x0)
    got = np.array([initial_soc(P[i:i + 1], v[i], 12.0)[0] for i in range(4)])
    # the parasitic current is part of i_b, so inverting at the terminal current is exact to ~1e-4
    np.testing.assert_allclose(got, socs, atol=2e-3)


def test_cli_fits_csv_flights_and_rejects_bad_input(tmp_path, capsys):
    fl = generate_flights(synthetic_truth(seed=4), 3, seed=400, duration_s=900.0, damage=NO_DAMAGE)
    paths = [write_table(f.motor, tmp_path / f"{f.name}_motor.csv") for f in fl]
    out = tmp_path / "out"
    rc = main(["fit", "motor", "--train", str(paths[0]), "--val", str(paths[1]), "--test", str(paths[2]),
               "--out", str(out), "--starts", "2", "--sa-generations", "10", "--lm-max-nfev", "5", "--quiet"])
    assert rc == 0
    d = json.loads((out / "result.json").read_text())
    assert d["component"] == "motor" and set(d["learned"]) == {"C_t", "h", "P_iron"}
    assert (out / "predictions" / f"{fl[2].name}_motor.csv").is_file()
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,current_a\n0,1\n")
    rc = main(["fit", "motor", "--train", str(bad), "--val", str(paths[1]), "--test", str(paths[2]),
               "--out", str(out), "--quiet"])
    assert rc == 2
    assert "missing required column" in capsys.readouterr().err


def test_block_separable_jacobian_equals_the_full_one():
    """Per-block unknowns shifted together give the same Jacobian as one column each."""
    from gcs_pdm.fitting import search

    t = np.linspace(0, 1, 6)
    blocks = [slice(0, 6), slice(6, 12), slice(12, 18)]

    def residuals(U):  # 2 shared unknowns, 3 per-block offsets
        out = []
        for b in range(3):
            out.append(U[:, [0]] * np.exp(-t * U[:, [1]]) + U[:, [2 + b]] * (b + 1) - 0.1 * b)
        return np.concatenate(out, axis=1)

    u0 = np.array([0.3, 0.6, 0.2, 0.5, 0.7])
    seen = {}
    orig = search.least_squares

    def spy(fun, x0, jac, **kw):
        seen["sep"] = jac(x0)
        return orig(fun, x0, jac=jac, **kw)

    search.least_squares = spy
    try:
        r = levenberg_marquardt(residuals, u0, SearchSettings(lm_max_nfev=50), shared=2, blocks=blocks)
        J_sep = seen["sep"]
        levenberg_marquardt(residuals, u0, SearchSettings(lm_max_nfev=50))
        J_full = seen["sep"]
    finally:
        search.least_squares = orig
    np.testing.assert_allclose(J_sep, J_full, atol=1e-6)
    assert J_sep[0:6, 3].max() == 0.0  # block 0's rows do not depend on block 1's unknown
    assert r.mse < 1e-12


def test_canonical_relabels_the_slow_pair_and_keeps_the_voltage():
    """Swapping (R_s, C_s) with (R_cp0, C_cp) leaves the plateau voltage unchanged; canonical() puts
    the fast pair first."""
    from gcs_pdm.fitting.problem import BATTERY_ELECTRICAL_BOUNDS, PackProblem

    fl = generate_flights(synthetic_truth(seed=4), 1, seed=500, duration_s=900.0, damage=NO_DAMAGE)[0].packs["LLF20"]
    prob = PackProblem([fl], builtin("paper_si").pack_matrix()[0], BATTERY_ELECTRICAL_BOUNDS, "voltage")
    names = prob.space.names
    v = np.array([builtin("paper_si").pack_matrix()[0][kernel.PACK_PARAMS.index(n)] for n in names])
    slow = v.copy()
    for a, b in (("R_s", "R_cp0"), ("C_s", "C_cp")):
        slow[names.index(a)], slow[names.index(b)] = v[names.index(b)], v[names.index(a)]
    u_fast, u_slow = prob.space.to_unit(v), prob.space.to_unit(slow)
    assert prob.canonical(u_fast) is None
    np.testing.assert_allclose(prob.canonical(u_slow), u_fast, atol=1e-12)
    r_fast, r_slow = prob.residuals(np.array([u_fast, u_slow]))
    assert np.sqrt(np.mean((r_fast - r_slow) ** 2)) < 2e-3  # the same circuit on the plateau


def test_levenberg_marquardt_uses_a_problem_s_own_jacobian_columns():
    """``partial``: the columns a problem differentiates itself replace their forward differences (the
    extended variant's OCV knots), and ``levenberg_marquardt_subset`` fits those coordinates alone."""
    from gcs_pdm.fitting.search import levenberg_marquardt_subset

    t = np.linspace(0.0, 3.0, 40)
    truth = np.array([0.3, 0.6, 0.7])
    calls = []

    def model(u):  # linear in u[1], u[2]; nonlinear in u[0]
        return u[..., 1:2] * np.exp(-3.0 * u[..., 0:1] * t) + u[..., 2:3]

    def residuals(U):
        calls.append(U.shape[0])
        return model(U) - model(truth)

    def own(u):
        return residuals(u[None])[0], np.stack([np.exp(-3.0 * u[0] * t), np.ones_like(t)], axis=1)

    r = levenberg_marquardt(residuals, np.array([0.5, 0.2, 0.2]), SearchSettings(lm_max_nfev=100),
                            partial=(np.array([1, 2]), own))
    np.testing.assert_allclose(r.u, truth, atol=1e-5)
    # the Jacobians shifted one vector each (column 0), never three
    assert max(calls) == 1
    calls.clear()
    sub = levenberg_marquardt_subset(residuals, np.array([0.3, 0.2, 0.2]), np.array([1, 2]),
                                     SearchSettings(lm_max_nfev=50), partial=lambda u: own(u))
    np.testing.assert_allclose(sub.u, truth, atol=1e-6)
    assert sub.u[0] == 0.3 and max(calls) == 1
