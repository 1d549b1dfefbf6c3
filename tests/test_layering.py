"""The package's layering, checked from the source: imports flow one way, no module imports
another's private names or reads another object's private attributes, and no import circle.

The layers, bottom up: ``estimators`` (the library, runs on robot logs), ``coop_loc_env`` (the
environment), ``policies`` (``scripted`` <- ``learning`` <- ``experiments``), ``scripts``.
Imports inside functions count as much as those at the top: a lazy import still ties two files.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("estimators", "coop_loc_env", "policies", "scripts", "hydra_plugins")

#: Which layers a layer may import (itself included). A sub-layer is named by its dotted prefix;
#: the longest matching prefix decides.
MAY_IMPORT = {
    "estimators": {"estimators"},
    "coop_loc_env": {"estimators", "coop_loc_env"},
    "hydra_plugins": {"hydra_plugins", "coop_loc_env"},
    # policies/*.py beside the three rooms: the package's exports and the episode loop
    # (learning's periodic evaluation runs it), over the scripted controllers.
    "policies": {"estimators", "coop_loc_env", "policies", "policies.scripted"},
    "policies.scripted": {"estimators", "coop_loc_env", "policies", "policies.scripted"},
    "policies.learning": {"estimators", "coop_loc_env", "policies", "policies.scripted",
                          "policies.learning"},
    "policies.experiments": {"estimators", "coop_loc_env", "policies", "policies.scripted",
                             "policies.learning", "policies.experiments"},
    "scripts": {"estimators", "coop_loc_env", "policies", "policies.scripted",
                "policies.learning", "policies.experiments", "scripts"},
}

#: Modules allowed to reach into a third-party library's private attributes, and why.
THIRD_PARTY_PRIVATES = {
    # pymunk's batch API and the Chipmunk structs behind it: the world's fast path reads them
    # in this one module, which checks the layout it relies on when it is imported.
    "coop_loc_env.chipmunk_raw",
}


@dataclass(frozen=True)
class Module:
    name: str
    path: Path
    tree: ast.Module

    @property
    def package(self) -> str:
        return self.name if self.path.name == "__init__.py" else self.name.rpartition(".")[0]


def _modules() -> dict[str, Module]:
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            name = ".".join(parts)
            modules[name] = Module(name, path, ast.parse(path.read_text(), str(path)))
    return modules


MODULES = _modules()


def _imports(module: Module) -> Iterator[tuple[int, str, str | None]]:
    """``(line, imported module, imported name or None)`` of every import in ``module``."""
    for node in ast.walk(module.tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, None
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                levels = module.package.split(".")
                parent = levels[: len(levels) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            for alias in node.names:
                yield node.lineno, base, alias.name


def _project_targets(module: Module) -> Iterator[tuple[int, str]]:
    """The project modules ``module`` imports (a ``from package import submodule`` names the
    submodule)."""
    for line, base, name in _imports(module):
        if name is not None and f"{base}.{name}" in MODULES:
            yield line, f"{base}.{name}"
        elif base in MODULES:
            yield line, base


def _layer(name: str) -> str:
    return max((layer for layer in MAY_IMPORT if name == layer or name.startswith(layer + ".")),
               key=len)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_every_project_module_is_in_a_layer():
    assert len(MODULES) > 100
    for name in MODULES:
        assert _layer(name) in MAY_IMPORT


def test_imports_flow_one_way():
    wrong = []
    for module in MODULES.values():
        allowed = MAY_IMPORT[_layer(module.name)]
        for line, target in _project_targets(module):
            if _layer(target) not in allowed:
                wrong.append(f"{module.path.relative_to(ROOT)}:{line} imports {target}")
    assert not wrong, "imports against the layers:\n" + "\n".join(wrong)


def test_no_import_circle():
    graph = {name: {t for _, t in _project_targets(m) if t != name} for name, m in MODULES.items()}
    circles = _strongly_connected(graph)
    assert not circles, "import circles:\n" + "\n".join(" <-> ".join(sorted(c)) for c in circles)


def test_no_private_name_is_imported_from_another_module():
    wrong = []
    for module in MODULES.values():
        for line, base, name in _imports(module):
            if base.split(".")[0] not in PACKAGES:
                continue
            where = f"{module.path.relative_to(ROOT)}:{line}"
            if name is not None and _is_private(name):
                wrong.append(f"{where} imports {name} from {base}")
            elif _layer(base).split(".")[0] != _layer(module.name).split(".")[0] and any(
                    _is_private(part) for part in base.split(".")):
                wrong.append(f"{where} imports the private module {base} of another layer")
    assert not wrong, "\n".join(wrong)


def _own_private_names(module: Module) -> set[str]:
    """The private attributes and methods ``module`` itself defines: assigned on ``self`` or
    ``cls``, or defined in a class body. Reading one of these on another instance of the
    module's own class (``other._x`` in ``__eq__``, a copy being built) is the module's own
    business."""
    names = set()
    for node in ast.walk(module.tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and isinstance(
                node.value, ast.Name) and node.value.id in ("self", "cls"):
            names.add(node.attr)
        elif isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    names.add(item.name)
                elif isinstance(item, ast.Assign):
                    names.update(t.id for t in item.targets if isinstance(t, ast.Name))
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    names.add(item.target.id)
    return {name for name in names if _is_private(name)}


def test_no_private_attribute_of_another_object_is_read():
    wrong = []
    for module in MODULES.values():
        if module.name in THIRD_PARTY_PRIVATES:
            continue
        own = _own_private_names(module)
        for node in ast.walk(module.tree):
            if not (isinstance(node, ast.Attribute) and _is_private(node.attr)):
                continue
            owner = node.value
            if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
                continue
            if isinstance(owner, ast.Call) and getattr(owner.func, "id", None) == "super":
                continue
            if node.attr in own:
                continue
            wrong.append(f"{module.path.relative_to(ROOT)}:{node.lineno} "
                         f"{ast.unparse(owner)}.{node.attr}")
    assert not wrong, "private attributes read from outside their object:\n" + "\n".join(wrong)


def test_the_checks_catch_what_they_look_for():
    assert _strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [
        {"a", "b", "c"}]
    assert _strongly_connected({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert _layer("policies.scripted.fsm") == "policies.scripted"
    assert "policies.experiments" not in MAY_IMPORT[_layer("policies.learning.training")]
    sample = ast.parse("class A:\n    _k = 1\n    def __init__(self):\n        self._x = 0\n"
                       "    def _f(self):\n        pass\n")
    assert _own_private_names(Module("m", ROOT / "m.py", sample)) == {"_k", "_x", "_f"}


def _strongly_connected(graph: dict[str, set[str]]) -> list[set[str]]:
    """The components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[set[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph.get(root, ())))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(graph.get(child, ()))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(component)
    return found
