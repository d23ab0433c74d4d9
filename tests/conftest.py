"""Shared fixtures: paths into the repository."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SCHEMA_DIR = REPO / "shared" / "schema"
EXAMPLES = SCHEMA_DIR / "examples"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture
def mosquitto(tmp_path: Path):  # type: ignore[no-untyped-def]
    """A private anonymous Mosquitto on a free loopback port, stopped after the test."""
    from tests.support.mosquitto import Mosquitto

    with Mosquitto(tmp_path / "mosquitto") as broker:
        yield broker
