"""`gcs-pdm fit battery --vehicle`: a described vehicle's own packs fitted (any cells and capacity),
a parameter set of its packs, and the description pointing at it (docs/vehicles.md, docs/fitting.md)."""
import json
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.cli import main
from gcs_pdm.fitting import problem as pb
from gcs_pdm.fitting.procedure import FitSettings, evaluate_battery
from gcs_pdm.fitting.search import SearchSettings
from gcs_pdm.logs.tables import BATTERY, flight_from_columns
from gcs_pdm.models import kernel
from gcs_pdm.models.chemistry import CHEMISTRIES
from gcs_pdm.models.params import ParameterError, ParameterSet
from gcs_pdm.vehicle.description import from_dict, load
from gcs_pdm.fitting.vehicle import base_set, extended_start, fit_packs, ocv_knots_per_cell, pack_format
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.sim.pack_curves import chemistry_curve_pack
from gcs_pdm.vehicle.presets import PRESETS

LOGS = Path(__file__).resolve().parents[1] / ".." / "shared" / "logs"
TLOG = LOGS / "arduplane_sitl_stock.tlog"
SMALL = FitSettings(search=SearchSettings(starts=3, sa_generations=25, lm_max_nfev=12, seed=2), model="paper")
NOISE_V = 0.01


def test_bounds_follow_the_pack():
    paper = pb.battery_bounds("paper")
    assert paper.electrical == pb.BATTERY_ELECTRICAL_BOUNDS and paper.thermal == pb.BATTERY_THERMAL_BOUNDS
    ext = pb.battery_bounds("extended")
    assert ext.electrical == pb.EXTENDED_ELECTRICAL_BOUNDS and ext.annealing == pb.EXTENDED_RC_BOUNDS
    small = pb.PackFormat(cells=3, capacity_c=2200 * 3.6)
    k_r = (3 / 5) * (7800 / 2200)
    by = {b.name: b for b in pb.battery_bounds("paper", small).electrical}
    ref = {b.name: b for b in pb.BATTERY_ELECTRICAL_BOUNDS}
    assert by["R_s"].lo == pytest.approx(ref["R_s"].lo * k_r) and by["C_b"].hi == pytest.approx(ref["C_b"].hi / k_r)
    assert by["R_cp2"] == ref["R_cp2"]                      # an exponent in SoC: unchanged
    eby = {b.name: b for b in pb.battery_bounds("extended", small).electrical}
    eref = {b.name: b for b in pb.EXTENDED_ELECTRICAL_BOUNDS}
    assert eby["ocv_0"].lo == pytest.approx(eref["ocv_0"].lo * 3 / 5)      # voltages with the cells
    assert eby["C_max"].hi == pytest.approx(eref["C_max"].hi * 2200 / 7800)  # charge with the capacity
    assert eby["tau_2"] == eref["tau_2"]


def test_bounds_are_the_cells_times_the_chemistrys_per_cell_ranges():
    """fit --vehicle's ranges: a LiPo pack's are the 5S ones carried by cells and capacity alone; a
    Li-ion or LiFePO4 pack's empty-pack OCV sits at its cells' empty voltage and its OCV span (full -
    empty) sets how far a charge moves the OCV (C_b inversely, the knots' rises)."""
    def bounds(chemistry: str, model: str) -> dict:
        data = _vehicle(3, 3000.0)
        data["packs"][0]["chemistry"] = chemistry
        fmt = pack_format(from_dict(data).packs[0])
        return {b.name: b for b in pb.battery_bounds(model, fmt).electrical}

    lipo_fmt = pb.PackFormat(cells=3, capacity_c=3000 * 3.6)
    for model in ("paper", "extended"):
        assert bounds("lipo", model) == {b.name: b for b in pb.battery_bounds(model, lipo_fmt).electrical}
    lipo = bounds("lipo", "extended")
    for chemistry, (empty, full) in (("liion", (3.0, 4.18)), ("lifepo4", (2.5, 3.45))):
        ext, paper = bounds(chemistry, "extended"), bounds(chemistry, "paper")
        span = (full - empty) / (4.2 - 3.27)
        # the empty pack's OCV range moved by 3 cells x (empty - a LiPo's 3.27 V) and holds 3 x empty
        assert ext["ocv_0"].lo == pytest.approx(lipo["ocv_0"].lo + 3 * (empty - 3.27))
        assert ext["ocv_0"].lo < 3 * empty < ext["ocv_0"].hi
        assert ext["docv_5"].hi == pytest.approx(lipo["docv_5"].hi * span)
        assert paper["C_b"].lo == pytest.approx(bounds("lipo", "paper")["C_b"].lo / span)
        assert paper["R_s"] == bounds("lipo", "paper")["R_s"]  # resistances: cells and capacity only
        assert "not a LiPo's" in paper["C_b"].why


