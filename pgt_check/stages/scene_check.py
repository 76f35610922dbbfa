"""The enhancer's scene check, before any frame is measured (``enhance.output = auto``).

MaRINeR's trained decoder can damage a scene unlike its training scenes (the Sceaux castle:
several dB below its own matching-only base, ``reports/mariner_scenes.md``), and nothing it
learned can tell. So a run asks the scene itself: for ``enhance.scene_check_frames`` frames
spread along the trajectory it enhances the render with the frame's first reference, scores
the decoder's output and the matching-only base against the frame's own photo, and keeps the
decoder only where it is significantly better (``mariner_core.scene_check.decide_output``).
The choice is one setting for the whole run: it goes into the config (config.json, the
measurement fingerprint) as ``enhance.output`` = "model" or "base", and into the log.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any, Literal

from pgt_check.common.sequences import evenly_spaced
from pgt_check.config import RunConfig
from pgt_check.types import Frame

logger = logging.getLogger(__name__)

__all__ = ["needs_scene_check", "resolve_enhancer_output"]


def needs_scene_check(config: RunConfig) -> bool:
    """Whether the run enhances with MaRINeR and leaves its output to the scene check."""
    e = config.enhance
    return e.mode != "never" and e.method == "mariner" and e.output == "auto"


def resolve_enhancer_output(
    config: RunConfig,
    frames: Sequence[Frame],
    references: Mapping[str, tuple[Frame, ...]],
    checker: Any,
) -> RunConfig:
    """``config`` with ``enhance.output`` decided by the scene check (unchanged where the run
    does not need one, ``needs_scene_check``). ``checker``: the run's ``FrameChecker`` (its
    renderer and enhancer are used; its enhancer's ``output`` is set to the choice too).
    Frames without a photo, a reference or mesh in view are skipped; with too few scored
    triples the base is used (it cannot be shown that the decoder helps)."""
    if not needs_scene_check(config):
        return config
    from mariner_core.scene_check import decide_output

    enhancer = checker.enhancer
    candidates = [f for f in frames if references.get(f.frame_id)]
    model_db: list[float] = []
    base_db: list[float] = []
    for frame in evenly_spaced(candidates, config.enhance.scene_check_frames):
        triple = checker.scene_triple(frame)
        if triple is None:
            continue
        scores = enhancer.scene_scores(*triple)
        if scores is None:  # the spec network: no base to fall back to
            logger.info("scene check: the MaRINeR checkpoint has no matching-only base; "
                        "its decoder's output is used")
            return _with_output(config, checker, "model")
        model_db.append(scores[0])
        base_db.append(scores[1])
    check = decide_output(model_db, base_db)
    logger.info("MaRINeR scene check: %s -> enhance.output = %s", check.reason, check.output)
    return _with_output(config, checker, "model" if check.output == "model" else "base")


def _with_output(config: RunConfig, checker: Any, output: Literal["model", "base"]) -> RunConfig:
    resolved = replace(config, enhance=replace(config.enhance, output=output))
    enhancer = checker.enhancer
    if hasattr(enhancer, "output"):
        enhancer.output = output
    checker.config = resolved
    return resolved
