"""Fixtures of the report tests; the data builders live in report_testdata.py."""

from __future__ import annotations

from typing import Any

import pytest
from report_testdata import judged, synthetic_measurements

from pgt_check.config import RunConfig


@pytest.fixture
def config() -> RunConfig:
    return RunConfig.from_dict(
        {"input": {"trajectory": "/home/alice/secret/scene/trajectories.txt", "mesh": "mesh.ply"}}
    )


@pytest.fixture
def records(config: RunConfig) -> list[dict[str, Any]]:
    return judged(synthetic_measurements(), config)
