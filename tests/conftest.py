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
