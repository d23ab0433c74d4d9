"""The package's import graph, read from the source: no cycles, the vision core free of I/O, the simulator and the
dashboard free of the appliance, and every module short enough to read.

Every ``import`` statement counts, including those inside functions (a lazy import is still a dependency) and those
under ``if TYPE_CHECKING:`` (a type a module names is a dependency for its reader, even when it never runs).
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

import pytest

EDGE = Path(__file__).resolve().parent.parent / "edge"

# The vision core: pure functions and small types over numpy arrays, the tracker's interface and configuration, the
# edge fits of the centre offsets, the pose-publishing rule, and the clock and errors they share.
CORE = (
    "edge.segmentation",
    "edge.background",
    "edge.coverage",
    "edge.blob_shape",
    "edge.filtering",
    "edge.two_tone",
    "edge.trackers",
    "edge.calibration",
    "edge.camera",
    "edge.messages",
    "edge.board_messages",
    "edge.contract",
    "edge.tracking",
    "edge.tracker_config",
    "edge.pipeline",
    "edge.acquisition",
    "edge.rover_track",
    "edge.area_checks",
    "edge.white",
    "edge.outline",
    "edge.centre_offsets",
    "edge.fit_worker",
    "edge.pooled_fits",
    "edge.orphans",
    "edge.edges_encoded",
    "edge.edges_held",
    "edge.poses",
    "edge.camera_controls",
    "edge.clock",
    "edge.errors",
)
# What the core must not reach, even indirectly: frame sources, the appliance, networking, the simulator, the UI.
NOT_IN_CORE = (
    "edge.sources",
    "edge.source_spec",
    "edge.capture",
    "edge.runtime",
    "edge.appliance",
    "edge.publisher",
    "edge.mqttclient",
    "edge.commands",
    "edge.broker",
    "edge.httpserver",
    "edge.sim",
    "edge.dashboard",
    "edge.cli",
    "edge.fusion",
    "edge.recording",
    "edge.httpguard",
    "edge.metrics",
    "edge.doctor",
    "edge.enroll",
    "edge.flashing",
    "edge.rover_host",
    "edge.offline",
    "edge.v4l2",
    "paho",
    "amqtt",
    "aiohttp",
    "click",
)
# The appliance's assembly and its command line: what the simulator and the dashboard must not reach.
APPLIANCE = ("edge.runtime", "edge.appliance", "edge.cli")

MAX_LINES = 450


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


@cache
def modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for path in sorted(EDGE.rglob("*.py")):
        parts = list(path.relative_to(EDGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


@cache
def imports(module: str, type_checking: bool) -> frozenset[str]:
    """Names ``module`` imports: an edge module where the import names one, else the top-level package."""
    path = modules()[module]
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found: set[str] = set()

    def target(name: str) -> str:
        return name if name in modules() or not name.startswith("edge.") else name.rsplit(".", 1)[0]

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test) and not type_checking:
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.Import):
            found.update(target(alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package[: len(package) - node.level + 1]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            for alias in node.names:
                full = f"{base}.{alias.name}"
                found.add(full if full in modules() else target(base))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    found.discard(module)
    return frozenset(found)


def reachable(module: str, type_checking: bool = True) -> set[str]:
    """Everything ``module`` imports, directly or through other edge modules."""
    seen: set[str] = set()
    todo = [module]
    while todo:
        for name in imports(todo.pop(), type_checking):
            if name not in seen:
                seen.add(name)
                if name in modules():
                    todo.append(name)
    return seen


def cycles(type_checking: bool) -> list[list[str]]:
    """The import graph's cycles: its strongly connected components of more than one module (Tarjan)."""
    graph = {m: sorted(i for i in imports(m, type_checking) if i in modules()) for m in modules()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in graph:
        if v not in index:
            strong(v)
    return found


def test_the_reader_sees_every_module_and_its_imports() -> None:
    assert {"edge.pipeline", "edge.trackers", "edge.trackers.paper", "edge.sim.loop"} <= set(modules())
    assert "edge.trackers.base" in imports("edge.pipeline", False)
    assert "edge.dashboard" in imports("edge.appliance", False)  # a lazy import inside a function counts
    assert "edge.broker.embedded" in imports("edge.appliance", True)  # under TYPE_CHECKING
    assert "edge.broker.embedded" not in imports("edge.appliance", False)


def test_every_module_the_rules_name_is_in_the_package() -> None:
    """A module renamed or moved leaves no rule checking nothing."""
    named = [*CORE, *(n for n in NOT_IN_CORE if n.startswith("edge.")), *APPLIANCE]
    assert [n for n in named if not any(_within(m, (n,)) for m in modules())] == []


@pytest.mark.parametrize("type_checking", [False, True], ids=["at run time", "counting TYPE_CHECKING imports"])
def test_no_module_imports_itself_back_through_others(type_checking: bool) -> None:
    assert cycles(type_checking) == []


def test_the_runtime_knows_nothing_of_the_dashboard_nor_of_its_own_assembly() -> None:
    reached = reachable("edge.runtime")
    assert sorted(n for n in reached if _within(n, ("edge.dashboard", "edge.appliance", "edge.cli"))) == []


@pytest.mark.parametrize("module", [m for m in sorted(modules()) if _within(m, ("edge.sim", "edge.dashboard"))])
def test_the_simulator_and_the_dashboard_do_not_reach_the_appliance(module: str) -> None:
    reached = reachable(module)
    assert sorted(n for n in reached if _within(n, APPLIANCE)) == []


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def test_no_module_is_over_450_lines() -> None:
    over = {str(path.relative_to(EDGE.parent)): _lines(path) for path in modules().values() if _lines(path) > MAX_LINES}
    assert over == {}, f"over {MAX_LINES} lines: {over}"


@pytest.mark.parametrize("module", [m for m in sorted(modules()) if _within(m, CORE)])
def test_the_vision_core_does_no_io_and_knows_no_appliance(module: str) -> None:
    reached = reachable(module)
    assert sorted(n for n in reached if _within(n, NOT_IN_CORE)) == []


@pytest.mark.parametrize("module", ["edge.config", "edge.tracker_config", "edge.tracking"])
def test_configuration_and_interface_do_not_depend_on_the_tracker_implementation(module: str) -> None:
    reached = reachable(module)
    assert sorted(n for n in reached if _within(n, ("edge.pipeline", "edge.trackers", "cv2"))) == []


REPO = EDGE.parent


def _imports_of_file(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


@pytest.mark.parametrize("folder", ["benchmarks", "docs", "tools", "firmware/harness", "edge"])
def test_scripts_and_the_firmware_harness_do_not_import_the_tests(folder: str) -> None:
    files = sorted((REPO / folder).rglob("*.py"))
    assert files, folder
    uses = {str(p.relative_to(REPO)): sorted(m for m in _imports_of_file(p) if m == "tests" or m.startswith("tests."))
            for p in files}  # fmt: skip
    assert {name: used for name, used in uses.items() if used} == {}


def test_the_readme_layout_table_names_every_module_and_folder_of_the_package() -> None:
    """A new file in ``edge/`` gets its row (or a place in one) in the README's layout table."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    table = text[text.index("## Layout") : text.index("## Tests and CI")]
    entries = {
        p.name
        for p in EDGE.iterdir()
        if p.name != "__init__.py" and (p.suffix == ".py" or (p / "__init__.py").exists())
    }
    assert sorted(e for e in entries if f"`edge/{e}" not in table) == []
