"""The measuring sections check their values when built: a bad value raises naming the key (a
ValueError; ``RunConfig.from_dict`` reports it as a ConfigError, tests/pgt_check/config/
test_run_config.py); the size bounds keep a run from allocating without bound."""

from __future__ import annotations

import pytest

from pgt_check.config.measure import (
    MAX_IMAGE_SIDE,
    MAX_KEYPOINTS,
    EdgeConfig,
    EnhanceConfig,
    HomographyConfig,
    InputConfig,
    MatchConfig,
    PoseConfig,
    ReferenceConfig,
    RenderConfig,
)


def test_every_section_builds_with_its_defaults():
    for section in (EdgeConfig, EnhanceConfig, HomographyConfig, InputConfig, MatchConfig,
                    PoseConfig, ReferenceConfig, RenderConfig):
        assert section() == section()


@pytest.mark.parametrize(
    "build,key",
    [
        (lambda: HomographyConfig(min_inliers=3), "homography.min_inliers"),
        (lambda: HomographyConfig(confidence=1.0), "homography.confidence"),
        (lambda: MatchConfig(max_keypoints=MAX_KEYPOINTS + 1), "match.max_keypoints"),
        (lambda: MatchConfig(resize_max=MAX_IMAGE_SIDE + 1), "match.resize_max"),
        (lambda: MatchConfig(method="orb-slam"), "match"),
        (lambda: EnhanceConfig(short_side=8), "enhance.short_side"),
        (lambda: EnhanceConfig(method="gan"), "enhance"),
        (lambda: RenderConfig(backend="raytracer"), "render"),
        (lambda: EdgeConfig(alpha=0.6), "edges.alpha"),
        (lambda: PoseConfig(max_error_px=0.0), "pose.max_error_px"),
        (lambda: ReferenceConfig(max_rotation_deg=181), "max_rotation_deg"),
    ],
)
def test_a_bad_value_names_its_key(build, key):
    with pytest.raises(ValueError, match=key):
        build()
