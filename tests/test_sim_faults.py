"""Fault and degradation grammar of the simulated vehicle."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.models import kernel
from gcs_pdm.sim.faults import (Degradation, FaultSpecError, apply_degradation, parse_degradation, parse_fault,
                                parse_trigger)
from gcs_pdm.sim.truth import true_parameters


def test_fault_grammar_all_triggers():
    f = parse_fault("motor:aft:0.8@leg:2-3")
    assert (f.motor, f.magnitude, f.trigger.kind, f.trigger.from_seq, f.trigger.seq, f.trigger.fraction) == \
        ("aft", 0.8, "leg", 2, 3, 0.5)
    assert parse_fault("motor:fwd:1@t:300").trigger.time_s == 300.0
    assert parse_fault("motor:fwd:0.25@wp:4").trigger.seq == 4
    assert parse_fault("motor:aft:0.5@leg:5-7:0.2").trigger.fraction == 0.2
    # the description parses back to the same spec
    assert parse_fault(f.describe()) == f


@pytest.mark.parametrize("text, needle", [
    ("motor:left:0.5@t:10", "motor must be one of"),
    ("motor:aft:1.5@t:10", "magnitude"),
    ("motor:aft:0.5@x:10", "unknown trigger"),
    ("motor:aft:0.5@leg:3", "leg:<from>-<to>"),
    ("motor:aft:0.5@t:-1", ">= 0"),
    ("motor:aft:0.5@wp:two", "integer"),
    ("motor:aft:0.5@leg:2-3:2", "fraction"),
    ("aft 0.5", "expected motor:"),
])
def test_fault_grammar_errors_name_the_problem(text, needle):
    with pytest.raises(FaultSpecError, match=needle):
        parse_fault(text)


def test_degradation_grammar_and_errors():
    assert parse_degradation("LRF40:capacity=0.8,resistance=1.5") == Degradation("LRF40", 0.8, 1.5)
    assert parse_degradation("URA40:resistance=2") == Degradation("URA40", 1.0, 2.0)
    for bad, needle in [("XYZ:capacity=0.5", "pack must be"), ("LRF40:volume=2", "unknown degradation"),
                        ("LRF40:capacity=0", "> 0"), ("LRF40:capacity=1.2", "<= 1"), ("LRF40", "expected")]:
        with pytest.raises(FaultSpecError, match=needle):
            parse_degradation(bad)
    with pytest.raises(FaultSpecError):
        parse_trigger("leg:a-b")


def test_apply_degradation_scales_capacity_and_resistance_of_one_pack():
    base = true_parameters()
    out = apply_degradation(base, [Degradation("LRF40", 0.8, 1.5)])
    a, b = base.pack_matrix(), out.pack_matrix()
    i = 2  # LRF40
    for name in ("C_b", "q_max", "C_max"):
        k = kernel.PACK_PARAMS.index(name)
        assert b[i, k] == pytest.approx(0.8 * a[i, k])
    for name in ("R_s", "R_cp0"):
        k = kernel.PACK_PARAMS.index(name)
        assert b[i, k] == pytest.approx(1.5 * a[i, k])
    other = [j for j in range(4) if j != i]
    np.testing.assert_array_equal(a[other], b[other])
    assert out.provenance["degradation"] == ["LRF40:capacity=0.8,resistance=1.5"]
