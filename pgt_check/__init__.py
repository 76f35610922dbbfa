"""pgt-check: per-frame validation of pseudo-ground-truth camera poses against a mesh.

Importing this package pulls in only the standard library and numpy; every heavy dependency
(OpenGL, torch, kornia, dask) is imported inside the step that needs it.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
