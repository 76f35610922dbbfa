"""Mesh loading for rendering: one flat, recentred triangle soup with its colour source.

``load_mesh`` reads PLY / OBJ / GLB (anything trimesh reads); scenes are flattened with their
node transforms. The result keeps world coordinates in float64 plus one recentring ``offset``
(the bounds centre) that the renderer subtracts before anything becomes float32, so
georeferenced coordinates (1e5-1e7) render without jitter.

Colour sources (``MeshData.shading``):

* ``"texture"``: per-vertex UVs and one or more RGB textures (``face_texture`` picks one per
  face, -1 = untextured face drawn with its vertex colour); unlit.
* ``"vertex"``: per-vertex RGB colours (face colours are expanded to vertices); unlit.
* ``"shaded"``: no colour is used; the renderer shades the geometry with a head light.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.types import check_shape

logger = logging.getLogger(__name__)

#: accepted values of ``load_mesh(shading=...)``
SHADING_CHOICES = ("auto", "vertex", "texture", "shaded")


@dataclass(frozen=True, eq=False)
class MeshData:
    """A triangle mesh ready for rendering.

    vertices: (V, 3) float64 world coordinates.
    faces: (F, 3) int32 vertex indices.
    colors: (V, 3) float32 RGB in [0, 1], or None.
    uv: (V, 2) float32 texture coordinates (OpenGL convention, v = 0 at the image bottom), or None.
    textures: tuple of (H, W, 3) uint8 RGB images (row 0 = image top).
    face_texture: (F,) int32 index into ``textures`` (-1 = no texture), or None.
    shading: "vertex" | "texture" | "shaded" (the colour source the renderer uses).
    offset: (3,) float64 recentring offset (world); the renderer works in ``vertices - offset``.
    side_files: the files the loader read besides the mesh file itself (OBJ materials and
    textures, glTF external buffers and images), as absolute paths in the order read; a file
    the mesh referred to but that was not found is ``"missing:<name as referenced>"``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    shading: str
    colors: np.ndarray | None = None
    uv: np.ndarray | None = None
    textures: tuple[np.ndarray, ...] = ()
    face_texture: np.ndarray | None = None
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    side_files: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        f = np.ascontiguousarray(self.faces, dtype=np.int32)
        check_shape("vertices", v, (None, 3))
        check_shape("faces", f, (None, 3))
        if not np.all(np.isfinite(v)):
            raise ValueError("vertices must be finite")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ValueError(f"faces index outside 0..{len(v) - 1}")
        if self.shading not in ("vertex", "texture", "shaded"):
            raise ValueError(f"shading must be vertex, texture or shaded, got {self.shading!r}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        offset = np.asarray(self.offset, dtype=np.float64).reshape(-1)
        check_shape("offset", offset, (3,))
        object.__setattr__(self, "offset", offset)
        if self.colors is not None:
            c = np.ascontiguousarray(self.colors, dtype=np.float32)
            check_shape("colors", c, (len(v), 3))
            object.__setattr__(self, "colors", c)
        if self.uv is not None:
            uv = np.ascontiguousarray(self.uv, dtype=np.float32)
            check_shape("uv", uv, (len(v), 2))
            object.__setattr__(self, "uv", uv)
        textures = tuple(np.ascontiguousarray(t, dtype=np.uint8) for t in self.textures)
        for i, t in enumerate(textures):
            check_shape(f"textures[{i}]", t, (None, None, 3))
        object.__setattr__(self, "textures", textures)
        if self.face_texture is not None:
            ft = np.ascontiguousarray(self.face_texture, dtype=np.int32)
            check_shape("face_texture", ft, (len(f),))
            if ft.size and (ft.min() < -1 or ft.max() >= len(textures)):
                raise ValueError("face_texture index outside the texture list")
            object.__setattr__(self, "face_texture", ft)
        if self.shading == "vertex" and self.colors is None:
            raise ValueError("shading 'vertex' needs vertex colours")
        if self.shading == "texture" and (
            self.uv is None or not textures or self.face_texture is None
        ):
            raise ValueError("shading 'texture' needs uv, textures and face_texture")

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64 axis-aligned bounds (min, max) in world coordinates."""
        if len(self.vertices) == 0:
            return np.zeros((2, 3))
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @property
    def num_faces(self) -> int:
        return len(self.faces)

    def without_colour(self) -> MeshData:
        """The same geometry with shading="shaded" (colours and textures dropped)."""
        return replace(self, colors=None, uv=None, textures=(), face_texture=None, shading="shaded")

    def vertex_colours_from_texture(self) -> np.ndarray:
        """(V, 3) float32 colour of each vertex sampled from its texture at its UV (bilinear-free,
        nearest texel); vertices of untextured faces keep their vertex colour (or mid grey)."""
        out = (
            self.colors.copy()
            if self.colors is not None
            else np.full((len(self.vertices), 3), 0.5, dtype=np.float32)
        )
        if self.shading != "texture" or self.uv is None or self.face_texture is None:
            return out
        for ti, tex in enumerate(self.textures):
            vids = np.unique(self.faces[self.face_texture == ti])
            if not vids.size:
                continue
            h, w = tex.shape[:2]
            u = np.mod(self.uv[vids, 0], 1.0)
            v = np.mod(self.uv[vids, 1], 1.0)
            col = np.clip((u * w).astype(int), 0, w - 1)
            row = np.clip(((1.0 - v) * h).astype(int), 0, h - 1)
            out[vids] = tex[row, col].astype(np.float32) / 255.0
        return out

    def decimated(self, fraction: float = 0.1) -> MeshData:
        """A copy with about ``fraction`` of the faces (for training augmentation).

        Uses quadric decimation (``fast_simplification``) when installed, else vertex
        clustering on a grid whose cell size is searched to approach the target face count.
        Colours are transferred from the nearest original vertex; a textured mesh is first
        baked to vertex colours (nearest texel at each vertex UV), so the result has
        shading="vertex" (blurry colours, like a TSDF mesh) or "shaded" for a colourless input.
        """
        if not 0.0 < fraction <= 1.0:
            raise ValueError(f"fraction must be in (0, 1], got {fraction}")
        centred = self.vertices - self.offset
        target = max(4, int(round(self.num_faces * fraction)))
        if fraction >= 1.0 or self.num_faces <= target:
            return self
        try:
            import fast_simplification
        except ImportError:
            fast_simplification = None
        if fast_simplification is not None:
            new_v, new_f = fast_simplification.simplify(
                centred.astype(np.float32), self.faces, target_count=target
            )
            new_v = np.asarray(new_v, dtype=np.float64)
        else:
            logger.info("fast_simplification not installed: decimating by vertex clustering")
            new_v, new_f = _cluster_decimate(centred, self.faces, target)
        colors = None
        shading = "shaded"
        if self.shading in ("vertex", "texture"):
            from scipy.spatial import cKDTree

            source = (
                self.vertex_colours_from_texture() if self.shading == "texture" else self.colors
            )
            _, nearest = cKDTree(centred).query(new_v)
            assert source is not None  # a vertex-coloured or textured mesh has colours
            colors = source[nearest]
            shading = "vertex"
        return MeshData(
            vertices=new_v + self.offset,
            faces=new_f,
            shading=shading,
            colors=colors,
            offset=self.offset,
        )


def _cluster_decimate(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: merge vertices per grid cell; bisect the cell size on the face count."""
    extent = float(np.max(np.ptp(vertices, axis=0))) or 1.0
    lo, hi = extent * 1e-5, extent
    best: tuple[np.ndarray, np.ndarray] | None = None
    for _ in range(20):
        cell = np.sqrt(lo * hi)
        keys = np.floor(vertices / cell).astype(np.int64)
        _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        sums = np.zeros((len(counts), 3))
        np.add.at(sums, inverse, vertices)
        new_v = sums / counts[:, None]
        f = inverse[faces]
        keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        f = np.unique(np.sort(f[keep], axis=1), axis=0) if keep.any() else f[keep]
        best = (
            (new_v, f) if best is None or len(f) >= target_faces or len(best[1]) < len(f) else best
        )
        if len(f) > target_faces * 1.1:
            lo = cell
        elif len(f) < target_faces * 0.9:
            hi = cell
        else:
            best = (new_v, f)
            break
    assert best is not None
    used = np.unique(best[1])
    remap = np.full(len(best[0]), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return best[0][used], remap[best[1]].astype(np.int32)


def _image_to_rgb(image: Any) -> np.ndarray | None:
    """PIL image (or array) -> (H, W, 3) uint8 RGB, alpha dropped; None if absent."""
    if image is None:
        return None
    arr = np.asarray(image.convert("RGB") if hasattr(image, "convert") else image)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    return np.ascontiguousarray(arr[:, :, :3]).astype(np.uint8)


def _material_image(material: Any) -> Any:
    for name in ("baseColorTexture", "image"):
        img = getattr(material, name, None)
        if img is not None:
            return img
    return None


def _material_colour(material: Any) -> np.ndarray:
    """Material main colour as (3,) float32 [0, 1] (mid grey if unknown)."""
    col = getattr(material, "main_color", None)
    if col is None:
        return np.full(3, 0.5, dtype=np.float32)
    return np.asarray(col, dtype=np.float32)[:3] / 255.0


@dataclass
class _Part:
    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None  # (V, 3) float32
    uv: np.ndarray | None
    texture: np.ndarray | None


def _part_from_trimesh(geom: Any) -> _Part:
    visual = geom.visual
    kind = getattr(visual, "kind", None)
    v = np.asarray(geom.vertices, dtype=np.float64)
    f = np.asarray(geom.faces, dtype=np.int64)
    if kind == "texture":
        material = getattr(visual, "material", None)
        image = _image_to_rgb(_material_image(material)) if material is not None else None
        uv = getattr(visual, "uv", None)
        if image is not None and uv is not None and len(uv) == len(v):
            return _Part(v, f, None, np.asarray(uv, dtype=np.float32), image)
        colour = _material_colour(material)
        return _Part(v, f, np.tile(colour, (len(v), 1)), None, None)
    if kind == "vertex":
        c = np.asarray(visual.vertex_colors, dtype=np.float32)[:, :3] / 255.0
        return _Part(v, f, c, None, None)
    if kind == "face":
        fc = np.asarray(visual.face_colors, dtype=np.float32)[:, :3] / 255.0
        # one vertex per face corner so each face keeps its own colour
        return _Part(
            v[f.reshape(-1)], np.arange(f.size).reshape(-1, 3), np.repeat(fc, 3, 0), None, None
        )
    return _Part(v, f, None, None, None)


def _flatten(loaded: Any) -> list[Any]:
    import trimesh

    if isinstance(loaded, trimesh.Scene):
        geoms = loaded.dump(concatenate=False)
    else:
        geoms = [loaded]
    meshes = [g for g in geoms if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    skipped = len(geoms) - len(meshes)
    if skipped:
        logger.warning("skipped %d non-triangle or empty geometries", skipped)
    return meshes


def mesh_from_trimesh(loaded: Any, shading: str = "auto", source: str = "") -> MeshData:
    """Build ``MeshData`` from a trimesh ``Trimesh`` or ``Scene`` (flattened with transforms)."""
    if shading not in SHADING_CHOICES:
        raise ValueError(f"shading must be one of {', '.join(SHADING_CHOICES)}, got {shading!r}")
    parts = [_part_from_trimesh(g) for g in _flatten(loaded)]
    if not parts:
        raise ValueError(f"{source or 'mesh'}: no triangles")
    resolved = _resolve_shading(parts, shading, source)
    mesh = _with_shading(_merge_parts(parts), resolved)
    logger.debug(
        "loaded %s: %d vertices, %d faces, shading %s, offset %s",
        source,
        len(mesh.vertices),
        mesh.num_faces,
        mesh.shading,
        mesh.offset.tolist(),
    )
    return mesh


def _resolve_shading(parts: list[_Part], shading: str, source: str) -> str:
    """The shading to use ("auto" picks texture, else vertex, else shaded); ValueError when the
    parts lack the colour source asked for."""
    has_texture = any(p.texture is not None for p in parts)
    has_colour = any(p.colors is not None for p in parts)
    if shading == "auto":
        resolved = "texture" if has_texture else "vertex" if has_colour else "shaded"
    else:
        resolved = shading
    if resolved == "texture" and not has_texture:
        raise ValueError(f"{source or 'mesh'}: shading='texture' but the mesh has no texture")
    if resolved == "vertex" and not (has_colour or has_texture):
        raise ValueError(f"{source or 'mesh'}: shading='vertex' but the mesh has no colours")
    return resolved


def _merge_parts(parts: list[_Part]) -> MeshData:
    """One MeshData holding every part, with the richest colour source any part has and the
    bounds centre as offset."""
    has_texture = any(p.texture is not None for p in parts)
    has_colour = any(p.colors is not None for p in parts)
    vertices, faces, colors, uvs, face_tex, textures = [], [], [], [], [], []
    base = 0
    for p in parts:
        nv = len(p.vertices)
        vertices.append(p.vertices)
        faces.append(p.faces + base)
        base += nv
        if p.texture is not None:
            textures.append(p.texture)
            face_tex.append(np.full(len(p.faces), len(textures) - 1, dtype=np.int32))
            uvs.append(p.uv)
            colors.append(np.ones((nv, 3), dtype=np.float32))
        else:
            face_tex.append(np.full(len(p.faces), -1, dtype=np.int32))
            uvs.append(np.zeros((nv, 2), dtype=np.float32))
            colors.append(
                p.colors if p.colors is not None else np.full((nv, 3), 0.5, dtype=np.float32)
            )
    v = np.concatenate(vertices)
    offset = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return MeshData(
        vertices=v,
        faces=np.concatenate(faces),
        shading="texture" if has_texture else ("vertex" if has_colour else "shaded"),
        colors=np.concatenate(colors) if (has_colour or has_texture) else None,
        uv=np.concatenate(uvs) if has_texture else None,  # type: ignore[arg-type]  # all set
        textures=tuple(textures),
        face_texture=np.concatenate(face_tex) if has_texture else None,
        offset=offset,
    )


def _with_shading(mesh: MeshData, resolved: str) -> MeshData:
    """``mesh`` reduced to the resolved shading: colours dropped for "shaded", textures baked
    into vertex colours for "vertex"; else ``mesh`` itself."""
    if resolved == "shaded":
        return mesh.without_colour()
    if resolved == "vertex" and mesh.shading == "texture":
        return replace(
            mesh,
            colors=mesh.vertex_colours_from_texture(),
            uv=None,
            textures=(),
            face_texture=None,
            shading="vertex",
        )
    return mesh


def load_mesh(path: str | Path, shading: str = "auto") -> MeshData:
    """Load a PLY / OBJ / GLB mesh (via trimesh) for rendering.

    shading: "auto" picks "texture" if any part has a texture image and UVs, else "vertex" if
    it has vertex or face colours, else "shaded". Asking for a colour source the mesh lacks
    raises ValueError (no silent fallback); "vertex" on a textured mesh bakes texels to vertices.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh not found: {path}")
    import trimesh

    resolver = _recording_resolver(path)
    loaded = trimesh.load(str(path), process=False, resolver=resolver)
    mesh = mesh_from_trimesh(loaded, shading=shading, source=str(path))
    side = tuple(dict.fromkeys(resolver.read))  # first-read order, each file once
    if side:
        logger.debug("%s: read %d side files (%s)", path, len(side), ", ".join(side[:5]))
    return replace(mesh, side_files=side)


def _recording_resolver(path: Path) -> Any:
    """A trimesh ``FilePathResolver`` for ``path`` that records every file it hands to the
    loader (``.read``): the content a run's mesh hash must cover besides the mesh file. It
    resolves names exactly as trimesh's own does (it calls it); a name it cannot resolve is
    recorded as ``missing:<name>`` (the file appearing later changes the hash)."""
    from trimesh.resolvers import FilePathResolver

    class RecordingResolver(FilePathResolver):
        def __init__(self, source: str, read: list[str]) -> None:
            super().__init__(source)
            self.read = read

        def namespaced(self, namespace: str) -> RecordingResolver:
            return RecordingResolver(str(Path(self.parent) / namespace), self.read)

        def get(self, name: str) -> bytes:
            try:
                data = super().get(name)
            except Exception:
                self.read.append(f"missing:{name}")
                raise
            self.read.append(str(self._resolved(name)))
            return data

        def _resolved(self, name: str) -> Path:
            # the candidates of FilePathResolver.get, in its order: the first that exists
            for candidate in (name.strip(), name.strip().lstrip("/"), Path(name).name):
                try:
                    found = self.absolute(candidate)
                except ValueError:
                    continue
                if found.exists():
                    return found
            return self.absolute(name)

    return RecordingResolver(str(path.absolute()), [])
