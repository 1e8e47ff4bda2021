"""Issue 32, "One vehicle": no code below the CLI branches on "the paper aircraft" or on "no vehicle".

The paper's aircraft is the ``edge540`` preset; a module below the command line and the service's
entry points takes a vehicle description and does not ask whether it is the paper's, nor what to
do when there is none (the entry points resolve "no vehicle" to ``edge540`` once). This test reads
the package's source (AST, no imports) and counts such branches per module:

- a call to, or an import of, ``is_paper_aircraft`` (or a private wrapper of it);
- ``X is None`` / ``X is not None`` where X names a vehicle: a name or attribute called
  ``vehicle``, ``inputs`` or ``_inputs`` (the description's model inputs);
- ``X or default`` with such an X (a missing vehicle resolved on the spot).

``ALLOWED`` lists the branches that are still there, per module, when this test was written
(main af0a3a3 + branch battery): a shrinking allow-list. A module may have fewer (lower its entry,
or drop it at 0), never more, and a module not listed has none.
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gcs_pdm"

#: names that hold a vehicle description (or its model inputs) in the core
VEHICLE_NAMES = {"vehicle", "inputs", "_inputs"}
PAPER_PREDICATES = {"is_paper_aircraft", "_is_paper_aircraft"}

#: the command line and the service's entry points, where "no vehicle" is resolved (allowed)
ENTRY_POINTS = {"cli.py", "signing_cli.py", "server.py", "runtime.py", "demo.py", "live.py"}

#: still-present branches (see the module docstring); to be removed, never added to
ALLOWED = {
    # the predicate's own definition, called only by the service's entry point (runtime.py: which
    # parameter set and limits to fly over the paper's aircraft)
    "vehicle/presets.py": 1,
}


def _is_vehicle_expr(node: ast.AST) -> bool:
    if isinstance(node, ast.Name):
        return node.id in VEHICLE_NAMES
    if isinstance(node, ast.Attribute):
        return node.attr in VEHICLE_NAMES
    return False


def branches(source: str) -> list[int]:
    """Line numbers of the branches this test forbids in ``source``."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare) and len(node.ops) == 1 and isinstance(node.ops[0], (ast.Is, ast.IsNot)):
            right = node.comparators[0]
            if isinstance(right, ast.Constant) and right.value is None and _is_vehicle_expr(node.left):
                lines.append(node.lineno)
        elif isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or) and _is_vehicle_expr(node.values[0]):
            lines.append(node.lineno)
        elif isinstance(node, ast.Call):
            fn = node.func
            name = fn.id if isinstance(fn, ast.Name) else fn.attr if isinstance(fn, ast.Attribute) else None
            if name in PAPER_PREDICATES:
                lines.append(node.lineno)
        elif isinstance(node, ast.FunctionDef) and node.name in PAPER_PREDICATES:
            lines.append(node.lineno)
    return sorted(lines)


@functools.cache  # read once per session: every module's test reads the same table
def found() -> dict[str, list[int]]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name in ENTRY_POINTS:
            continue
        lines = branches(path.read_text(encoding="utf-8"))
        if lines:
            out[path.relative_to(PACKAGE).as_posix()] = lines
    return out


def test_the_detector_sees_both_kinds_of_branch():
    src = ("def f(vehicle, self):\n"
           "    if vehicle is None:\n"
           "        pass\n"
           "    if self._inputs is not None:\n"
           "        pass\n"
           "    return is_paper_aircraft(vehicle)\n"
           "def g(x):\n"
           "    return x is None or x.vehicle.name\n"
           "def h(service):\n"
           "    return service.vehicle or PRESETS['edge540']\n")
    assert branches(src) == [2, 4, 6, 10]


@pytest.mark.parametrize("module", sorted(set(found()) | set(ALLOWED)))
def test_no_new_branch_on_the_paper_aircraft_or_a_missing_vehicle(module):
    lines = found().get(module, [])
    allowed = ALLOWED.get(module, 0)
    assert len(lines) <= allowed, (
        f"gcs_pdm/{module} branches on the paper aircraft or on a missing vehicle at lines {lines} "
        f"({len(lines)}, allowed {allowed}): take a vehicle description (the paper's aircraft is the "
        f"edge540 preset) and resolve 'no vehicle' at the command line or the service's entry point")
