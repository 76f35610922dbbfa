"""pyrender renderer (optional backend, the ``[pyrender]`` extra): same output as moderngl.

Select it with ``make_renderer(mesh, backend="pyrender")`` or ``--renderer pyrender``. It gives
the same ``Render`` as the default moderngl backend (docs/rendering.md has the measurements):

* exact OpenCV projection: ``IntrinsicsCamera(fx, fy, cx + 0.5, cy + 0.5)`` (OpenGL pixel
  corners are integers) and camera node pose ``world_from_cam @ diag(1, -1, -1, 1)``;
* 4x MSAA off: pyrender always renders into a 4-sample framebuffer and enables
  GL_MULTISAMPLE, which blends edges and biases depth by a fraction of a pixel; this module
  drops that one ``glEnable`` during its own draws (all samples then hold the pixel-centre value);
* back faces drawn (``SKIP_CULL_FACES``), unlit vertex colours / textures (``FLAT``; without it
  pyrender's PBR lighting darkens every colour), material base colour 1;
* colourless meshes: pyrender's flat shader is swapped for ``shaders/headlight.frag``, the
  moderngl backend's head-light formula (``ambient + (1 - ambient) * |n . v|``);
* float64 recentring (``MeshData.offset``) before anything becomes float32;
* depth: pyrender linearises its 24-bit depth buffer (0 = no surface), so the error grows like
  ``z^2 / znear``: ``near_ratio`` defaults to 1e-3 here (relative depth error <= ~1e-4 at the far
  plane) against moderngl's float32 attachment with 1e-4; colour is read back as 8-bit.

The platform comes from ``PYOPENGL_PLATFORM`` (set to ``egl`` here unless already set, e.g. to
``osmesa``) and must be fixed before PyOpenGL is first imported in the process. The GL context
is created on the first ``render`` call, never at import or construction (GL contexts do not
survive ``fork``: create renderers inside spawned workers).
"""

from __future__ import annotations

import logging
import os
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.render.base import Render
from pgt_check.render.mesh import MeshData
from pgt_check.render.projection import centred_view
from pgt_check.types import Camera

logger = logging.getLogger(__name__)

#: fragment shader used instead of pyrender's flat.frag for colourless ("shaded") meshes
HEADLIGHT_SHADER = Path(__file__).with_name("shaders") / "headlight.frag"

#: OpenCV camera axes (x right, y down, z forward) -> OpenGL camera axes (y up, z backward)
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])

_patch_lock = threading.Lock()
_no_msaa = threading.local()


def import_pyrender() -> Any:
    """Import pyrender on a headless platform (``PYOPENGL_PLATFORM``, default ``egl``).

    Raises ImportError with the install recipe if pyrender or PyOpenGL is missing.
    """
    wanted = os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    if "OpenGL" in sys.modules and "pyrender" not in sys.modules:
        logger.debug("PyOpenGL was imported before pyrender; PYOPENGL_PLATFORM=%s", wanted)
    try:
        import pyrender
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "the pyrender backend needs pyrender and PyOpenGL>=3.1.7: "
            "pip install pyrender==0.1.45 && pip install 'PyOpenGL>=3.1.7' "
            f"(two commands, see scripts/setup.sh): {exc}"
        ) from exc
    _install_msaa_switch(pyrender)
    return pyrender


def _install_msaa_switch(pyrender: Any) -> None:
    """Wrap ``pyrender.renderer.glEnable`` once so that its ``glEnable(GL_MULTISAMPLE)`` turns
    into ``glDisable`` while this thread is inside ``PyrenderRenderer.render`` (GL_MULTISAMPLE
    is on by default, so skipping the call is not enough; other pyrender users are unaffected).
    """
    module = pyrender.renderer
    with _patch_lock:
        if getattr(module.glEnable, "_pgt_check_wrapper", False):
            return
        from OpenGL.GL import GL_MULTISAMPLE, glDisable

        original = module.glEnable

        def gl_enable(cap: Any, *args: Any) -> Any:
            if cap == GL_MULTISAMPLE and getattr(_no_msaa, "active", False):
                return glDisable(GL_MULTISAMPLE)
            return original(cap, *args)

        gl_enable._pgt_check_wrapper = True  # type: ignore[attr-defined]
        module.glEnable = gl_enable