def _vehicle(cells: int, capacity_mah: float) -> dict:
    data = PRESETS["plane-3s"].to_dict()
    data["name"] = f"test-{cells}s"
    data["packs"][0].update(cells_series=cells, capacity_mah=capacity_mah, reports_temperature=True)
    data["packs"][0].pop("full_cell_voltage")
    return data


def _synthetic_flights(truth: np.ndarray, capacity_c: float, n: int, seed: int, variant: str = "paper") -> list:
    """Flights of one pack simulated by the kernel (``variant``'s vector): rest, climb, cruise legs at
    0.5-2.5C, rest; noise."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        c_rate = capacity_c / 3600.0
        legs = [(60, 0.02)] + [(rng.uniform(60, 240), rng.uniform(0.5, 2.5)) for _ in range(6)] + [(60, 0.02)]
        current = np.concatenate([np.full(int(d), c * c_rate) for d, c in legs])
        t = np.arange(current.size, dtype=float)
        dt = np.diff(t, prepend=t[0])
        soc0 = rng.uniform(0.85, 1.0)
        settle = kernel.initial_extended_state if variant == "extended" else kernel.initial_pack_state
        x0 = settle(truth[None], soc0, 20.0, current[0])
        tr = kernel.simulate_packs(truth[None], x0, dt, current, np.full(t.size, 20.0), variant=variant)
        out.append(flight_from_columns(f"f{seed}_{k}", BATTERY, {
            "time_s": t, "current_a": current, "voltage_v": tr.voltage[0] + rng.normal(0, NOISE_V, t.size),
            "temperature_c": tr.temperature[0] + rng.normal(0, 0.1, t.size), "ambient_c": np.full(t.size, 20.0)}))
    return out


@pytest.mark.parametrize("cells,capacity_mah", [(3, 2200.0), (6, 10000.0)])
def test_a_3s_and_a_6s_pack_are_fitted_and_the_voltage_recovered(cells, capacity_mah):
    desc = from_dict(_vehicle(cells, capacity_mah))
    start = model_inputs(desc).pack_matrix[0]
    rng = np.random.default_rng(cells)
    truth = start.copy()
    for i in (kernel.I_RS, kernel.I_RCP0, kernel.I_CS, kernel.I_CCP):
        truth[i] *= rng.uniform(0.75, 1.3)                  # a pack that is not the chemistry default
    truth[kernel.I_CB] *= 0.9
    truth[kernel.I_QMAX] = truth[kernel.I_CB] * desc.packs[0].full_voltage
    flights = {"train": _synthetic_flights(truth, desc.packs[0].capacity_c, 3, 10 + cells),
               "validation": _synthetic_flights(truth, desc.packs[0].capacity_c, 1, 20 + cells),
               "test": _synthetic_flights(truth, desc.packs[0].capacity_c, 1, 30 + cells)}
    merged, results = fit_packs(desc, lambda split, pack: flights[split], {k: k for k in flights}, SMALL)
    res = results["battery"]
    assert tuple(merged.packs) == ("battery",)
    learned = np.array([res.parameters[k] for k in kernel.PACK_PARAMS])
    # a full pack of this many cells: the fitted circuit's open-circuit voltage at full charge
    assert learned[kernel.I_QMAX] / learned[kernel.I_CB] == pytest.approx(desc.packs[0].full_voltage)
    assert learned[kernel.I_CMAX] == pytest.approx(desc.packs[0].capacity_c)
    test_rmse = res.errors["learned"]["test"]["overall"]["voltage"]["rmse"]
    truth_rmse = evaluate_battery(truth, flights["test"], SMALL)["overall"]["voltage"]["rmse"]
    start_rmse = evaluate_battery(start, flights["test"], SMALL)["overall"]["voltage"]["rmse"]
    assert test_rmse < 1.5 * truth_rmse + 0.005, (test_rmse, truth_rmse)
    assert test_rmse < 0.5 * start_rmse                    # better than the chemistry default it started from
    assert res.thermal["fitted"]


def test_parameter_sets_hold_any_packs_but_only_the_paper_layout_has_a_matrix():
    ps = base_set(PRESETS["quad-6s"], "paper")
    again = ParameterSet.from_json(ps.to_json())
    assert tuple(again.packs) == ("battery",) and again == ps
    with pytest.raises(ParameterError, match="four-pack layout"):
        again.pack_matrix()
    assert again.provenance["pack_formats"]["battery"]["cells_series"] == 6


def test_scale_to_pack_reads_the_fitted_packs_format(tmp_path):
    """A fitted 6S 10 Ah pack carried to a 3S 5 Ah one: resistances x (3/6)(10/5) = 1 from the set's own
    format, not from the paper's 5S 7.8 Ah."""
    ps = base_set(PRESETS["quad-6s"], "paper")
    path = tmp_path / "set.json"
    path.write_text(ps.to_json())
    data = PRESETS["quad-6s"].to_dict()
    data["packs"][0].update(cells_series=3, capacity_mah=5000.0,
                            parameters={"set": str(path), "pack": "battery", "scale_to_pack": True})
    small = model_inputs(from_dict(data)).pack_matrix[0]
    big = model_inputs(PRESETS["quad-6s"]).pack_matrix[0]
    assert small[kernel.I_RS] == pytest.approx(big[kernel.I_RS])
    assert small[kernel.I_CMAX] == pytest.approx(5000 * 3.6)


