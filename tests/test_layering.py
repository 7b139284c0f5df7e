"""The rooms of wftool and the one direction their imports run (docs/design.md, "Rooms").

Every import of a wftool module anywhere in the package counts, in a function or under
TYPE_CHECKING too: a module may import its own room and the rooms of lower layers, never
a room of its own layer (sideways) or above; and no modules import each other in a circle.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

PACKAGE = Path(__file__).parent.parent / "wftool"

LAYERS: tuple[tuple[str, ...], ...] = (
    ("wftool",),  # the package itself: __version__
    ("errors",),
    ("extras", "progress", "interrupts", "display", "stats"),
    ("link",),  # the byte transport and the CRC both protocols share
    ("fsp",),  # the OBC library
    ("fc",),
    ("firmware", "recording", "sitl"),  # firmware: MCU names per Betaflight version (fc)
    ("flash", "verify", "ros2", "preflight"),  # ros2: the live ROS 2 node; preflight: a board's
    ("analysis", "bench"),
    ("doctor", "paper"),
    ("cli",),
    ("__main__",),
)
"""Bottom to top: a room imports only from layers below its own."""

LAYER = {room: level for level, rooms in enumerate(LAYERS) for room in rooms}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def room_of(module: str) -> str:
    """`wftool.fsp.decoder` is in `fsp`, `wftool.paper` in `paper`, `wftool` in `wftool`."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def imports_of(path: Path, modules: Iterable[str]) -> set[str]:
    """The wftool modules `path` imports, anywhere in it; `from pkg import name` is the
    module `pkg.name` when there is one."""
    known = set(modules)
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: a relative import (wftool imports absolutely)"
            assert node.module is not None
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                found.add(submodule if submodule in known else node.module)
    return {name for name in found if name.split(".")[0] == "wftool"}


def import_graph() -> dict[str, set[str]]:
    paths = {module_name(path): path for path in PACKAGE.rglob("*.py")}
    return {module: imports_of(path, paths) for module, path in paths.items()}


def against_direction(graph: Mapping[str, Iterable[str]]) -> list[str]:
    """Every import of another room that is not of a lower layer, as "a -> b (rooms)"."""
    wrong = []
    for module, imported in graph.items():
        room = room_of(module)
        for target in imported:
            other = room_of(target)
            if other != room and not LAYER[other] < LAYER[room]:
                wrong.append(f"{module} -> {target} ({room} -> {other})")
    return sorted(wrong)


def cycles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in graph.get(node, ()):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                other = stack.pop()
                on_stack.discard(other)
                component.append(other)
                if other == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def rooms(graph: Mapping[str, Iterable[str]]) -> dict[str, set[str]]:
    """The graph between rooms."""
    between: dict[str, set[str]] = {room_of(module): set() for module in graph}
    for module, imported in graph.items():
        between[room_of(module)].update(
            room_of(t) for t in imported if room_of(t) != room_of(module)
        )
    return between


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph()


def test_every_room_is_declared(graph):
    assert {room_of(module) for module in graph} <= set(LAYER)


def test_imports_run_one_way(graph):
    assert against_direction(graph) == []


def test_no_modules_import_each_other_in_a_circle(graph):
    assert cycles(graph) == []


def test_no_rooms_import_each_other_in_a_circle(graph):
    assert cycles(rooms(graph)) == []


def test_the_checks_see_a_wrong_import_and_a_circle():
    """The checks themselves, on made-up graphs: the OBC library importing the FC tooling,
    two rooms of one layer, and a circle of three modules."""
    assert against_direction({"wftool.fsp.reader": {"wftool.fc.transport"}}) == [
        "wftool.fsp.reader -> wftool.fc.transport (fsp -> fc)"
    ]
    assert against_direction({"wftool.verify.x": {"wftool.ros2.y"}}) != []
    assert against_direction({"wftool.verify.x": {"wftool.recording.y", "wftool.verify.z"}}) == []
    circle = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert cycles(circle) == [["a", "b", "c"]]
