# SPDX-License-Identifier: Apache-2.0
"""The package's shape: layers that import only those beneath them, no import circle,
no private name imported across modules, no module past ~500 lines.

Layers, lowest first: errors (and the allocator helper) -> numerics -> io -> live ->
diagnosis -> app (a request in, a result out) -> adapters (ros/, view/, cli, batch, plots,
paper, htmlreport). Inside numerics and
diagnosis, rooms (subpackages: numerics/local, lifted, excitation, systems; diagnosis/
criterion, causes, selection, controller, monitoring) belong to their layer; their
``__init__`` imports nothing. A module may import modules of its own layer or lower ones
(type-only imports may reach higher); within a layer the imports, type-only ones included,
form no circle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "mr_ident"
MAX_LINES = 520

LAYERS = {
    "errors": 0,
    "allocator": 0,
    "version": 0,
    "numerics": 1,
    "io": 2,
    "live": 3,
    "diagnosis": 4,
    "app": 5,
}
ADAPTER = 6


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def layer(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1:  # mr_ident/__init__: lazy exports of every layer
        return ADAPTER + 1
    return LAYERS.get(parts[1], ADAPTER)


def imports(module: str) -> list[tuple[str, list[str], bool]]:
    """(imported module, names, inside TYPE_CHECKING) for every import of this package."""
    path = MODULES[module]
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    typing_only: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            typing_only.update(id(n) for n in ast.walk(node))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] != "mr_ident":
                continue
            names = [a.name for a in node.names]
            # "from . import batched" imports a module, not a name
            if node.module is None or f"{target}.{names[0]}" in MODULES:
                for n in names:
                    out.append((f"{target}.{n}", [], id(node) in typing_only))
            else:
                out.append((target, names, id(node) in typing_only))
        elif isinstance(node, ast.Import):
            out += [
                (a.name, [], id(node) in typing_only)
                for a in node.names
                if a.name.startswith("mr_ident")
            ]
    return out


def test_every_module_imports_only_its_own_layer_or_those_beneath():
    wrong = []
    for m in MODULES:
        for target, _, typing_only in imports(m):
            if not typing_only and layer(target) > layer(m):
                wrong.append(f"{m} (layer {layer(m)}) imports {target} (layer {layer(target)})")
    assert not wrong, "\n".join(wrong)


def test_no_import_circle():
    # type-only imports (under TYPE_CHECKING) count too: a circle there is a circle in design
    graph = {m: {t for t, _, _ in imports(m) if t in MODULES} for m in MODULES}
    state: dict[str, int] = {}
    circles = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for t in graph[m]:
            if t == m or (m.startswith(t + ".") and MODULES[t].name == "__init__.py"):
                continue  # a package's own __init__ (its parent) is not a circle
            if state.get(t) == 1:
                circles.append(" -> ".join(stack[stack.index(t) :] + [t]))
            elif t not in state:
                visit(t, stack + [t])
        state[m] = 2

    for m in MODULES:
        if m not in state:
            visit(m, [m])
    assert not circles, "\n".join(circles)


def test_no_private_name_is_imported_across_modules():
    wrong = [
        f"{m} imports {n} from {t}"
        for m in MODULES
        for t, names, _ in imports(m)
        for n in names
        if n.startswith("_") and not n.endswith("__")
    ]
    assert not wrong, "\n".join(wrong)


def test_the_rooms_of_a_layer_import_nothing_up_front():
    """A room (numerics/local, diagnosis/causes, ...) is a docstring: importing one module of
    it must not load its neighbours (start-up, test_cli)."""
    rooms = [
        m
        for m, p in MODULES.items()
        if p.name == "__init__.py" and m.startswith(("mr_ident.numerics.", "mr_ident.diagnosis."))
    ]
    assert "mr_ident.numerics.local" in rooms and "mr_ident.diagnosis.causes" in rooms
    wrong = [
        m
        for m in rooms
        if any(
            isinstance(n, (ast.Import, ast.ImportFrom))
            for n in ast.walk(ast.parse(MODULES[m].read_text()))
        )
    ]
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_is_past_about_500_lines(module):
    n = len(MODULES[module].read_text().splitlines())
    assert n <= MAX_LINES, f"{module} has {n} lines"


def test_only_the_ros_adapters_import_ros():
    ros = (
        "rclpy",
        "std_msgs",
        "sensor_msgs",
        "diagnostic_msgs",
        "rcl_interfaces",
        "rosidl_runtime_py",
    )
    wrong = []
    for m, path in MODULES.items():
        if m.startswith("mr_ident.ros"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and not node.level
                else []
            )
            wrong += [f"{m} imports {n}" for n in names if n.split(".")[0] in ros]
    assert not wrong, "\n".join(wrong)
