"""The house's rule, checked on the code: imports between the package's rooms (subpackages and top-level
modules) form no circle, so every import points down the layers of docs/architecture.md."""
from __future__ import annotations

import ast
from pathlib import Path

import lunaralbedo

ROOT = Path(lunaralbedo.__file__).parent


def _room(module: str) -> str:
    """``lunaralbedo.engine.solve`` -> ``engine``; ``lunaralbedo.settings`` -> ``settings``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _imports(path: Path) -> set[str]:
    """Modules of the package that ``path`` imports (absolute names), function-level imports included."""
    rel = path.relative_to(ROOT.parent).with_suffix("")
    here = list(rel.parts[:-1])  # the package a relative import starts from (also for an __init__)
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - (node.level - 1)] if node.level > 1 else here
                name = ".".join(base + ([node.module] if node.module else []))
                names = [name] if node.module else [f"{name}.{a.name}" for a in node.names]
            else:
                names = [node.module or ""]
            found.update(n for n in names if n.startswith("lunaralbedo"))
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("lunaralbedo"))
    return found


def room_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        if rel.parts[-1] == "__main__":
            continue  # the entry points (python -m) sit above every room
        src = _room(".".join(rel.parts))
        for target in _imports(path):
            dst = _room(target)
            if dst != src and dst not in ("lunaralbedo", "__init__"):
                graph.setdefault(src, set()).add(dst)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


def test_the_rooms_import_in_no_circle():
    graph = room_graph()
    assert {"engine", "model", "cli", "io"} <= set(graph)  # the graph was read
    assert _cycle(graph) is None, " -> ".join(_cycle(graph))


def test_the_bottom_floors_import_nothing_above_them():
    graph = room_graph()
    for low in ("errors", "constants", "simd"):
        assert not graph.get(low, set()) - {"errors", "constants"}, (low, graph.get(low))
    assert graph.get("model", set()) <= {"errors", "constants"}, graph.get("model")  # pure math: no I/O, no engine
    assert "cli" not in set().union(*graph.values())  # nothing imports the command line


def test_the_checker_sees_a_circle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
