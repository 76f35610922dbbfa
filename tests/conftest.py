"""Fixtures shared by the whole test suite."""

from __future__ import annotations

import logging
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


@pytest.fixture(autouse=True)
def _pgt_check_logging():
    """After each test the ``pgt_check`` logger has the level, handlers and propagation it had
    before, and no ``pgt_check`` logger is disabled. A command run in-process sets that level
    and handler (``commands.common.configure_logging``; ``enhance -q`` / ``compare -q``:
    ERROR), which hid the warnings a later test on the same worker asserted with ``caplog``
    (test_correction's "unreadable": order-dependent under pytest-xdist)."""
    root = logging.getLogger("pgt_check")
    saved = (root.level, root.handlers[:], root.propagate)
    yield
    root.setLevel(saved[0])
    root.handlers[:] = saved[1]
    root.propagate = saved[2]
    for name, logger in list(logging.Logger.manager.loggerDict.items()):
        if name.startswith("pgt_check") and isinstance(logger, logging.Logger):
            logger.disabled = False