def _headlight_cache(pyrender: Any) -> Any:
    """A pyrender shader cache that serves ``HEADLIGHT_SHADER`` wherever flat.frag is asked."""
    from pyrender.shader_program import ShaderProgramCache

    class HeadlightShaderCache(ShaderProgramCache):
        def get_program(
            self,
            vertex_shader: str,
            fragment_shader: str,
            geometry_shader: str | None = None,
            defines: dict | None = None,
        ) -> Any:
            if fragment_shader == "flat.frag":
                # an absolute path survives os.path.join(shader_dir, name)
                fragment_shader = str(HEADLIGHT_SHADER)
            return super().get_program(vertex_shader, fragment_shader, geometry_shader, defines)

    return HeadlightShaderCache()


class PyrenderRenderer:
    """Render one ``MeshData`` with pyrender (offscreen, EGL or OSMesa).

    ambient: ambient term of the head-light shading used for colourless meshes (as moderngl).
    near_ratio: lower bound of znear / zfar (see ``near_far_from_bounds``); larger than
        moderngl's because pyrender's metric depth comes from the 24-bit depth buffer.
    msaa: keep pyrender's 4x multisampling (smoother edges, but edge colours are blended and
        depth is biased by up to ~0.4 px); off by default for exact projection.
    """

    def __init__(
        self,
        mesh: MeshData,
        ambient: float = 0.2,
        near_ratio: float = 1e-3,
        msaa: bool = False,
    ) -> None:
        if not 0.0 <= ambient <= 1.0:
            raise ValueError(f"ambient must be in [0, 1], got {ambient}")
        if not 0.0 < near_ratio < 1.0:
            raise ValueError(f"near_ratio must be in (0, 1), got {near_ratio}")
        self.mesh = mesh
        self.shading = mesh.shading
        self.ambient = float(ambient)
        self.near_ratio = float(near_ratio)
        self.msaa = bool(msaa)
        self._bounds_centred = mesh.bounds - mesh.offset
        self._renderer: Any = None
        self._scene: Any = None
        self._camera_node: Any = None
        self._flags: int = 0

    # -- scene ---------------------------------------------------------------------------------
    def _build_scene(self, pyrender: Any) -> None:
        mesh = self.mesh
        nv = len(mesh.vertices)
        pos = (mesh.vertices - mesh.offset).astype(np.float32)  # recentre in float64 first
        shaded = mesh.shading == "shaded" or mesh.colors is None
        colors = np.ones((nv, 3), np.float32) if shaded else mesh.colors
        a = self.ambient

        def material(texture: Any = None) -> Any:
            return pyrender.MetallicRoughnessMaterial(
                baseColorFactor=[1.0, 1.0, 1.0, 1.0],  # trimesh's default colour would dim it
                baseColorTexture=texture,
                emissiveFactor=[a, a, a],  # read by the head-light shader only
                metallicFactor=0.0,
                roughnessFactor=1.0,
                doubleSided=True,
            )

        groups: list[tuple[np.ndarray, Any]] = []  # (faces, texture or None)
        if mesh.shading == "texture" and mesh.face_texture is not None:
            for ti, image in enumerate(mesh.textures):
                sel = mesh.faces[mesh.face_texture == ti]
                if len(sel):
                    # RGBA rows are 4-byte aligned whatever the width (GL_UNPACK_ALIGNMENT = 4)
                    rgba = np.dstack([image, np.full(image.shape[:2], 255, np.uint8)])
                    tex = pyrender.Texture(
                        source=rgba, source_channels="RGBA", sampler=pyrender.Sampler()
                    )
                    groups.append((sel, tex))
            sel = mesh.faces[mesh.face_texture < 0]
            if len(sel):
                groups.append((sel, None))
        else:
            groups.append((mesh.faces, None))

        primitives = []
        for faces, texture in groups:
            used, inverse = np.unique(faces.reshape(-1), return_inverse=True)
            indices = inverse.reshape(-1, 3).astype(np.uint32)
            uv = mesh.uv[used] if texture is not None and mesh.uv is not None else None
            primitives.append(
                pyrender.Primitive(
                    positions=pos[used],
                    indices=indices,
                    color_0=None if shaded else colors[used],  # type: ignore[index]  # not shaded: set
                    texcoord_0=uv,
                    material=material(texture),
                )
            )
        scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[0.0, 0.0, 0.0])
        scene.add(pyrender.Mesh(primitives=primitives))
        camera = pyrender.IntrinsicsCamera(fx=1.0, fy=1.0, cx=0.0, cy=0.0, znear=0.1, zfar=1.0)
        self._camera_node = scene.add(camera, pose=np.eye(4))
        self._scene = scene
        self._flags = pyrender.RenderFlags.FLAT | pyrender.RenderFlags.SKIP_CULL_FACES

    def _init_gl(self, width: int, height: int) -> None:
        pyrender = import_pyrender()
        self._build_scene(pyrender)
        self._renderer = pyrender.OffscreenRenderer(width, height)
        logger.debug("pyrender context on PYOPENGL_PLATFORM=%s", os.environ["PYOPENGL_PLATFORM"])
        if self.shading == "shaded":
            inner = getattr(self._renderer, "_renderer", None)
            if inner is None or not hasattr(inner, "_program_cache"):
                raise RuntimeError(
                    "this pyrender version has no Renderer._program_cache: cannot install the "
                    "head-light shader for a colourless mesh (use backend='moderngl')"
                )
            inner._program_cache = _headlight_cache(pyrender)

    # -- API -----------------------------------------------------------------------------------
    def render(self, camera: Camera, world_from_cam: np.ndarray) -> Render:
        """Render at ``world_from_cam`` (4x4 float64, OpenCV axes); distorted cameras are
        rendered with ``camera.as_pinhole()`` (as the moderngl backend)."""
        camera, centred_from_cam, planes = centred_view(
            camera, world_from_cam, self.mesh.offset, self._bounds_centred, self.near_ratio
        )
        w, h = camera.width, camera.height
        if planes is None or self.mesh.num_faces == 0:
            return Render.empty(h, w, self.shading)
        znear, zfar = planes

        if self._renderer is None:
            self._init_gl(w, h)
        fx, fy = camera.focal
        cx, cy = camera.principal_point
        cam = self._camera_node.camera
        cam.fx, cam.fy = float(fx), float(fy)
        cam.cx, cam.cy = float(cx) + 0.5, float(cy) + 0.5  # OpenGL pixel corners are integers
        cam.znear, cam.zfar = float(znear), float(zfar)
        self._scene.set_pose(self._camera_node, centred_from_cam @ _CV_TO_GL)
        self._renderer.viewport_width = w
        self._renderer.viewport_height = h

        _no_msaa.active = not self.msaa
        try:
            color, depth = self._renderer.render(self._scene, flags=self._flags)
        finally:
            _no_msaa.active = False
        depth = np.array(depth, dtype=np.float32)  # pyrender's buffer is read-only
        coverage = depth > 0.0
        depth[~coverage] = 0.0
        rgb = np.asarray(color[:, :, :3], dtype=np.float32) / np.float32(255.0)
        rgb[~coverage] = 0.0
        return Render(rgb=rgb, depth=depth, coverage=coverage, shading=self.shading)

    def close(self) -> None:
        """Release the GL context and everything uploaded (safe to call twice).

        Not ``OffscreenRenderer.delete()``: under EGL it calls ``eglTerminate`` on the
        process-wide display (also from ``__del__`` at garbage collection), which destroys every
        other EGL context of the process: other pyrender renderers and the moderngl backend's
        (measured: they then raise EGLError or render garbage). Only this renderer's context
        is destroyed here. A renderer dropped without ``close()`` has the same problem when
        it is garbage collected: close pyrender renderers explicitly.
        """
        if self._renderer is not None:
            _release_offscreen(self._renderer)
        self._renderer = None
        self._scene = None
        self._camera_node = None

    def __enter__(self) -> PyrenderRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        # pyrender's own finalisers would eglTerminate the shared display (see close())
        try:
            self.close()
        except Exception:  # noqa: BLE001 - never raise from a finaliser
            pass


