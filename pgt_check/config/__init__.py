"""The run configuration (layer 0): ``from pgt_check.config import RunConfig``.

- ``run_config``: ``RunConfig`` (typed, frozen, strict loading), presets, older layouts moved
  (``moved_to_sections``);
- ``measure``: the measuring sections (input, render, match, homography, enhance, edges, pose)
  and their size bounds;
- ``judge``: the judging sections (verdict, gate, run_checks, correct) and ``JudgingConfig``,
  the sections the verdict stage may read;
- ``load``: strict loading of plain data (type and range checks, config files, ``merge``).

This package re-exports their public names; inside it, modules import each other directly.
"""

from pgt_check.config.judge import (
    MAX_UNVERIFIABLE_DEFAULT,
    MOVED_KEYS,
    CorrectConfig,
    GateConfig,
    JudgingConfig,
    RunChecksConfig,
    VerdictConfig,
)
from pgt_check.config.load import from_dict, merge
from pgt_check.config.measure import (
    MAX_IMAGE_SIDE,
    MAX_ITERATIONS,
    MAX_KEYPOINTS,
    MAX_TILE_GRID,
    EdgeConfig,
    EnhanceConfig,
    HomographyConfig,
    InputConfig,
    MatchConfig,
    PoseConfig,
    ReferenceConfig,
    RenderConfig,
)
from pgt_check.config.run_config import (
    ACTION_KEYS,
    MEASUREMENT_SECTIONS,
    PRESETS,
    RunConfig,
    load_config_file,
    moved_to_sections,
)

__all__ = [
    "ACTION_KEYS", "MAX_IMAGE_SIDE", "MAX_ITERATIONS", "MAX_KEYPOINTS", "MAX_TILE_GRID",
    "MAX_UNVERIFIABLE_DEFAULT", "MEASUREMENT_SECTIONS", "MOVED_KEYS", "PRESETS",
    "CorrectConfig", "EdgeConfig", "EnhanceConfig", "GateConfig", "HomographyConfig",
    "InputConfig", "JudgingConfig", "MatchConfig", "PoseConfig", "ReferenceConfig",
    "RenderConfig", "RunChecksConfig", "RunConfig", "VerdictConfig", "from_dict",
    "load_config_file", "merge", "moved_to_sections",
]
