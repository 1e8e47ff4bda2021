"""The fit procedure on the extended variant: result, merged set, CLI default, flights without temperature."""
import json
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.cli import main
from gcs_pdm.fitting.logs import read_table, write_table
from gcs_pdm.fitting.procedure import FitSettings, fit_battery, merge_results
from gcs_pdm.fitting.search import SearchSettings
from gcs_pdm.models import kernel
from gcs_pdm.models.params import ParameterSet, builtin

ROOT = Path(__file__).resolve().parents[1] / "fixtures" / "pybamm"
TINY = SearchSettings(starts=2, sa_generations=6, lm_max_nfev=6, seed=2)
SMALL_EXT = FitSettings(model="extended", extended_search=TINY, extended_thermal_generations=4)
FLIGHTS = ("chen2020_02", "chen2020_12", "chen2020_04")  # train, validation, test


def flights():
    return [read_table(ROOT / "Chen2020" / f"{n}.parquet", "battery", n) for n in FLIGHTS]


@pytest.fixture(scope="module")
def fit():
    tr, va, te = flights()
    return fit_battery([tr], [va], [te], SMALL_EXT, pack="URA40")


def test_default_of_new_fits_is_the_extended_variant_and_the_result_names_it(fit):
    from gcs_pdm.fitting import cli, procedure

    assert procedure.DEFAULT_MODEL == cli.DEFAULT_MODEL == "extended"
    d = json.loads(json.dumps(fit.to_dict(), allow_nan=False))
    assert d["model"] == "extended" and d["thermal"]["fitted"] is True
    assert set(d["parameters"]) == set(kernel.EXT_PACK_PARAMS)
    assert {"ocv_0", "docv_12", "R_0", "E_r", "C_t", "h", "dU_dT"} <= set(d["learned"])
    assert [s["stage"] for s in d["stages"]] == ["electrical", "thermal"]
    assert 0.0 < d["initial_soc"]["chen2020_04"] < 1.2
    # a fit is better than the chemistry default it started from
    assert d["errors"]["learned"]["train"]["overall"]["voltage"]["rmse"] < 0.3


def test_merged_set_keeps_paper_values_and_round_trips(fit):
    ps = merge_results(builtin("previous_si"), {"URA40": fit}, name="learned_ext")
    pack = ps.packs["URA40"]
    assert pack.model == "extended"
    assert pack.battery == builtin("previous_si").packs["URA40"].battery  # the powertrain's paper circuit
    np.testing.assert_array_equal(pack.extended_vector(), [fit.parameters[k] for k in kernel.EXT_PACK_PARAMS])
    assert ParameterSet.from_json(ps.to_json()) == ps
    # the learned OCV is monotone, as every vector inside the bounds is
    v = kernel.open_circuit_voltage(pack.extended_vector(), np.linspace(0, 1, 501))
    assert np.all(np.diff(v) > 0)


def test_flights_without_temperature_fit_the_circuit_and_say_why_not_the_heat():
    no_t = [f.with_columns(temperature_c=np.full(len(f), np.nan)) for f in flights()]
    res = fit_battery([no_t[0]], [no_t[1]], [no_t[2]], SMALL_EXT)
    assert res.thermal["fitted"] is False and "no pack temperature" in res.thermal["reason"]
    assert [s.name for s in res.stages] == ["electrical"]
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["errors"]["learned"]["test"]["overall"]["temperature"]["rmse"] is None
    assert d["errors"]["learned"]["test"]["overall"]["voltage"]["rmse"] < 0.5


def test_cli_fits_a_table_without_a_temperature_column_and_takes_model_paper(tmp_path):
    tr, va, te = flights()
    paths = []
    for f in (tr, va, te):
        p = write_table(f, tmp_path / f"{f.name}.csv")
        text = p.read_text().splitlines()
        cols = text[0].split(",")
        k = cols.index("temperature_c")
        p.write_text("\n".join(",".join(c for i, c in enumerate(line.split(",")) if i != k) for line in text) + "\n")
        paths.append(p)
    budget = ["--starts", "2", "--sa-generations", "4", "--lm-max-nfev", "4", "--quiet", "--no-plots"]
    rc = main(["fit", "battery", "--train", str(paths[0]), "--val", str(paths[1]), "--test", str(paths[2]),
               "--out", str(tmp_path / "ext"), *budget])
    assert rc == 0
    d = json.loads((tmp_path / "ext" / "result.json").read_text())
    assert d["model"] == "extended" and d["thermal"]["fitted"] is False
    rc = main(["fit", "battery", "--train", str(paths[0]), "--val", str(paths[1]), "--test", str(paths[2]),
               "--out", str(tmp_path / "paper"), "--model", "paper", *budget])
    assert rc == 0
    d = json.loads((tmp_path / "paper" / "result.json").read_text())
    assert d["model"] == "paper" and set(d["parameters"]) == set(kernel.PACK_PARAMS)


def test_library_default_is_the_extended_variant():
    assert FitSettings().model == "extended"
    assert FitSettings(model="paper").search_for("electrical") == FitSettings().search


