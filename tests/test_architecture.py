"""The import structure of ``pgt_check``: no cycles (imports inside functions count too), and the
pipeline layers point one way (see docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "pgt_check"

#: layer of each top-level part; a module may import only its own layer or lower ones
LAYERS = {
    "errors": 0, "common": 0, "types": 0, "config": 0, "constants": 0, "registry": 0,
    "progress": 0, "threads": 0, "output_layout": 0,
    "io": 1, "render": 1, "match": 1, "geometry": 1, "enhance": 1,
    "measure": 2,
    "verdict": 3,
    "store": 3, "content_hash": 3, "ownership": 3, "records_file": 3,
    "correct": 4,
    "report": 5,
    "executor": 6, "stages": 6, "runner": 6, "rejudge": 6,
    "cli": 7, "commands": 7, "__main__": 7, "api": 7,
}


def _module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def import_graph() -> dict[str, set[str]]:
    """module -> pgt_check modules it imports anywhere in its file (TYPE_CHECKING included)."""
    modules = {_module_name(p): p for p in PKG.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            for t in targets:
                if t in modules and t != name:
                    deps.add(t)
        graph[name] = deps
    return graph


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_no_import_cycles():
    graph = import_graph()
    # parent packages are imported with their children; an edge to a package's __init__ is an
    # edge to that module only (what Python executes), so plain DFS over the module graph
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_layers_point_one_way():
    graph = import_graph()
    bad = []
    for m, deps in graph.items():
        lm = LAYERS.get(_part(m))
        if lm is None:
            continue
        for d in deps:
            ld = LAYERS.get(_part(d))
            if ld is not None and ld > lm:
                bad.append(f"{m} ({_part(m)}, layer {lm}) imports {d} (layer {ld})")
    assert not bad, "\n".join(sorted(bad))


def test_every_part_has_a_layer():
    parts = {_part(m) for m in import_graph()} - {"__init__"}
    assert parts <= set(LAYERS), sorted(parts - set(LAYERS))


def test_package_holds_no_test_scaffolding():
    """Test and benchmark helpers live outside the package (``pgt_eval``, ``tests/``,
    ``benchmarks/``): nothing in ``pgt_check`` imports them."""
    bad = []
    for path in PKG.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            bad += [f"{path.relative_to(PKG.parent)} imports {n}" for n in names
                    if n.split(".")[0] in ("pgt_eval", "tests", "benchmarks")]
    assert not bad, "\n".join(bad)
    assert not (PKG / "evaluation.py").exists()
