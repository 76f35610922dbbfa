"""Helpers for the io tests: seeded random poses and tiny images."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from pgt_check.geometry.transforms import make_rigid, quat_to_rotmat


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture
def random_rigid(rng: np.random.Generator) -> Callable[..., np.ndarray]:
    """Draw seeded random (4, 4) rigid transforms, translation in [-scale, scale]^3."""

    def draw(scale: float = 5.0) -> np.ndarray:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        return make_rigid(quat_to_rotmat(q), rng.uniform(-scale, scale, size=3))

    return draw


@pytest.fixture
def make_image() -> Callable[..., Path]:
    """Write a small PNG (w x h, RGB noise) and return its path."""

    def make(path: Path, width: int = 32, height: int = 24) -> Path:
        from PIL import Image

        path.parent.mkdir(parents=True, exist_ok=True)
        pixels = np.random.default_rng(0).integers(0, 256, size=(height, width, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(path)
        return path

    return make


def _check_error(err: BaseException, path: Path, line: int | None, fragment: str) -> None:
    message = str(err)
    assert path.name in message, message
    if line is not None:
        assert f"{path.name}:{line}:" in message, message
        assert getattr(err, "line", None) == line
    assert fragment in message, message


@pytest.fixture
def check_error() -> Callable[[BaseException, Path, int | None, str], None]:
    """Assert an error message names the file, the 1-based line (if any) and has ``fragment``."""
    return _check_error
