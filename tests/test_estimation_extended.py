"""Packs of the extended variant on the live path: the estimator's own filter for them, the Monte
Carlo prediction flying the kernel's extended step, the powertrain's extended block."""
import dataclasses

import numpy as np
import pytest

from gcs_pdm.estimation.estimator import EstimatorConfig, StateEstimator
from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator, predict_packs_at_current
from gcs_pdm.frames import PackFrame
from gcs_pdm.models import kernel, topology
from gcs_pdm.models.params import PACK_NAMES, default_set, extended_default
from gcs_pdm.models.powertrain import Limits

CUTOFF_V = 17.5


def extended_set(packs=PACK_NAMES, chemistry="lipo"):
    ps = default_set()
    for n in packs:
        ps = ps.with_pack(n, dataclasses.replace(ps.packs[n], model="extended", extended=extended_default(chemistry)))
    return ps


def current_profile(rng, duration_s):
    """1 Hz: a 60 s climb at 28 A, cruise legs of 8-16 A, a 60 s descent at 6 A."""
    i = np.empty(int(duration_s))
    k = 0
    while k < i.size:
        n = int(rng.uniform(60, 240))
        i[k:k + n] = rng.uniform(8.0, 16.0)
        k += n
    i[:60], i[-60:] = 28.0, 6.0
    return np.arange(i.size, dtype=float), i


def fly_extended(ps, seed=3, duration_s=1200.0, soc0=0.95):
    """Every pack flown on the kernel's extended variant; noisy frames and the truth."""
    rng = np.random.default_rng(seed)
    t, cur = current_profile(rng, duration_s)
    ext = np.stack([ps.packs[n].extended_vector() for n in PACK_NAMES])
    run = kernel.simulate_packs(ext, kernel.initial_extended_state(ext, soc0, 20.0, 0.0), np.diff(t, prepend=t[0]),
                                cur, 20.0, variant="extended")
    frames = [PackFrame(float(t[k]), n, voltage_v=float(run.voltage[b, k] + rng.normal(0, 0.03)),
                        current_a=float(cur[k] + rng.normal(0, 0.25)),
                        temperature_c=float(run.temperature[b, k] + rng.normal(0, 0.3)))
              for k in range(t.size) for b, n in enumerate(PACK_NAMES)]
    return frames, run


@pytest.fixture(scope="module")
def flown():
    ps = extended_set()
    frames, run = fly_extended(ps)
    est = StateEstimator(ps)
    for f in frames:
        est.consume(f)
    return ps, frames, run, est


@pytest.mark.slow
def test_extended_packs_are_tracked_by_their_own_filter(flown):
    ps, frames, run, est = flown
    e = est.estimate()
    assert est.ext is not None and sorted(est.ext_row) == [0, 1, 2, 3]
    assert np.all(np.abs(e.soc - run.soc[:, -1]) < 0.02), (e.soc, run.soc[:, -1])
    assert np.all(np.abs(e.soc - run.soc[:, -1]) < 3 * e.soc_sd)
    assert np.all(np.abs(e.pack_temp_c - run.temperature[:, -1]) < 1.0)
    assert np.all(np.abs(e.pack_voltage_v - run.voltage[:, -1]) < 0.1)
    checks = e.model_mismatch
    assert all(c["state"] == "matches" and c["model"] == "extended" for c in checks.values()), checks
    assert est.counters["model_mismatch_raised"] == 0


def test_the_paper_estimator_on_extended_cells_says_mismatch(flown):
    """The same telemetry through the paper variant's values: its straight-line OCV cannot follow
    the curved one, and the consistency test says so (the SoC it reports is far off). With the set
    as a prior (``estimation.fitted_prior``, the default) every pack's set is contradicted by its
    innovations and the advisory says to refit; on the set's curve the filter that takes over leaves
    its own charge count, so the curve is judged contradicted too and the pack is estimated from its
    chemistry's curves, near the truth with a σ that holds it (docs/notes/2026-11-27-takeover-curve.md;
    before: 0.00 ± 0.07 against 0.42)."""
    ps, frames, run, _ = flown
    est = StateEstimator(default_set(), EstimatorConfig(fitted_set_as_prior=False))
    for f in frames:
        est.consume(f)
    e = est.estimate()
    assert est.counters["model_mismatch_raised"] >= 4
    assert all(c["active"] and c["model"] == "paper" for c in e.model_mismatch.values())
    assert np.all(np.abs(e.soc - run.soc[:, -1]) > 0.1)
    watched = StateEstimator(default_set())
    for f in frames:
        watched.consume(f)
    assert watched.counters["fitted_set_contradicted"] == 4
    assert watched.counters["fitted_curve_contradicted"] == 4
    e = watched.estimate()
    assert all(c["active"] and "curve_reason" in c["fitted_set"] for c in e.model_mismatch.values())
    err = np.abs(e.soc - run.soc[:, -1])
    assert np.all(err < 0.1), (e.soc, run.soc[:, -1])
    assert np.all(err <= 2.0 * e.soc_sd), (err, e.soc_sd)