@pytest.mark.skipif(not TLOG.is_file(), reason="needs ../shared/logs (the stock ArduPlane SITL session)")
def test_fit_vehicle_on_the_stock_arduplane_log_closes_the_loop(tmp_path, capsys):
    out = tmp_path / "fit"
    code = main(["fit", "battery", "--vehicle", "plane-3s", "--model", "paper", "--train", str(TLOG),
                 "--val", str(TLOG), "--test", str(TLOG), "--out", str(out), "--no-plots", "--quiet",
                 "--starts", "3", "--sa-generations", "40", "--lm-max-nfev", "15"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["vehicle"] == "plane-3s" and summary["pack"] == "battery"
    result = json.loads((out / "result.json").read_text())
    rmse = result["errors"]["learned"]["train"]["overall"]["voltage"]["rmse"]
    assert rmse < 0.1 and rmse < 0.5 * result["errors"]["reference"]["train"]["overall"]["voltage"]["rmse"]
    # no pack temperature: the thermal values stay the chemistry default, and result.json says so
    assert not result["thermal"]["fitted"] and "chemistry default" in result["thermal"]["reason"]
    ps = ParameterSet.from_json((out / "parameters.json").read_text())
    p = ps.packs["battery"]
    assert tuple(ps.packs) == ("battery",)
    assert p.battery.q_max / p.battery.C_b == pytest.approx(3 * 4.35)      # a 3-cell pack at its full voltage
    start = model_inputs(PRESETS["plane-3s"]).pack_matrix[0]
    assert (p.thermal.C_t, p.thermal.h) == pytest.approx((start[kernel.I_CT], start[kernel.I_H]))
    # the description pointing at it checks and feeds the model the fitted circuit
    assert main(["vehicle", "check", str(out / "vehicle.toml")]) == 0
    desc = load(out / "vehicle.toml")
    assert desc.packs[0].parameters.set == str((out / "parameters.json").resolve())
    np.testing.assert_allclose(model_inputs(desc).pack_matrix[0][kernel.I_RS], p.battery.R_s)


def test_fit_vehicle_names_an_unknown_pack(tmp_path, capsys):
    code = main(["fit", "battery", "--vehicle", "plane-3s", "--pack", "LLF20", "--train", str(TLOG),
                 "--val", str(TLOG), "--test", str(TLOG), "--out", str(tmp_path), "--quiet"])
    assert code == 2 and "vehicle plane-3s has packs battery" in capsys.readouterr().err


@pytest.mark.skipif(not TLOG.is_file(), reason="needs ../shared/logs (the stock ArduPlane SITL session)")
def test_fit_motor_vehicle_says_why_sitl_motors_cannot_be_fitted(tmp_path, capsys):
    """Stock SITL's ESC temperature never changes: cleaning rejects it, and the fit says so."""
    code = main(["fit", "motor", "--vehicle", "plane-3s", "--train", str(TLOG), "--val", str(TLOG), "--test",
                 str(TLOG), "--out", str(tmp_path), "--quiet", "--no-plots"])
    assert code == 2 and "temperature_c missing" in capsys.readouterr().err


def test_a_motor_set_is_pointed_at_by_every_motor(tmp_path):
    from gcs_pdm.fitting.vehicle import write_fitted

    desc = PRESETS["quad-4s"]
    start = base_set(desc, "paper")
    set_path, desc_path = write_fitted(desc, start, (), tmp_path, motors=True)
    again = load(desc_path)
    assert {m.parameter_set for m in again.motors} == {str(set_path.resolve())}
    assert all(m.values is None for m in again.motors)
    np.testing.assert_allclose(model_inputs(again).motor_matrix, model_inputs(desc).motor_matrix[:1].repeat(4, 0))


def test_a_start_outside_the_charge_range_is_warned_about():
    from types import SimpleNamespace

    from gcs_pdm.fitting.vehicle import start_soc_warnings

    spec = PRESETS["plane-3s"].packs[0]
    res = SimpleNamespace(predictions=[SimpleNamespace(name="a", initial_soc=-0.27, split="test"),
                                       SimpleNamespace(name="b", initial_soc=0.6, split="train")])
    (w,) = start_soc_warnings(res, spec)
    assert w.startswith("a: starts at SoC -0.27 with full at 4.35 V/cell") and "full_cell_voltage" in w


@pytest.mark.skipif(not TLOG.is_file(), reason="needs ../shared/logs (the stock ArduPlane SITL session)")
def test_an_extended_fit_of_a_3s_pack_stays_in_its_scaled_ranges(tmp_path, capsys):
    out = tmp_path / "ext"
    assert main(["fit", "battery", "--vehicle", "plane-3s", "--model", "extended", "--train", str(TLOG),
                 "--val", str(TLOG), "--test", str(TLOG), "--out", str(out), "--no-plots", "--quiet",
                 "--starts", "2", "--sa-generations", "15", "--lm-max-nfev", "10"]) == 0
    assert "read the paper variant" in capsys.readouterr().err
    result = json.loads((out / "result.json").read_text())
    assert result["errors"]["learned"]["train"]["overall"]["voltage"]["rmse"] < 0.1
    bounds = result["stages"][0]["bounds"]
    ref = {b.name: b for b in pb.EXTENDED_ELECTRICAL_BOUNDS}
    assert bounds["ocv_0"][1] == pytest.approx(ref["ocv_0"].hi * 3 / 5)
    assert bounds["C_max"][1] == pytest.approx(ref["C_max"].hi * 3300 / 7800)
    p = ParameterSet.from_json((out / "parameters.json").read_text()).packs["battery"]
    assert p.model == "extended" and 2.5 * 3 < p.extended["ocv_0"] < 3.6 * 3
    # the paper circuit the service reads stays the pack's start (3 cells, full at 4.35 V/cell)
    assert p.battery.q_max / p.battery.C_b == pytest.approx(3 * 4.35)


# fit --vehicle --model extended for every chemistry of models.chemistry: the extended start is the
# chemistry's own rested curve inside the ranges carried to the pack's cells; a LiFePO4 pack raised
# a KeyError (the extended start had no LiFePO4 curve)
TINY_EXT = FitSettings(model="extended", extended_search=SearchSettings(starts=2, sa_generations=6, lm_max_nfev=6,
                                                                         seed=2), extended_thermal_generations=4)


def _description(chemistry: str, cells: int = 3, capacity_mah: float = 3000.0):
    data = _vehicle(cells, capacity_mah)
    data["packs"][0]["chemistry"] = chemistry
    return from_dict(data)


@pytest.mark.parametrize("chemistry", sorted(CHEMISTRIES))
def test_the_extended_start_of_every_chemistry_lies_inside_its_ranges(chemistry):
    spec = _description(chemistry).packs[0]
    start = extended_start(spec)
    bounds = {b.name: b for b in pb.battery_bounds("extended", pack_format(spec)).electrical}
    outside = {k: (start[k], bounds[k].lo, bounds[k].hi) for k in bounds
               if not bounds[k].lo <= start[k] <= bounds[k].hi}
    assert not outside, outside
    ocv = start["ocv_0"] + np.cumsum([0.0] + [start[f"docv_{k}"] for k in range(1, kernel.N_OCV_KNOTS)])
    # the start is full at the pack's full voltage and empty at the chemistry's empty cell
    assert ocv[-1] == pytest.approx(spec.full_voltage, rel=1e-9)
    assert ocv[0] / 3 == pytest.approx(ocv_knots_per_cell(chemistry)[0] * spec.full_cell_v
                                       / ocv_knots_per_cell(chemistry)[-1])


def test_a_lifepo4_start_is_its_chemistrys_plateau():
    knots = ocv_knots_per_cell("lifepo4")
    mid = (kernel.EXT_OCV_SOC >= 0.2) & (kernel.EXT_OCV_SOC <= 0.9)
    assert knots[0] == pytest.approx(2.5) and knots[-1] == pytest.approx(3.45)
    assert np.all((knots[mid] >= 3.25) & (knots[mid] <= 3.34))     # not a LiPo's 3.73-4.1 V


def test_an_unknown_chemistry_is_named_with_the_known_ones():
    with pytest.raises(ValueError, match="lipo, lihv, liion, lifepo4"):
        ocv_knots_per_cell("nimh")


@pytest.mark.parametrize("chemistry", ["lifepo4", "lihv"])
def test_an_extended_fit_of_a_lifepo4_or_lihv_pack_runs_and_recovers_its_voltage(chemistry):
    desc = _description(chemistry)
    spec = desc.packs[0]
    truth = chemistry_curve_pack(model_inputs(desc).pack_matrix[0], chemistry, spec.cells_series)
    flights = {split: _synthetic_flights(truth, spec.capacity_c, 1, seed, "extended")
               for seed, split in enumerate(("train", "validation", "test"))}
    merged, results = fit_packs(desc, lambda split, pack: flights[split], {k: k for k in flights}, TINY_EXT)
    res = results["battery"]
    p = merged.packs["battery"]
    assert p.model == "extended"
    # the fitted empty pack sits near the chemistry's empty cell (LFP 2.5 V, LiHV 3.27 V), 3 cells
    empty = CHEMISTRIES[chemistry].ocv_cell_v[0]
    assert abs(p.extended["ocv_0"] / 3 - empty) < 0.3, p.extended["ocv_0"]
    # the flights it was fitted to: the flown voltage recovered to the noise (10 mV), far below the start's.
    # (Not the test flight: one training flight leaves an LFP plateau's few-mV slope loose, and a flight's
    # start SoC is read from its voltage on it; docs/notes/2026-11-27-lfp-extended-fit.md)
    rmse = res.errors["learned"]["train"]["overall"]["voltage"]["rmse"]
    start_rmse = evaluate_battery(base_set(desc, "extended").packs["battery"].extended_vector(), flights["train"],
                                  TINY_EXT, model="extended")["overall"]["voltage"]["rmse"]
    assert rmse < 0.02 and rmse < 0.5 * start_rmse, (rmse, start_rmse)
