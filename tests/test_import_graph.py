"""No import cycles in gcs_pdm: the module graph, built from every ``import`` in the source (module
level and function-local alike: a local import only hides a cycle), is acyclic; and the packages
(``gcs_pdm.<name>``) import one way, down the layers of ``LAYERS`` (docs/architecture.md)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "gcs_pdm"


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    files = {module_name(p, root): p for p in root.rglob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in files}
    for mod, path in files.items():
        package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    base = ".".join(anchor + ([base] if base else []))
                # ``from pkg import sub`` imports the submodule; ``from mod import name`` the module
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in files else base for a in node.names]
            for t in targets:
                while t and t not in files:  # ``import gcs_pdm.a.b.c`` where c is a name: its module
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle (as a path that ends where it starts), or None."""
    colour: dict[str, int] = {}  # 1: on the current path, 2: done
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        colour[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if colour.get(n) == 1:
                return stack[stack.index(n):] + [n]
            if n not in colour and (found := visit(n)):
                return found
        stack.pop()
        colour[m] = 2
        return None

    for m in sorted(graph):
        if m not in colour and (found := visit(m)):
            return found
    return None


def test_the_finder_sees_function_local_cycles(tmp_path):
    pkg = tmp_path / "gcs_pdm"
    (pkg / "a").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a" / "__init__.py").write_text("")
    (pkg / "a" / "x.py").write_text("from gcs_pdm.a.y import f\n")
    (pkg / "a" / "y.py").write_text("def f():\n    from . import x\n")
    (pkg / "a" / "z.py").write_text("import gcs_pdm.a.x\n")
    graph = import_graph(pkg)
    assert graph["gcs_pdm.a.x"] == {"gcs_pdm.a.y"} and graph["gcs_pdm.a.y"] == {"gcs_pdm.a.x"}
    assert find_cycle(graph) in (["gcs_pdm.a.x", "gcs_pdm.a.y", "gcs_pdm.a.x"],
                                 ["gcs_pdm.a.y", "gcs_pdm.a.x", "gcs_pdm.a.y"])
    (pkg / "a" / "y.py").write_text("def f():\n    pass\n")
    assert find_cycle(import_graph(pkg)) is None


@pytest.fixture(scope="module")
def gcs_graph() -> dict[str, set[str]]:
    """gcs_pdm's module graph, parsed once for the tests below (a few seconds)."""
    return import_graph()


def test_gcs_pdm_has_no_import_cycle(gcs_graph):
    graph = gcs_graph
    assert len(graph) > 50 and graph["gcs_pdm.service.live"]
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


# --- packages ---------------------------------------------------------------------------------------

#: The intended layers, lowest first: a package (``gcs_pdm.<name>``, or a top-level module) imports only
#: from layers below its own, never from its own layer's other members nor from above. Within a layer
#: the members are independent of one another.
LAYERS: list[tuple[str, ...]] = [
    # process-wide utilities: import nothing of gcs_pdm (compiled runs the warm-up groups it is given)
    ("gcs_pdm", "command_errors", "process_gc", "process_threads", "compiled"),
    ("models", "geo", "missions"),           # data and physics: parameter sets, kernels, geodesy, missions
    ("frames",),                             # the telemetry frames (their values' units come from models)
    ("vehicle",),                            # the vehicle description (data) and what a model needs of it
    ("mavlink",),                            # MAVLink I/O: the link, tlogs, frame mapping
    ("logs",),                               # autopilot logs (.bin, .ulg), read into flight tables and frames
    ("estimation",),                         # state estimation and prediction
    ("diagnosis",),                          # faults and prognosis from the estimator
    ("sim",),                                # the simulated vehicle (its truth is what planning and fits test on)
    ("fitting", "planning"),                 # parameter fits; the planner
    ("replay",),                             # recorded flights through the core, the replay command
    ("packs",),                              # pack records across flights
    ("service",),                            # the live service: wires frames to the core
    ("cli", "vehicle_cli", "packs_cli"),     # entry points
]


def package_of(module: str) -> str:
    """``gcs_pdm.a.b`` -> ``a``; a top-level module is its own package; the root is ``gcs_pdm``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def package_graph(graph: dict[str, set[str]]) -> dict[str, dict[str, set[str]]]:
    """package -> imported package -> the module edges behind it (``a.x -> b.y``)."""
    out: dict[str, dict[str, set[str]]] = {}
    for mod, targets in graph.items():
        src = package_of(mod)
        out.setdefault(src, {})
        for t in targets:
            if (dst := package_of(t)) != src:
                out[src].setdefault(dst, set()).add(f"{mod} -> {t}")
    return out


def layer_violations(graph: dict[str, set[str]], layers: list[tuple[str, ...]]) -> list[str]:
    """Each package edge that does not run to a lower layer, with the module imports behind it."""
    rank = {p: i for i, layer in enumerate(layers) for p in layer}
    out = []
    for src, targets in sorted(package_graph(graph).items()):
        for dst, edges in sorted(targets.items()):
            if rank[dst] >= rank[src]:
                out.append(f"{src} (layer {rank[src]}) imports {dst} (layer {rank[dst]}): {'; '.join(sorted(edges))}")
    return out


def test_every_package_has_a_layer(gcs_graph):
    placed = [p for layer in LAYERS for p in layer]
    assert len(placed) == len(set(placed))
    assert set(package_graph(gcs_graph)) == set(placed), "place a new package in LAYERS"


def test_packages_import_only_from_lower_layers(gcs_graph):
    graph = gcs_graph
    packages = {src: set(dst) for src, dst in package_graph(graph).items()}
    assert find_cycle(packages) is None, " -> ".join(find_cycle(packages))
    assert layer_violations(graph, LAYERS) == []


def test_the_layer_check_sees_an_upward_function_local_import(tmp_path):
    pkg = tmp_path / "gcs_pdm"
    for sub in ("low", "high"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "high" / "h.py").write_text("from gcs_pdm.low import l\n")
    (pkg / "low" / "l.py").write_text("def f():\n    from gcs_pdm.high.h import x\n")
    layers = [("gcs_pdm",), ("low",), ("high",)]
    assert layer_violations(import_graph(pkg), layers) == [
        "low (layer 1) imports high (layer 2): gcs_pdm.low.l -> gcs_pdm.high.h"]
    (pkg / "low" / "l.py").write_text("def f():\n    pass\n")
    assert layer_violations(import_graph(pkg), layers) == []
