"""The floor plan of docs/architecture.md holds: every import (module-level or inside a function) points to a
lower floor or stays in its own folder, and no modules import each other in a cycle."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "simshear_gym"

# Floors, bottom to top; the same table is drawn in docs/architecture.md. A room is a sub-package or a
# top-level module of simshear_gym.
FLOORS: tuple[tuple[str, ...], ...] = (
    ("io", "transforms", "tables", "machine", "command_line"),
    ("data",),
    ("robots", "models"),
    ("sim",),
    ("contract",),
    ("envs", "control"),
    ("real",),
    ("train", "lab"),
    ("evaluate",),
    ("pipelines",),
    ("ship",),
    ("demo", "cli"),
)
FLOOR = {room: level for level, rooms in enumerate(FLOORS) for room in rooms}


def _modules() -> dict[str, Path]:
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        modules[name] = path
    return modules


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the package modules it imports anywhere in its body."""
    edges: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = name.split(".") if is_package else name.split(".")[:-1]
                    anchor = anchor[:len(anchor) - (node.level - 1)]
                    base = ".".join(anchor + ([base] if base else []))
                targets = [base] + [f"{base}.{alias.name}" for alias in node.names]
            else:
                continue
            for target in targets:
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target not in (name, "simshear_gym"):
                    edges[name].add(target)
    return edges


def _room(module: str) -> str:
    return module.split(".")[1]


def test_every_room_has_a_floor():
    rooms = {_room(name) for name in _modules() if name != "simshear_gym"}
    assert rooms <= set(FLOOR), f"rooms without a floor in FLOORS (and docs/architecture.md): {rooms - set(FLOOR)}"


def test_imports_point_down_or_stay_in_their_room():
    upward = sorted(
        f"{source} -> {target}"
        for source, targets in _imports(_modules()).items() for target in targets
        if _room(source) != _room(target) and FLOOR[_room(target)] >= FLOOR[_room(source)]
    )
    assert not upward, "imports that point up or sideways:\n" + "\n".join(upward)


def test_no_import_cycle():
    edges = _imports(_modules())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in edges.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for module in _modules():
        if module not in index:
            visit(module)
    assert not cycles, f"import cycles: {cycles}"


def test_architecture_doc_draws_the_same_floors():
    doc = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    for level, rooms in enumerate(FLOORS):
        row = f"| {level} | " + ", ".join(f"`{room}`" for room in rooms) + " |"
        assert row in doc, f"docs/architecture.md lacks the floor row {row!r}"
