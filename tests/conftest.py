"""Fixtures shared by the whole test suite."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real datasets in ``../shared/data`` (or $PGT_SHARED_DATA); skips the test if absent."""
    path = Path(os.environ.get("PGT_SHARED_DATA", REPO.parent / "shared" / "data"))
    if not path.is_dir():
        pytest.skip(f"shared data not found at {path} (set PGT_SHARED_DATA)")
    return path


@pytest.fixture(scope="session")
def sample_scene() -> Path:
    """The generated sample scene committed in ``sample_data/scene``."""
    path = REPO / "sample_data" / "scene"
    if not (path / "trajectories.txt").is_file():
        pytest.fail("sample_data/scene is missing: run python scripts/make_sample_data.py")
    return path


@pytest.fixture(scope="session")
def check_frames():
    """Measure and judge every frame of an in-memory trajectory (the runner's stages 1 + 2)."""
    from pgt_check.config import RunConfig
    from pgt_check.measure import FrameChecker, pick_references
    from pgt_check.verdict import apply_verdicts

    def _check(traj, mesh: Path, **config) -> list[dict]:
        cfg = RunConfig.from_dict(
            {"input": {"trajectory": traj.source, "mesh": str(mesh)}, **config}
        )
        checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
        try:
            recs = [checker.measure(f) for f in traj.frames]
        finally:
            checker.close()
        return apply_verdicts(recs, cfg)

    return _check
