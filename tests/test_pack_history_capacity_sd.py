"""A pack's history gives the next flight a capacity with the σ of how it was read
(gcs_pdm/packs/priors.py, ``borrowed_curve_capacity_rel_sd``).

A health point's capacity is the charge between two rests over the SoC the rests say was used. A
pack with no curve of its own has its rests read through its chemistry's (a Li-ion pack's on the LG
M50's electrodes): each rest's SoC is then as uncertain as the chemistry's published curves are
apart (``CURVE_FAMILY_SPREAD``), the same way on every flight. On PyBaMM's NCA_Kim2011 the reading
came out 7-23 % low with σ 1.6 % (docs/notes/2026-11-28-history-prior.md).
"""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from gcs_pdm.estimation.calibration import PackPrior
from gcs_pdm.models.chemistry import chemistry
from gcs_pdm.models.curve_hypotheses import CURVE_FAMILY_SPREAD
from gcs_pdm.packs.health import HealthSettings
from gcs_pdm.packs.priors import prior_with_history

RATED_AH = 7.8
HISTORY = {"capacity_ah": 7.0, "capacity_sd_ah": 0.112, "capacity_depth_of_discharge": 0.6}


def test_a_capacity_read_through_the_chemistrys_curve_carries_the_curves_spread():
    base = PackPrior("liion", 5, RATED_AH * 3600.0)
    told = prior_with_history(base, HISTORY, "SN-1")
    curve_part = math.sqrt(2.0) * CURVE_FAMILY_SPREAD["liion"].rest_soc_sd / 0.6
    assert told.capacity_c == pytest.approx(7.0 * 3600.0)
    assert told.capacity_rel_sd == pytest.approx(math.hypot(0.112 / 7.0, curve_part))
    assert "read through its chemistry's curve" in told.capacity_source
    # a shallower use between the rests reads the capacity less surely; unknown: the shallowest read
    shallow = prior_with_history(base, {**HISTORY, "capacity_depth_of_discharge": 0.35})
    unknown = prior_with_history(base, {**HISTORY, "capacity_depth_of_discharge": None})
    assert shallow.capacity_rel_sd > told.capacity_rel_sd
    assert unknown.capacity_rel_sd == pytest.approx(
        math.hypot(0.016, math.sqrt(2.0) * 0.08 / HealthSettings().min_soc_used), rel=1e-6)


def test_a_pack_with_its_own_curve_keeps_the_health_points_sigma():
    own = replace(chemistry("liion"), name="this pack's own curve")
    base = PackPrior("liion", 5, RATED_AH * 3600.0, curve=own)
    told = prior_with_history(base, HISTORY, "SN-1")
    assert told.capacity_rel_sd == pytest.approx(0.112 / 7.0)
    assert told.capacity_source == "pack history (SN-1)"
