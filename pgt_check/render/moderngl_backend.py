"""moderngl renderer on a headless EGL standalone context (the default backend).

Recipe (measured, see docs/renderer.md and docs/rendering.md): exact OpenCV projection
(cx, cy + 0.5), no MSAA, back-face culling off, unlit colours, camera-space z written to a second
float32 attachment.
The GL context is created on the first ``render`` call, never at import or construction, so
a renderer can be built in one process and used in a spawned worker only.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from typing import Any

import numpy as np

from pgt_check.geometry.transforms import invert_rigid
from pgt_check.render.base import Render
from pgt_check.render.mesh import MeshData
from pgt_check.render.projection import centred_view, opengl_projection
from pgt_check.types import Camera

logger = logging.getLogger(__name__)

#: framebuffers kept per renderer (one per image size in use)
MAX_FRAMEBUFFERS = 4


def _release(fbo: Any, attachments: tuple[Any, ...]) -> None:
    fbo.release()
    for att in attachments:
        att.release()


_VERTEX_SHADER = """
#version 330
uniform mat4 view;   // cam_from_(recentred world)
uniform mat4 proj;
in vec3 in_pos;
in vec3 in_color;
in vec2 in_uv;
out vec3 v_color;
out vec2 v_uv;
out vec3 v_cam;
void main() {
    vec4 p = view * vec4(in_pos, 1.0);
    v_cam = p.xyz;
    v_color = in_color;
    v_uv = in_uv;
    gl_Position = proj * p;
}
"""

_FRAGMENT_SHADER = """
#version 330
uniform sampler2D tex;
uniform int shaded;     // 1: head-light Lambertian of the face normal, grey
uniform float ambient;
in vec3 v_color;
in vec2 v_uv;
in vec3 v_cam;
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_z;
void main() {
    vec3 c;
    if (shaded == 1) {
        // face normal from screen-space derivatives: exact per triangle, independent of winding
        vec3 n = normalize(cross(dFdx(v_cam), dFdy(v_cam)));
        float s = ambient + (1.0 - ambient) * abs(dot(n, normalize(-v_cam)));
        c = vec3(s);
    } else {
        c = v_color * texture(tex, v_uv).rgb;
    }
    out_color = vec4(clamp(c, 0.0, 1.0), 1.0);
    out_z = v_cam.z;
}
"""


class ModernGLRenderer:
    """Render one ``MeshData`` with moderngl (EGL, headless).

    ambient: ambient term of the head-light shading used for colourless meshes,
        ``shade = ambient + (1 - ambient) * |n . v|`` with per-face normals n and the view ray v.
    near_ratio: lower bound of znear / zfar (see ``near_far_from_bounds``).
    """

    def __init__(self, mesh: MeshData, ambient: float = 0.2, near_ratio: float = 1e-4) -> None:
        if not 0.0 <= ambient <= 1.0:
            raise ValueError(f"ambient must be in [0, 1], got {ambient}")
        self.mesh = mesh
        self.shading = mesh.shading
        self.ambient = float(ambient)
        self.near_ratio = float(near_ratio)
        self._bounds_centred = mesh.bounds - mesh.offset
        self._ctx: Any = None
        self._prog: Any = None
        self._draws: list[tuple[Any, Any]] = []  # (vao, texture)
        self._resources: list[Any] = []
        # framebuffers by size, most recently used last: a frame renders at the matching size,
        # the edge path's size and its references' size in turn, and re-creating the buffers
        # at every change of size cost about 7 ms a frame (reports/pipeline_timing.md)
        self._fbos: OrderedDict[tuple[int, int], tuple[Any, tuple[Any, ...]]] = OrderedDict()

    # -- GL resources ------------------------------------------------------------------------
    def _init_gl(self) -> None:
        import moderngl

        ctx = moderngl.create_standalone_context(backend="egl", require=330)  # type: ignore[arg-type]
        self._ctx = ctx
        with ctx:
            self._upload()

    def _upload(self) -> None:
        ctx = self._ctx
        logger.debug("moderngl context: %s", ctx.info.get("GL_RENDERER"))
        prog = ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER)
        self._prog = prog
        mesh = self.mesh
        nv = len(mesh.vertices)
        pos = (mesh.vertices - mesh.offset).astype(np.float32)  # recentre in float64 first
        if mesh.shading == "shaded" or mesh.colors is None:
            colors = np.ones((nv, 3), dtype=np.float32)
        else:
            colors = mesh.colors
        uv = mesh.uv if (mesh.shading == "texture" and mesh.uv is not None) else None
        if uv is None:
            uv = np.zeros((nv, 2), dtype=np.float32)
        data = np.hstack([pos, colors, uv]).astype(np.float32)
        vbo = ctx.buffer(np.ascontiguousarray(data).tobytes())
        self._resources.append(vbo)

        white = ctx.texture((1, 1), 3, bytes([255, 255, 255]))
        self._resources.append(white)
        groups: list[tuple[np.ndarray, Any]] = []
        if mesh.shading == "texture" and mesh.face_texture is not None:
            for ti, image in enumerate(mesh.textures):
                sel = mesh.faces[mesh.face_texture == ti]
                if len(sel):
                    groups.append((sel, self._make_texture(image)))
            sel = mesh.faces[mesh.face_texture < 0]
            if len(sel):
                groups.append((sel, white))
        else:
            groups.append((mesh.faces, white))
        for faces, texture in groups:
            ibo = ctx.buffer(np.ascontiguousarray(faces, dtype=np.uint32).tobytes())
            vao = ctx.vertex_array(
                prog,
                [(vbo, "3f 3f 2f", "in_pos", "in_color", "in_uv")],
                index_buffer=ibo,
                index_element_size=4,
            )
            self._resources += [ibo, vao]
            self._draws.append((vao, texture))

    def _make_texture(self, image: np.ndarray) -> Any:
        import moderngl

        h, w = image.shape[:2]
        # GL texture row 0 is v = 0 (image bottom in the UV convention): upload flipped
        data = np.ascontiguousarray(image[::-1])
        tex = self._ctx.texture((w, h), 3, data.tobytes(), alignment=1)
        tex.repeat_x = True
        tex.repeat_y = True
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self._resources.append(tex)
        return tex

    def _framebuffer(self, width: int, height: int) -> Any:
        size = (width, height)
        kept = self._fbos.get(size)
        if kept is not None:
            self._fbos.move_to_end(size)
            return kept[0]
        while len(self._fbos) >= MAX_FRAMEBUFFERS:
            _, (old, attachments) = self._fbos.popitem(last=False)
            _release(old, attachments)
        ctx = self._ctx
        color = ctx.renderbuffer(size, components=4, dtype="f4")
        zbuf = ctx.renderbuffer(size, components=1, dtype="f4")
        depth = ctx.depth_renderbuffer(size)
        fbo = ctx.framebuffer(color_attachments=[color, zbuf], depth_attachment=depth)
        self._fbos[size] = (fbo, (color, zbuf, depth))
        return fbo

    # -- API ---------------------------------------------------------------------------------
    def render(self, camera: Camera, world_from_cam: np.ndarray) -> Render:
        """Render at ``world_from_cam`` (4x4 float64, OpenCV axes).

        Distorted cameras are rendered with ``camera.as_pinhole()`` (the IO layer undistorts
        photos to the same pinhole model).
        """
        camera, centred_from_cam, planes = centred_view(
            camera, world_from_cam, self.mesh.offset, self._bounds_centred, self.near_ratio
        )
        w, h = camera.width, camera.height
        if planes is None or self.mesh.num_faces == 0:
            return Render.empty(h, w, self.shading)
        znear, zfar = planes
        proj = opengl_projection(camera, znear, zfar)

        if self._ctx is None:
            self._init_gl()
        # several renderers may live in one process: make this context current for the draw
        with self._ctx:
            rgba, depth = self._draw(w, h, invert_rigid(centred_from_cam), proj)
        # row 0 of the read-back is the image top (see opengl_projection): no flip needed
        coverage = depth > 0.0
        depth[~coverage] = 0.0
        rgb = np.ascontiguousarray(rgba[:, :, :3])
        rgb[~coverage] = 0.0
        return Render(rgb=rgb, depth=depth, coverage=coverage, shading=self.shading)

    def _draw(
        self, w: int, h: int, cam_from_centred: np.ndarray, proj: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        ctx = self._ctx
        fbo = self._framebuffer(w, h)
        fbo.use()
        ctx.viewport = (0, 0, w, h)
        ctx.disable(ctx.CULL_FACE | ctx.BLEND)
        ctx.enable(ctx.DEPTH_TEST)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._prog["view"].write(cam_from_centred.T.astype(np.float32).tobytes())
        self._prog["proj"].write(proj.T.astype(np.float32).tobytes())
        self._prog["shaded"].value = 1 if self.shading == "shaded" else 0
        self._prog["ambient"].value = self.ambient
        self._prog["tex"].value = 0
        for vao, texture in self._draws:
            texture.use(location=0)
            vao.render()
        rgba = np.frombuffer(fbo.read(components=4, attachment=0, dtype="f4"), dtype=np.float32)
        z = np.frombuffer(fbo.read(components=1, attachment=1, dtype="f4"), dtype=np.float32)
        return rgba.reshape(h, w, 4), z.reshape(h, w).copy()

    def close(self) -> None:
        """Release GL resources and the context (safe to call twice)."""
        if self._ctx is None:
            return
        with self._ctx:
            for fbo, attachments in self._fbos.values():
                _release(fbo, attachments)
            for r in reversed(self._resources):
                r.release()
            if self._prog is not None:
                self._prog.release()
        self._fbos = OrderedDict()
        self._resources = []
        self._draws = []
        self._prog = None
        self._ctx.release()
        self._ctx = None

    def __enter__(self) -> ModernGLRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


