"""The order and the units of work of a run under xdist (``--dist loadgroup``, which
``tests/conftest.py`` sets under ``-n``), applied by ``tests/conftest.py`` (docs/notes/2026-11-27-test-time.md).

xdist's default hands each worker a block of consecutive tests and never moves a test once
given, so a long test late in the collection ends the run with one worker idle. Here the tests
marked ``slow`` come first and each test is its own unit, handed to whichever worker is free
(longest first, then list scheduling); the tests of a module that share a module-scoped fixture
(a fit, a flight, a service made once) are one unit, so the fixture is still made once.
"""
from __future__ import annotations

import pytest

#: fixture scopes whose value the tests of one module share (function: per test; session: per worker)
SHARED_SCOPES = ("module", "package")


def order_for_xdist(items: list) -> None:
    """Groups and sorts ``items`` in place; deterministic, so every worker collects the same order."""
    for item in items:
        if not item.get_closest_marker("xdist_group") and uses_shared_fixture(item):
            item.add_marker(pytest.mark.xdist_group(item.path.stem))  # test file names are unique
    slow_groups = {group(i) for i in items if i.get_closest_marker("slow")} - {None}
    items.sort(key=lambda i: not (i.get_closest_marker("slow") or group(i) in slow_groups))


def uses_shared_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)  # absent on items that are not Python functions
    if info is None:
        return False
    return any(d.scope in SHARED_SCOPES for defs in info.name2fixturedefs.values() for d in defs)


def group(item) -> str | None:
    """The item's ``xdist_group`` name, as xdist reads it (None: no group)."""
    mark = item.get_closest_marker("xdist_group")
    return None if mark is None else str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
