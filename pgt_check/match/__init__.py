"""Matching: keypoint correspondences between a render (image0) and a photo (image1).

Backends are chosen by name from an explicit table; heavy backends import their dependencies
only when built.
"""

from __future__ import annotations

import importlib
from typing import Any

from pgt_check.match.base import Matcher, Matches
from pgt_check.registry import MATCHERS


#: matcher name -> ("module:factory", fixed keyword arguments); see pgt_check.registry
def make_matcher(name: str, **options: Any) -> Matcher:
    """Build the matcher registered as ``name`` (see ``MATCHERS``)."""
    if name not in MATCHERS:
        raise ValueError(f"unknown matcher {name!r} (available: {', '.join(MATCHERS)})")
    target, fixed = MATCHERS[name]
    module_name, attr = target.split(":")
    factory = getattr(importlib.import_module(module_name), attr)
    return factory(**fixed, **options)


__all__ = ["MATCHERS", "Matcher", "Matches", "make_matcher"]
