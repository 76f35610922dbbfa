"""Shared fixtures for render tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def shared_data_dir() -> Path:
    return Path(
        os.environ.get("PGT_SHARED_DATA", Path(__file__).resolve().parents[4] / "shared" / "data")
    )


@pytest.fixture(scope="session")
def shared_data() -> Path:
    root = shared_data_dir()
    if not root.is_dir():
        pytest.skip(f"shared data not found at {root} (set PGT_SHARED_DATA)")
    return root