def test_ocv_smoothness_prior_is_zero_on_a_straight_curve_and_grows_with_a_kink():
    from gcs_pdm.fitting import problem as pb
    from gcs_pdm.fitting.cleaning import clean_flights
    from gcs_pdm.models.params import extended_default

    fl, _, _ = clean_flights(flights()[:1])
    base = np.array(list(extended_default("li-ion").values()))
    plain = pb.ExtendedPackProblem(fl, base, pb.EXTENDED_ELECTRICAL_BOUNDS, "voltage")
    prior = pb.ExtendedPackProblem(fl, base, pb.EXTENDED_ELECTRICAL_BOUNDS, "voltage", ocv_smoothing=0.04)
    assert prior.n_residuals == plain.n_residuals + kernel.N_OCV_KNOTS - 2
    names = prior.space.names
    values = np.array([base[kernel.EXT_PACK_PARAMS.index(n)] for n in names])
    widths = np.diff(kernel.EXT_OCV_SOC)
    for k in range(1, kernel.N_OCV_KNOTS):
        values[names.index(f"docv_{k}")] = 4.0 * widths[k - 1]      # a straight line, 4 V per unit SoC
    straight = prior.residuals(prior.space.to_unit(values)[None])[0]
    np.testing.assert_allclose(straight[:plain.n_residuals], plain.residuals(plain.space.to_unit(values)[None])[0])
    np.testing.assert_allclose(straight[plain.n_residuals:], 0.0, atol=1e-9)
    kinked = values.copy()
    kinked[names.index("docv_20")] *= 3.0                              # a step the data did not ask for
    rows = prior.residuals(prior.space.to_unit(kinked)[None])[0][plain.n_residuals:]
    assert np.count_nonzero(np.abs(rows) > 1e-6) == 2 and np.abs(rows).max() == pytest.approx(0.04 * 8.0)


@pytest.mark.parametrize("smoothing", [0.0, 0.04])
def test_ocv_knot_jacobian_matches_one_simulation_per_knot(smoothing):
    """ExtendedPackProblem.ocv_jacobian (two simulations per flight) against plain forward differences
    (one shifted vector per knot), away from the base point so the initial SoC and the curve both move."""
    from gcs_pdm.fitting import problem as pb
    from gcs_pdm.fitting.cleaning import clean_flights
    from gcs_pdm.models.params import extended_default

    fl, _, _ = clean_flights(flights()[:2])
    base = np.array(list(extended_default("li-ion").values()))
    prob = pb.ExtendedPackProblem(fl, base, pb.EXTENDED_ELECTRICAL_BOUNDS, "voltage", ocv_smoothing=smoothing)
    cols = prob.ocv_columns
    assert [prob.space.names[c] for c in cols] == ["ocv_0"] + [f"docv_{k}" for k in range(1, kernel.N_OCV_KNOTS)]
    start = prob.space.to_unit(np.array([base[kernel.EXT_PACK_PARAMS.index(n)] for n in prob.space.names]))
    u = np.clip(start + 0.03 * np.random.default_rng(4).standard_normal(start.size), 0.02, 0.98)
    r0, J = prob.ocv_jacobian(u)
    h = 1e-6
    U = np.tile(u, (cols.size + 1, 1))
    U[np.arange(cols.size), cols] += h
    R = prob.residuals(U, parallel=False)
    np.testing.assert_array_equal(r0, R[-1])
    J_fd = ((R[:-1] - R[-1]) / h).T
    scale = np.abs(J_fd).max(axis=0)
    # every knot below the flights' starts moves some sample (those above it move none: exactly 0 both ways)
    assert np.count_nonzero(scale > 0.1) >= cols.size - 4
    assert np.all(np.abs(J - J_fd).max(axis=0) <= 1e-3 * np.maximum(scale, 1.0))
    # a temperature problem has no knot columns (the curve does not enter the heat)
    assert pb.ExtendedPackProblem(fl, base, pb.EXTENDED_THERMAL_BOUNDS, "temperature").ocv_columns.size == 0


def test_extended_kernel_records_its_states():
    from gcs_pdm.models.params import extended_default

    p = np.array(list(extended_default("lipo").values()))
    n = 300
    current = np.where(np.arange(n) < 50, 0.0, 20.0)
    x0 = kernel.initial_extended_state(p, 0.9, 20.0)
    plain = kernel.simulate_packs(p, x0, np.ones(n), current, 20.0, variant="extended")
    rec = kernel.simulate_packs(p, x0, np.ones(n), current, 20.0, variant="extended", record_states=True)
    assert plain.states is None and rec.states.shape == (1, n, kernel.N_EXT_STATE)
    np.testing.assert_array_equal(rec.voltage, plain.voltage)
    np.testing.assert_array_equal(rec.states[0, :, kernel.X_SOC], plain.soc[0])
    np.testing.assert_array_equal(rec.states[0, :, kernel.X_T], plain.temperature[0])
    np.testing.assert_array_equal(rec.states[0, -1], plain.final_state[0])
    # the terminal voltage is the OCV at the recorded surface SoC minus the drops
    surface = rec.states[0, :, kernel.X_SOC] - rec.states[0, :, kernel.X_SD]
    assert np.all(kernel.open_circuit_voltage(p, surface) >= rec.voltage[0] - 1e-9)


def test_validation_chooses_only_among_candidates_that_fit_the_training_flights():
    from gcs_pdm.fitting.procedure import _choose

    train = np.array([30.0, 33.0, 53.0, 106.0]) ** 2 * 1e-6   # the last two: LM stopped in poor minima
    val = np.array([140.0, 211.0, 137.0, 163.0]) ** 2 * 1e-6  # one of them has the lowest validation error
    assert _choose(train, val, 1.5) == 0
    assert _choose(train, val, 0.0) == 2                        # 0: the plain validation choice (paper variant)
    assert _choose(train, val, 2.0) == 2
    assert FitSettings().extended_train_tolerance == 1.5


def test_the_fit_applies_the_training_tolerance_to_its_choice(fit):
    cands = fit.stages[0].candidates
    chosen = cands[fit.stages[0].chosen]
    screened = [c for c in cands if not c.polished]
    start = next(c for c in screened if c.start == chosen.start)
    best_train = min(c.lm_rmse for c in screened)
    fits = [c for c in screened if c.lm_rmse <= 1.5 * best_train]
    assert start in fits and start.val_rmse == min(c.val_rmse for c in fits)