def test_a_mixed_set_runs_each_pack_on_its_own_variant():
    ps = extended_set(packs=("ULA20",))
    est = StateEstimator(ps)
    assert est.ext_row == {1: 0}
    est.consume(PackFrame(0.0, "ULA20", 20.0, 0.0, 20.0))
    est.consume(PackFrame(0.0, "LLF20", 20.0, 0.0, 20.0))
    e = est.estimate()
    # at rest, 20.0 V is 4.0 V/cell: on the LiPo curve that is SoC ≈ 0.8; on the paper's line ≈ 0.4
    assert e.soc[1] == pytest.approx(0.8, abs=0.03)
    assert e.soc[0] < 0.6
    assert e.model_mismatch["ULA20"]["model"] == "extended" and e.model_mismatch["LLF20"]["model"] == "paper"
    # the capacity the prognosis counts SoC against is each pack's own variant's
    small = dict(ps.packs["ULA20"].extended, C_max=0.8 * ps.packs["ULA20"].extended["C_max"])
    est = StateEstimator(ps.with_pack("ULA20", dataclasses.replace(ps.packs["ULA20"], extended=small)))
    cap = est.capacity_c()
    assert cap[1] == pytest.approx(small["C_max"]) and cap[0] == pytest.approx(ps.packs["LLF20"].battery.C_max)


def test_extended_block_flies_the_kernel_extended_step():
    """All paper: the same as ``simulate_vehicle``. Extended packs: each pack's recorded voltage is
    ``kernel.simulate_packs(variant="extended")`` driven by the current the block gave it."""
    ps = extended_set()
    pm, mv = ps.pack_matrix(), ps.motor_vector()
    ext = np.stack([ps.packs[n].extended_vector() for n in PACK_NAMES])  # used where is_ext
    is_ext = np.array([True, False, True, False])
    x_paper = kernel.initial_pack_state(pm, 0.9, 20.0)
    x0 = np.zeros((1, 4, kernel.N_EXT_STATE))
    x0[0, :, :4] = x_paper
    x0[0, is_ext] = kernel.initial_extended_state(ext[is_ext], 0.9, 20.0, 0.0)
    dt = np.full(300, 5.0)
    power = np.full(300, 800.0)
    mp = np.repeat(mv[None, None], 2, axis=1)
    topo = topology.PAPER_TOPOLOGY
    paper = topology.simulate_vehicle(topo, pm[None], mp, x_paper[None], np.full((1, 2), 20.0), dt, power, 15.0,
                                      record=True)
    same = topology.simulate_vehicle_extended(topo, pm[None], ext[None], np.zeros(4, bool), mp,
                                              np.concatenate([x_paper, np.zeros((4, 1))], axis=1)[None],
                                              np.full((1, 2), 20.0), dt, power, 15.0, record=True)
    np.testing.assert_array_equal(same.pack_voltage, paper.pack_voltage)
    np.testing.assert_array_equal(same.motor_temp, paper.motor_temp)
    fault = np.array([[0.3, 0.0]])
    paper_f = topology.simulate_vehicle(topo, pm[None], mp, x_paper[None], np.full((1, 2), 20.0), dt, power, 15.0,
                                        fault, record=True)
    same_f = topology.simulate_vehicle_extended(topo, pm[None], ext[None], np.zeros(4, bool), mp,
                                                np.concatenate([x_paper, np.zeros((4, 1))], axis=1)[None],
                                                np.full((1, 2), 20.0), dt, power, 15.0, fault, record=True)
    np.testing.assert_array_equal(same_f.motor_current, paper_f.motor_current)
    mixed = topology.simulate_vehicle_extended(topo, pm[None], ext[None], is_ext, mp, x0, np.full((1, 2), 20.0),
                                               dt, power, 15.0, record=True)
    for b in np.flatnonzero(is_ext):
        direct = kernel.simulate_packs(ext[b], x0[0, b], dt, mixed.pack_current[0, :, b], 15.0, variant="extended")
        np.testing.assert_allclose(mixed.pack_voltage[0, :, b], direct.voltage[0], rtol=1e-12)
        np.testing.assert_allclose(mixed.pack_soc[0, :, b], direct.soc[0], rtol=1e-12)
    # an extended pack's curve is not the paper line: the strings differ
    assert np.max(np.abs(mixed.pack_voltage[0, :, 0] - paper.pack_voltage[0, :, 0])) > 0.2


