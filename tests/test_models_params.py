"""Parameter sets: the paper's tables verbatim, the physical reading, validation, JSON."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gcs_pdm.models import params as P
from gcs_pdm.models.kernel import PACK_PARAMS


def test_paper_set_is_verbatim():
    paper = P.builtin("paper")
    llf = paper.packs["LLF20"]
    assert llf.battery.R_s == pytest.approx(7.4e-3)
    assert llf.battery.R_p == pytest.approx(0.9e-4)
    assert llf.battery.R_cp0 == pytest.approx(3.0e-2)
    assert llf.battery.R_cp1 == pytest.approx(1.2e-16)
    assert llf.battery.R_cp2 == 34.41
    assert (llf.battery.C_s, llf.battery.C_b, llf.battery.C_cp) == (112.3, 18.3, 316.1)
    assert llf.thermal.C_t == pytest.approx(20.76e-4) and llf.thermal.h == 11.68
    assert paper.packs["URA40"].battery.R_cp2 == 34.46
    assert paper.motor.C_t == pytest.approx(10.32e-4) and paper.motor.h == 11.17
    previous = P.builtin("previous")
    assert previous.packs["ULA20"].battery.R_cp2 == 36.0 and previous.motor.h == 10.0
    assert not paper.physical and not previous.physical


def test_physical_reading_gives_a_5s_7800mah_pack():
    ps = P.default_set()
    assert ps.physical and ps.name == "paper_si"
    for name in P.PACK_NAMES:
        b, th = ps.packs[name].battery, ps.packs[name].thermal
        assert b.q_max / b.C_b == pytest.approx(21.0)  # full 5S pack at 4.2 V/cell
        assert b.C_max == pytest.approx(7.8 * 3600)
        assert 0.3 < b.R_s * b.C_s < 3  # R–C time constants of seconds
        assert 3 < b.R_cp0 * b.C_cp < 30
        # self-discharge of milliamps, not an emptied pack
        assert 21.0 / b.R_p < 0.01
        # the open-circuit voltage spans a LiPo's range over the usable capacity
        assert 18.5 < (b.q_max - b.C_max) / b.C_b < 20.0
        assert 5 * 60 < th.C_t / th.h < 60 * 60  # thermal time constants of minutes


def test_validation_names_the_field():
    good = P.default_set().to_dict()
    bad = json.loads(json.dumps(good))
    bad["packs"]["LRF40"]["battery"]["R_s"] = -0.01
    with pytest.raises(P.ParameterError, match=r"packs\.LRF40\.battery\.R_s"):
        P.ParameterSet.from_dict(bad)
    bad = json.loads(json.dumps(good))
    bad["motor"]["h"] = math.nan
    with pytest.raises(P.ParameterError, match=r"motor\.h"):
        P.ParameterSet.from_dict(bad)
    bad = json.loads(json.dumps(good))
    del bad["packs"]["ULA20"]["thermal"]["C_t"]
    with pytest.raises(P.ParameterError, match=r"packs\.ULA20\.thermal\.C_t"):
        P.ParameterSet.from_dict(bad)
    bad = json.loads(json.dumps(good))
    bad["packs"]["LLF20"]["battery"]["C_b"] = "lots"
    with pytest.raises(P.ParameterError, match=r"C_b"):
        P.ParameterSet.from_dict(bad)
    with pytest.raises(P.ParameterError, match="not JSON"):
        P.ParameterSet.from_json("{nope")


def test_json_round_trip_and_vectors():
    for ps in P.BUILTIN_SETS.values():
        again = P.ParameterSet.from_json(ps.to_json())
        assert again == ps
        np.testing.assert_array_equal(again.pack_matrix(), ps.pack_matrix())
    d = P.default_set().to_dict()
    assert d["units"]["BatteryParams"]["R_s"] == "ohm"
    pack = P.default_set().packs["LRF40"]
    assert P.pack_from_vector(P.pack_vector(pack)) == pack
    assert P.pack_vector(pack)[PACK_PARAMS.index("C_cp")] == pack.battery.C_cp


def test_perturbed_sets_differ_but_stay_physical():
    rng = np.random.default_rng(3)
    base = P.default_set()
    other = P.perturbed(base, rng, rel=0.15)
    assert not np.allclose(other.pack_matrix(), base.pack_matrix())
    ratio = other.pack_matrix() / base.pack_matrix()
    i_r2 = PACK_PARAMS.index("R_cp2")
    assert np.all(np.abs(ratio[:, i_r2] - 1) <= 0.015 + 1e-12)
    m, b = other.pack_matrix(), base.pack_matrix()
    end_r = m[:, 3] * np.exp(m[:, i_r2]) / (b[:, 3] * np.exp(b[:, i_r2]))
    assert np.all((end_r > 0.85 - 1e-9) & (end_r < 1.15 + 1e-9))
    i_cmax = PACK_PARAMS.index("C_max")
    np.testing.assert_array_equal(m[:, i_cmax], b[:, i_cmax])


def test_degraded_pack_holds_less_and_resists_more():
    base = P.default_set()
    aged = P.degraded(base, "LRF40", capacity=0.8, resistance=1.5)
    b0, b1 = base.packs["LRF40"].battery, aged.packs["LRF40"].battery
    assert b1.C_max == pytest.approx(0.8 * b0.C_max) and b1.C_b == pytest.approx(0.8 * b0.C_b)
    assert b1.q_max / b1.C_b == pytest.approx(21.0)  # still full at 4.2 V/cell
    assert b1.R_s == pytest.approx(1.5 * b0.R_s) and b1.R_cp0 == pytest.approx(1.5 * b0.R_cp0)
    assert b1.C_s == b0.C_s and aged.packs["LLF20"] == base.packs["LLF20"]
    with pytest.raises(P.ParameterError, match="no pack"):
        P.degraded(base, "XYZ", 0.9)
    with pytest.raises(P.ParameterError, match="LRF40"):
        P.degraded(base, "LRF40", capacity=0.0)
