"""No import cycles in gcs_pdm: the module graph, built from every ``import`` in the source (module
level and function-local alike: a local import only hides a cycle), is acyclic."""
from __future__ import annotations

import ast
from pathlib import Path

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


def test_gcs_pdm_has_no_import_cycle():
    graph = import_graph()
    assert len(graph) > 50 and graph["gcs_pdm.service.live"]
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))