def first_below(v, t):
    k = np.flatnonzero(v < CUTOFF_V)
    return t[k[0]] if k.size else np.inf


def test_prediction_with_extended_packs_matches_a_direct_extended_simulation(flown):
    ps, _, _, est = flown
    rng = np.random.default_rng(5)
    # at a held current: the median of the Monte Carlo against the extended kernel from the mean
    current = np.full(4, 12.0)
    pred = predict_packs_at_current(est, np.full(4, CUTOFF_V), current_a=current, horizon_s=3600.0, step_s=5.0,
                                    rng=rng, n_samples=64, param_rel_sigma=0.0)
    dt = np.full(720, 5.0)
    t = np.cumsum(dt)
    for b in range(4):
        r = est.ext_row[b]
        direct = kernel.simulate_packs(est.ext.params[r], est.ext.mean[r], dt, np.full(720, 12.0), est.ambient_c,
                                       variant="extended")
        t_direct = first_below(direct.voltage[0], t)
        assert np.isfinite(t_direct)
        assert pred.time_to_cutoff_s[b, 1] == pytest.approx(t_direct, rel=0.02)  # measured: equal
        assert pred.time_to_cutoff_s[b, 0] <= t_direct <= pred.time_to_cutoff_s[b, 2]
    # under a shaft-power load: the same against the extended block flown from the mean state
    load = FutureLoad.constant(800.0, 3600.0, 10.0, ambient_c=est.ambient_c)
    pred = predict_from_estimator(est, load, rng=rng, n_samples=64, param_rel_sigma=0.0, stop_on_failure=False,
                                  trajectories=False, limits=Limits(pack_cutoff_v=CUTOFF_V))
    x0 = np.zeros((1, 4, kernel.N_EXT_STATE))
    ext = np.zeros((4, kernel.N_EXT_PARAMS))
    for b, r in est.ext_row.items():
        x0[0, b], ext[b] = est.ext.mean[r], est.ext.params[r]
    tm = np.where(np.isfinite(est.motors.mean[:, 0]), est.motors.mean[:, 0], est.ambient_c)
    direct = topology.simulate_vehicle_extended(topology.PAPER_TOPOLOGY, est.packs.params[None], ext[None],
                                                np.ones(4, bool), np.repeat(est.motors.params[0][None, None], 2, axis=1),
                                                x0, tm[None], load.dt, load.shaft_power_w, est.ambient_c, record=True)
    t = np.cumsum(load.dt)
    for b in range(4):
        t_direct = first_below(direct.pack_voltage[0, :, b], t)
        assert np.isfinite(t_direct)
        assert pred.pack_time_to_cutoff_s[b, 1] == pytest.approx(t_direct, rel=0.03)  # measured: 750 vs 740-750 s


def test_the_service_says_the_planner_flies_paper_values_of_extended_packs(tmp_path):
    """Activating a set with an extended pack: the answer and /status name the pack whose paper
    values the planner still flies; a paper-only set has no such note."""
    from fastapi.testclient import TestClient

    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service

    token = "extended-test-token-0123456789"
    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=token, policy="advise"))
    try:
        client = TestClient(create_app(svc))
        auth = {"Authorization": f"Bearer {token}"}
        assert client.get("/status").json()["model_variants"]["notes"] == []
        body = extended_set(packs=("URA40",)).to_dict()
        r = client.post("/parameter-sets", json={"parameter_set": body, "name": "ext_ura40"}, headers=auth)
        assert r.status_code == 201, r.json()
        r = client.post("/parameter-sets/ext_ura40/activate", headers=auth)
        assert r.status_code == 200
        variants = r.json()["model_variants"]
        assert variants["packs"]["URA40"] == "extended" and variants["packs"]["LLF20"] == "paper"
        assert variants["notes"] == [n for n in variants["notes"] if "URA40" in n] and len(variants["notes"]) == 1
        assert "planner uses the paper-variant values of pack URA40" in variants["notes"][0]
        assert client.get("/status").json()["model_variants"] == variants
    finally:
        svc.close()
