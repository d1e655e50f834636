"""The package's shape: imports run down the stages, no cycles, SQL only in labels/.

Read from the source with ``ast`` (nothing is imported), so a new module is checked the
moment it exists.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "vgm_studio"
# Each top-level part of the package and its stage: a part imports only parts of lower
# stages (README's package map, bottom to top).
STAGES = {
    "core": 0,
    "errors": 0,
    "atomic": 0,
    "progress": 0,
    "processes": 0,
    "datasets": 1,
    "maps": 1,
    "simulation": 2,
    "matching": 2,
    "graph": 2,
    "labels": 3,
    "vgm": 3,
    "model": 4,
    "trainer": 5,
    "slam": 5,
    "workspace": 6,
    "audit": 6,
    "compare": 6,
    "recording": 6,
    "studio": 7,
    "services": 7,
    "tools": 8,
}


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _typing_only(tree: ast.AST) -> set[int]:
    """Nodes under ``if TYPE_CHECKING:``: imports for annotations, never run."""
    inside: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                inside.update(id(n) for n in ast.walk(child))
    return inside


def _imports(path: Path) -> set[str]:
    """Every ``vgm_studio`` module ``path`` imports when it runs, at any depth of the file."""
    found = set()
    tree = ast.parse(path.read_text())
    skip = _typing_only(tree)
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return found


def _graph() -> dict[str, set[str]]:
    modules = {_module(p): p for p in PACKAGE.rglob("*.py")}
    return {
        name: {m for m in _imports(path) if m in modules and m != name}
        for name, path in modules.items()
    }


def _part(module: str) -> str:
    return module.split(".")[1] if "." in module else ""


def test_imports_run_down_the_stages():
    graph = _graph()
    assert set(STAGES) == {_part(m) for m in graph if _part(m)}, "a part without a stage"
    upward = [
        f"{a} -> {b}"
        for a, targets in graph.items()
        for b in targets
        if _part(a) and _part(b) and _part(a) != _part(b) and STAGES[_part(a)] <= STAGES[_part(b)]
    ]
    assert upward == []


def test_no_module_imports_itself_through_others():
    graph = _graph()
    # Each package's __init__ re-exports its modules; an arrow into a face is no cycle.
    faces = {m for m in graph if (PACKAGE.parent / m.replace(".", "/") / "__init__.py").exists()}
    edges = {a: {b for b in targets if b not in faces} for a, targets in graph.items()}
    state: dict[str, int] = {}
    cycles: list[str] = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join([*path[path.index(nxt) :], nxt]))
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = 2

    for start in sorted(edges):
        if start not in state:
            visit(start, [start])
    assert cycles == []


def test_sql_lives_in_labels_only():
    # ROS 2 bags are SQLite files: reading them (and naming their errors) is a log format's
    # business, not our store's.
    allowed = {"vgm_studio.datasets.rosbag", "vgm_studio.datasets.bag_errors"}
    users = {
        _module(p)
        for p in PACKAGE.rglob("*.py")
        if {"sqlite3", "psycopg"} & set(_imports(p)) and _part(_module(p)) != "labels"
    }
    assert users <= allowed


def test_benchmarks_and_the_trainer_process_do_not_import_the_command_line():
    importers = [
        p.name
        for p in [*(REPO / "benchmarks").glob("*.py"), *(PACKAGE / "trainer").glob("*.py")]
        if any(m.startswith("vgm_studio.tools") for m in _imports(p))
    ]
    assert importers == []
