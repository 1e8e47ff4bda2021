"""What a pack's capacity is read on (gcs_pdm/packs/cell_curves.py): one reading per chemistry for
the live service, ``packs ingest`` and the ageing evaluation. A Li-ion pack that has lost lithium is
read on its electrodes' curves; its full-cell curve, whose shape changes as it loses lithium, reads it
high."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gcs_pdm.models.chemistry import CHEMISTRIES
from gcs_pdm.packs.cell_curves import capacity_reading, pack_health_point, rested_cell_voltage
from gcs_pdm.packs.health import OcvCurve, health_point
from gcs_pdm.packs.ingest import IngestSettings, records_from_log
from gcs_pdm.packs.synthetic import SyntheticPack, pack_profile, write_pack_tlog


def test_each_chemistry_has_one_reading_and_an_unknown_one_is_refused():
    liion = capacity_reading("liion", 7.8)
    assert liion.electrodes is not None and liion.ocv is None
    # the electrodes scale with the rating: the LG M50's per Ah of its 5 Ah
    assert liion.electrodes.negative_ah / 7.8 == pytest.approx(capacity_reading("liion", 5.0).electrodes.negative_ah / 5.0)
    lipo = capacity_reading("lipo", 7.8)
    assert lipo.electrodes is None and lipo.ocv.voltage_v == CHEMISTRIES["lipo"].ocv_cell_v and lipo.ocv.soc_sd > 0
    with pytest.raises(ValueError, match="not one of"):
        capacity_reading("nimh", 5.0)


def test_an_aged_liion_cell_rests_full_at_the_full_voltage_with_less_charge_to_the_cut_off():
    el = capacity_reading("liion", 5.0).electrodes
    for capacity in (5.0, 4.2):
        x0, y0 = el.full_state_for(capacity, 4.2)
        assert float(el.u_p(y0) - el.u_n(x0)) == pytest.approx(4.2, abs=1e-3)
        assert el.capacity_from(x0, y0) == pytest.approx(capacity, rel=1e-3)
    # lithium lost: the negative starts emptier
    assert el.full_state_for(4.2, 4.2)[0] < el.full_state_for(5.0, 4.2)[0]
    with pytest.raises(ValueError, match="no lithium inventory"):
        el.full_state_for(50.0, 4.2)


@pytest.fixture(scope="module")
def aged_liion_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("liion") / "aged.tlog"
    pack = SyntheticPack(serial="LI-1", rated_capacity_ah=5.0, capacity_ah=4.25, chemistry="liion")
    return path, write_pack_tlog(path, pack, seed=3, bulk=False)


def test_packs_ingest_reads_an_aged_liion_pack_on_its_electrodes(aged_liion_log):
    path, truth = aged_liion_log
    (rec,), _ = records_from_log(path, "h", IngestSettings(chemistry="liion"))
    h = rec["health"]
    assert h["method"]["ocv_curve"] == "liion electrodes"
    assert abs(h["capacity_ah"] / truth["capacity_ah"] - 1.0) < 0.03
    assert abs(h["capacity_ah"] - truth["capacity_ah"]) < 2.0 * h["capacity_sd_ah"]


def test_the_fresh_full_cell_curve_reads_the_same_aged_pack_high():
    """The reason for the electrodes: the same pack (15 % of its lithium lost) read on the fresh
    cell's own open-circuit curve against SoC, through the same health point."""
    reading = capacity_reading("liion", 5.0)
    t, i, _ = pack_profile(seed=3)
    drawn = [0.0]
    for k in range(1, t.size):
        drawn.append(drawn[-1] + 0.5 * (i[k] + i[k - 1]) * (t[k] - t[k - 1]) / 3600.0)
    v = rested_cell_voltage(reading, 4.25, drawn) - 0.005 * i
    on_electrodes = pack_health_point("P", t, i, v, chemistry="liion", nominal_capacity_ah=5.0)
    el = reading.electrodes
    x0, y0 = el.full_state_for(5.0, 4.2)
    q = [k * 5.0 / 100 for k in range(101)]
    fresh_curve = OcvCurve(tuple(1.0 - x / 5.0 for x in q),
                           tuple(float(el.u_p(y0 + x / el.positive_ah) - el.u_n(x0 - x / el.negative_ah)) for x in q))
    on_fresh_curve = health_point("P", t, i, v, nominal_capacity_ah=5.0, ocv=fresh_curve)
    assert abs(on_electrodes.capacity_ah / 4.25 - 1.0) < 0.02
    assert on_fresh_curve.capacity_ah / 4.25 - 1.0 > 0.03


def _capacity_by_full_scan(el, x0: float, y0: float, pol: float) -> float:
    """The charge to the cut-off by evaluating every sample of the 4000-sample grid (the reference
    the bisection must reproduce to the bit)."""
    q = np.linspace(0.0, min(x0 * el.negative_ah, (1.0 - y0) * el.positive_ah), 4000)
    v = el.u_p(y0 + q / el.positive_ah) - el.u_n(x0 - q / el.negative_ah) - pol
    below = np.flatnonzero(v <= el.lower_cutoff_v)
    if below.size == 0:
        return float(q[-1])
    k = int(below[0])
    if k == 0:
        return 0.0
    w = (v[k - 1] - el.lower_cutoff_v) / (v[k - 1] - v[k])
    return float(q[k - 1] + w * (q[k] - q[k - 1]))


@pytest.mark.parametrize("bumpy", [False, True])
def test_the_capacity_to_the_cut_off_is_the_full_scans_to_the_bit(bumpy):
    el = capacity_reading("liion", 5.0).electrodes
    if bumpy:  # a measured table whose negative potential rises here and there: evaluated in full
        neg = np.array(el.negative_v)
        neg[100:300:7] += 2e-4
        el = dataclasses.replace(el, negative_v=tuple(neg))
    assert el.monotone is not bumpy
    rng = np.random.default_rng(1)
    x0 = np.concatenate([rng.uniform(0.0, 1.0, 300), [0.0, 0.999]])
    for v0, pol in ((4.2, 0.0), (3.7, 0.004), (2.9, 0.3)):
        y0 = el.y_at(v0 + el.u_n(x0))
        got = el.capacities_from(x0, y0, pol)
        assert got.tolist() == [_capacity_by_full_scan(el, float(x), float(y), pol) for x, y in zip(x0, y0)]
