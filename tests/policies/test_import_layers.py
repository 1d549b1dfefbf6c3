"""The import graph of ``policies/``, read from the source with ``ast``: no circles, and
imports flow one way, experiments -> learning -> scripted (``policies.episode`` below all).

Every ``import`` / ``from ... import`` counts, those inside functions included.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "policies"
# layer -> the layers it must never import
FORBIDDEN = {
    "scripted": {"learning", "experiments"},
    "learning": {"experiments"},
    "episode": {"scripted.registry", "learning", "experiments"},
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """``module -> the policies modules it imports`` for every module of ``policies/``."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        edges: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                # `from policies.x import y` imports policies.x.y when y is a module
                targets = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
            else:
                continue
            edges |= {t for t in targets if t in modules and t != name}
        graph[name] = edges
    return graph


def _layer(module: str) -> str:
    return module.removeprefix("policies.")


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle of ``graph`` (a module list), or ``None``."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_policies_has_no_import_circles():
    graph = import_graph()
    assert "policies.learning.loader" in graph and "policies.scripted.wander" in graph
    assert _cycle(graph) is None, _cycle(graph)


def test_the_circle_finder_finds_one():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


def test_layers_import_one_way():
    bad = []
    for module, edges in import_graph().items():
        for layer, forbidden in FORBIDDEN.items():
            if _layer(module) == layer or _layer(module).startswith(layer + "."):
                bad += [(module, e) for e in sorted(edges)
                        if any(_layer(e) == f or _layer(e).startswith(f + ".") for f in forbidden)]
    assert bad == []
