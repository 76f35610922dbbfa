"""Enhancement step: a render given the appearance of a reference photo (MaRINeR, reprojection).

Methods are chosen by name from ``ENHANCERS``; a method's module (and torch for MaRINeR) is
imported only when it is built.
"""

from __future__ import annotations

import importlib
from typing import Any

from pgt_check.enhance.base import EnhancedImage, Enhancer, Evidence, ReferenceView, View
from pgt_check.registry import ENHANCERS


def make_enhancer(config: Any) -> Enhancer:
    """Build the enhancement method named by ``config.method`` (an ``EnhanceConfig``)."""
    if config.method not in ENHANCERS:
        raise ValueError(
            f"unknown enhancement method {config.method!r} (available: {', '.join(ENHANCERS)})"
        )
    module_name, attr = ENHANCERS[config.method].split(":")
    return getattr(importlib.import_module(module_name), attr).from_config(config)


__all__ = [
    "ENHANCERS",
    "EnhancedImage",
    "Enhancer",
    "Evidence",
    "ReferenceView",
    "View",
    "make_enhancer",
]
