"""Rendering: load a mesh and render RGB + metric depth + coverage at a camera pose.

```python
from pgt_check.render import load_mesh, make_renderer
mesh = load_mesh("mesh.ply")                 # MeshData, shading "auto" -> vertex/texture/shaded
renderer = make_renderer(mesh)               # moderngl + EGL; GL context created on first render
# make_renderer(mesh, backend="pyrender")    # optional [pyrender] extra, same Render output
r = renderer.render(camera, world_from_cam)  # Render(rgb, depth, coverage, shading)
renderer.close()
```
Importing this package does not import moderngl, pyrender or trimesh.
"""

from __future__ import annotations

import importlib
from typing import Any

from pgt_check.errors import ConfigError
from pgt_check.registry import RENDER_BACKENDS
from pgt_check.render.base import SHADING_MODES, Render, Renderer
from pgt_check.render.mesh import MeshData, load_mesh, mesh_from_trimesh

#: backend name -> (module, class); modules are imported only when that backend is made
BACKENDS = RENDER_BACKENDS


def make_renderer(mesh: MeshData, backend: str = "moderngl", **options: Any) -> Renderer:
    """Build a renderer for ``mesh``; ``options`` go to the backend class (e.g. ambient)."""
    if backend not in BACKENDS:
        raise ConfigError(f"unknown render backend {backend!r} (allowed: {', '.join(BACKENDS)})")
    module_name, class_name = BACKENDS[backend]
    cls = getattr(importlib.import_module(module_name), class_name)
    return cls(mesh, **options)


__all__ = [
    "BACKENDS",
    "SHADING_MODES",
    "MeshData",
    "Render",
    "Renderer",
    "load_mesh",
    "make_renderer",
    "mesh_from_trimesh",
]
