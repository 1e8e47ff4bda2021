"""Training flights the fitted circuit does not draw (gcs_pdm.fitting.misfit)."""
import json
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.fitting.misfit import misfit_warnings
from gcs_pdm.fitting.procedure import FitSettings, fit_battery
from gcs_pdm.fitting.search import SearchSettings
from gcs_pdm.fitting.logs import read_table


def entry(name, rmse):
    return {"flight": name, "voltage": {"rmse": rmse}}


def test_a_training_flight_missed_by_more_than_the_per_cell_limit_is_warned_about():
    flights = [entry("fine", 0.045), entry("cold_climb", 0.626), entry("edge", 0.100)]
    warnings = misfit_warnings(flights, cells=5)
    assert len(warnings) == 1 and warnings[0].startswith("training flight cold_climb: the fitted circuit misses it by 626 mV")
    assert "125 mV per cell" in warnings[0]
    # the limit is per cell: 100 mV is on the limit of a 5S pack, over that of a 4S one (80 mV)
    assert [w.split(":")[0] for w in misfit_warnings(flights, cells=4)] == ["training flight cold_climb",
                                                                           "training flight edge"]
    assert misfit_warnings(flights, cells=32) == []
    assert len(misfit_warnings(flights, cells=5, per_cell_v=0.005)) == 3


def test_flights_without_a_voltage_error_are_not_judged():
    flights = [{"flight": "no_voltage", "temperature": {"rmse": 3.0}}, entry("nan", float("nan")), entry("none", None)]
    assert misfit_warnings(flights, cells=5) == []


ROOT = Path(__file__).resolve().parents[1] / "fixtures" / "pybamm"


def test_a_fit_that_cannot_draw_its_training_flights_says_so():
    # the paper variant (a straight-line OCV) on PyBaMM flights misses them by hundreds of mV: a short
    # search is enough to show the warnings land in the result, one per missed training flight
    manifest = json.loads((ROOT / "manifest.json").read_text())
    flights = {f["flight"]: read_table(ROOT / f["file"], "battery", f["flight"]) for f in manifest["flights"]
               if f["set"] == "Chen2020"}
    train = [flights["chen2020_02"], flights["chen2020_09"]]
    settings = FitSettings(model="paper", search=SearchSettings(starts=2, sa_generations=4, lm_max_nfev=4))
    result = fit_battery(train, [flights["chen2020_12"]], [flights["chen2020_04"]], settings)
    errors = {e["flight"]: e["voltage"]["rmse"] for e in result.errors["learned"]["train"]["flights"]}
    missed = {name for name, rmse in errors.items() if rmse > 0.100}
    assert missed, errors   # the straight line cannot draw these cells
    warned = [w for w in result.warnings if w.startswith("training flight ")]
    assert sorted(w.split(":")[0].removeprefix("training flight ") for w in warned) == sorted(missed)
    assert np.isfinite(list(errors.values())).all()


def test_flights_to_leave_out_are_far_beyond_the_others_and_never_most_of_them():
    from gcs_pdm.fitting.misfit import flights_to_leave_out

    # OKane2022's draw (docs/fitting.md): one cold climb holds most of the error
    okane = {"01": .116, "02": .062, "03": .089, "05": .103, "06": .633, "07": .099, "09": .106, "10": .051}
    assert flights_to_leave_out(okane, cells=5) == ["06"]
    # over the per-cell limit but not far beyond the others: the circuit is poor everywhere, none stands out
    assert flights_to_leave_out({"a": .150, "b": .200, "c": .250, "d": .180}, cells=5) == []
    # far beyond the others but within the per-cell limit: a good fit's worst flight stays
    assert flights_to_leave_out({"a": .010, "b": .012, "c": .011, "d": .090}, cells=5) == []
    # worst first, and never more than half (nor fewer than two kept)
    many = {"a": .02, "b": .02, "c": .02, "d": .02, "e": .8, "f": .9, "g": .7}
    assert flights_to_leave_out(many, cells=5) == ["f", "e", "g"]
    assert flights_to_leave_out(many, cells=5, keep_at_least=0.8) == ["f"]
    assert flights_to_leave_out({"a": .02, "b": .9}, cells=5) == []          # too few to judge
    assert flights_to_leave_out({"a": .02, "b": float("nan"), "c": .02, "d": .03, "e": .5}, cells=5) == ["e"]


def _mixed_pack_fit(**changes):
    # four Chen2020 flights and one flight of another cell (Marquis2019): no one circuit draws both
    import dataclasses

    manifest = json.loads((ROOT / "manifest.json").read_text())
    logs = {f["flight"]: read_table(ROOT / f["file"], "battery", f["flight"]) for f in manifest["flights"]}
    train = [logs[n] for n in ("chen2020_02", "chen2020_05", "chen2020_07", "chen2020_08", "marquis2019_03")]
    settings = dataclasses.replace(FitSettings(), extended_search=SearchSettings(starts=2, sa_generations=15, lm_max_nfev=20),
                                   extended_polish_nfev=0, extended_thermal_generations=3, **changes)
    seen = []
    result = fit_battery(train, [logs["chen2020_12"]], [logs["chen2020_04"]], settings,
                         progress=lambda fraction, stage: seen.append(fraction))
    return result, seen


