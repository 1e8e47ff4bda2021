"""The run's order under xdist (tests/run_order.py): slow tests first, a module's tests that share
a module-scoped fixture one xdist unit, the rest in collection order."""
from __future__ import annotations

from pathlib import Path

import pytest

pytest_plugins = ["pytester"]

RUN_ORDER = Path(__file__).with_name("run_order.py")


@pytest.fixture
def collected(pytester):
    pytester.makeconftest(f"""
import sys
sys.path.insert(0, {str(RUN_ORDER.parent)!r})
from run_order import order_for_xdist

def pytest_collection_modifyitems(config, items):
    order_for_xdist(items)
""")
    pytester.makeini("[pytest]\nmarkers =\n    slow: long\n    xdist_group: unit")
    pytester.makepyfile(test_a="""
import pytest

@pytest.fixture(scope="module")
def fitted():
    return 1

def test_fast():
    pass

def test_uses_the_fit(fitted):
    pass

@pytest.mark.slow
def test_slow_uses_the_fit(fitted):
    pass
""", test_b="""
import pytest

def test_fast_b():
    pass

@pytest.mark.slow
def test_slow_b():
    pass

@pytest.mark.xdist_group("mine")
def test_own_group():
    pass
""")
    run = pytester.inline_run("--collect-only", "-p", "no:xdist")
    return run.getcall("pytest_collection_finish").session.items  # as collection_modifyitems left them


def test_slow_tests_and_their_fixture_sharing_units_come_first(collected):
    names = [i.name for i in collected]
    # the fit's unit (one of its tests is slow) and the slow test first, then the rest in collection order
    assert names == ["test_uses_the_fit", "test_slow_uses_the_fit", "test_slow_b",
                     "test_fast", "test_fast_b", "test_own_group"]


def test_tests_sharing_a_module_fixture_are_one_unit_and_others_keep_their_own(collected):
    from run_order import group

    units = {i.name: group(i) for i in collected}
    assert units["test_uses_the_fit"] == units["test_slow_uses_the_fit"] == "test_a"
    assert units["test_fast"] is None and units["test_slow_b"] is None  # each its own unit
    assert units["test_own_group"] == "mine"  # a group someone chose is kept
