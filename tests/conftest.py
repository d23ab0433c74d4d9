"""Shared fixtures: paths into the repository."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parent.parent
SCHEMA_DIR = REPO / "shared" / "schema"
EXAMPLES = SCHEMA_DIR / "examples"


def benchmark_module(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` loaded by its path, once (the scripts are no package; ``sys.path`` is left alone)."""
    qualified = f"benchmarks.{name}"
    if qualified in sys.modules:
        return sys.modules[qualified]
    spec = importlib.util.spec_from_file_location(qualified, REPO / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[qualified] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The groups pytest-xdist deals out whole (``--dist loadgroup``): a file's tests stay together, so a module
    fixture (a rendered clip, a compiled firmware) is made once; every ``realtime`` test, whatever its file, shares
    one group, so two of them never run beside each other and fight for the cores their bars are timed on."""
    for item in items:
        group = "realtime" if item.get_closest_marker("realtime") else item.nodeid.split("::", 1)[0]
        item.add_marker(pytest.mark.xdist_group(group))


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node: object, ids: list[str]) -> None:
    """Each pytest-xdist worker's test ids carry their group by now (the worker appends ``@group``, the scheduler
    reads it back). If they do not (``--dist`` other than pyproject.toml's ``loadgroup``, or the groups silently lost
    as with pytest 9.2 and pytest-xdist 3.8, pytest-xdist#1386), the real-time tests would run beside each other:
    stop instead."""
    lost = [nodeid for nodeid in ids if "@" not in nodeid.rsplit("]", 1)[-1]]
    if lost:
        why = f"{lost[0]} has no pytest-xdist group: run with --dist loadgroup on a pytest pyproject.toml allows"
        pytest.exit(why, returncode=4)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(autouse=True)
def private_state_dir(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Each test's own state directory (the embedded broker's logins), inherited by the processes it starts: never
    the user's ~/.local/state, which other runs on this machine share."""
    state = tmp_path_factory.mktemp("state")
    monkeypatch.setenv("XDG_STATE_HOME", str(state))
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    return state / "edge-ips"


@pytest.fixture
def mosquitto(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A private anonymous Mosquitto on a free loopback port, stopped after the test."""
    from tests.support.mosquitto import Mosquitto

    with Mosquitto(tmp_path / "mosquitto") as broker:
        yield broker