@pytest.mark.slow
def test_a_fit_is_repeated_without_the_training_flight_it_cannot_draw():
    result, progress = _mixed_pack_fit()
    assert [x["flight"] for x in result.left_out] == ["marquis2019_03"]
    left = result.left_out[0]
    assert left["first_fit_rmse_v"] > 0.100 and left["final_rmse_v"] > left["first_fit_rmse_v"]
    assert result.flights["train"] == ["chen2020_02", "chen2020_05", "chen2020_07", "chen2020_08"]
    assert result.warnings[0].startswith("training flight marquis2019_03: left out of the fit")
    d = result.to_dict()
    assert d["left_out"][0]["flight"] == "marquis2019_03" and d["provenance"]["settings"]["leave_out_misfits"]
    # the Chen flights are fitted better without it than with it
    again, _ = _mixed_pack_fit(leave_out_misfits=False)
    kept = {e["flight"]: e["voltage"]["rmse"] for e in result.errors["learned"]["train"]["flights"]}
    mixed = {e["flight"]: e["voltage"]["rmse"] for e in again.errors["learned"]["train"]["flights"]}
    assert not again.left_out and "marquis2019_03" in mixed
    assert np.mean(list(kept.values())) < np.mean([mixed[n] for n in kept])
    # one progress bar over both passes: never back, ends at 1
    assert progress == sorted(progress) and progress[-1] == 1.0


def test_a_log_cut_into_segments_leaves_whole_and_never_empties_the_training_set():
    from gcs_pdm.fitting.misfit import training_segments_to_leave_out

    # A was cut into three segments, B into two; A#2 and B#1 are missed far beyond the others
    rmse = {"A#1": .03, "A#2": .9, "A#3": .03, "B#1": .8, "B#2": .03, "C": .03, "D": .03, "E": .03}
    log_of = {"A#1": "A", "A#2": "A", "A#3": "A", "B#1": "B", "B#2": "B"}
    # both logs leave whole: 5 of 8 segments, fewer than half would remain -> no repeat
    assert training_segments_to_leave_out(rmse, log_of, cells=5) == []
    # with more clean logs, the flagged segments and their siblings leave, worst first
    more = rmse | {"F": .03, "G": .03, "H": .03, "I": .03}
    assert training_segments_to_leave_out(more, log_of, cells=5) == ["A#2", "B#1", "A#1", "A#3", "B#2"]
    # a segment whose log is not known is its own log
    assert training_segments_to_leave_out({"x#2": .9, "y": .03, "z": .03, "w": .03}, {}, cells=5) == ["x#2"]
    # nothing flagged: nothing leaves
    assert training_segments_to_leave_out({"a": .03, "b": .03, "c": .03}, {}, cells=5) == []


def test_a_paper_fits_siblings_are_the_models_that_earned_their_training_error():
    # the paper variant's q_max follows its C_b (problem.pack_vectors_with): a sibling built by copying its
    # values into the chosen vector would keep the chosen one's full charge and read every start wrong.
    # The reported spread must be the distance between the chosen prediction and the siblings' own.
    from gcs_pdm.fitting import problem as pb
    from gcs_pdm.fitting.cleaning import clean_flights
    from gcs_pdm.fitting.procedure import _pack_traces
    from gcs_pdm.models import kernel

    manifest = json.loads((ROOT / "manifest.json").read_text())
    logs = {f["flight"]: read_table(ROOT / f["file"], "battery", f["flight"]) for f in manifest["flights"]
            if f["set"] == "Chen2020"}
    train = [logs[n] for n in ("chen2020_02", "chen2020_05", "chen2020_07", "chen2020_08")]
    val, test = [logs["chen2020_12"]], [logs["chen2020_04"]]
    settings = FitSettings(model="paper", search=SearchSettings(starts=4, sa_generations=6, lm_max_nfev=8),
                           agreement_tolerance=10.0, leave_out_misfits=False)
    result = fit_battery(train, val, test, settings)
    record = result.candidate_agreement
    assert record["measured"] and len(record["candidates"]) >= 2
    chosen = np.array([result.parameters[k] for k in kernel.PACK_PARAMS])
    electrical = result.stages[0]
    prepared = [pb.prepare(f, "voltage", settings.init_samples) for f in clean_flights(val + test)[0]]
    ours = [v for v, _, _ in _pack_traces(chosen, prepared)]
    apart = {}
    for c in record["candidates"][1:]:
        values = electrical.candidates[c].values
        sibling = pb.pack_vectors_with(chosen, list(values), np.array([list(values.values())]))[0]
        for j, (v, _, _) in enumerate(_pack_traces(sibling, prepared)):
            d = v - ours[j]
            apart.setdefault(j, []).append(float(np.sqrt(np.mean(d[np.isfinite(d)] ** 2))))
    for j, f in enumerate(record["flights"]):
        assert f["spread_v"] == pytest.approx(max(apart[j]), rel=1e-6, abs=1e-9), f