def _release_offscreen(offscreen: Any) -> None:
    """Free an ``OffscreenRenderer``'s GL objects and its context, without ``eglTerminate``."""
    platform = offscreen._platform
    renderer = offscreen._renderer
    if platform is None:
        return
    try:
        platform.make_current()
        if renderer is not None:
            renderer.delete()
            # pyrender.Renderer.__del__ calls delete() again at garbage collection, in whatever
            # context is current then (e.g. a moderngl one), and delete() does not forget its
            # shadow framebuffer id: that glDeleteFramebuffers hit another context's object
            # (measured: moderngl renders garbage afterwards). Make the second call a no-op.
            renderer._shadow_fb = None
            renderer.delete = _noop
    finally:
        display = getattr(platform, "_egl_display", None)
        context = getattr(platform, "_egl_context", None)
        if display is not None and context is not None:
            from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

            eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
            eglDestroyContext(display, context)
            # Platform.__del__ -> delete_context() would still eglTerminate a known display
            platform._egl_context = None
            platform._egl_display = None
        else:  # OSMesa (or another platform): its own delete is process-safe
            platform.delete_context()
        # OffscreenRenderer.__del__ calls delete(), which now finds nothing to free
        offscreen._renderer = None
        offscreen._platform = None




def _noop() -> None:
    return None
