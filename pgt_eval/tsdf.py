"""A textureless scene made as real scans are made (issue #29): the boxes fused by TSDF from noisy
synthetic depth maps, then marching cubes and decimation; photos with objects the mesh lacks.

```python
vol = TsdfVolume.empty(lo, hi, voxel=0.04)              # numpy TSDF volume (projective, truncated)
vol.integrate(depth, K, world_from_cam)                 # one depth map (H, W) metric z, 0 = none
mesh = vol.mesh()                                       # marching cubes (scikit-image) -> trimesh
traj = make_tsdf_scene("out/", n_frames=12)             # tsdf.ply + photos + LaMAR files
```

The sensor model of ``noisy_depth`` (a structured-light RGB-D camera, Kinect-v1-like):
axial noise 0.0012 + 0.0019 (z - 0.4)^2 m and disparity quantisation (depth step
0.0028 z^2 m), both scaled by ``noise_scale``,
a range limit, mixed ("flying") pixels across depth discontinuities from a small blur of
the depth, the pixels of a large local depth range dropped (the usual edge filter), and
blob-shaped dropouts (absorbing / specular patches). Each depth map is fused at its pose with a
small tracking error. What the fused mesh has, like a real scan: rounded edges and creases
(truncation, voxel size, noise averaging), holes where no view saw the surface or depth dropped
out, a surface cut at the volume's bounds, no colours.

Marching cubes needs scikit-image (the ``tsdf`` extra: ``pip install -e .[tsdf]``);
``TsdfVolume.mesh`` raises ``ImportError`` naming the extra when it is absent.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pgt_check.types import check_shape

#: the part of the boxes scene the photos see (m): x, y, z bounds of the fusion volume
BOXES_BOUNDS = (np.array([-3.2, -1.8, -0.15]), np.array([3.2, 4.25, 3.05]))


@dataclass(eq=False)
class TsdfVolume:
    """A truncated signed distance volume (projective TSDF, running weighted mean).

    origin: (3,) world position of voxel (0, 0, 0)'s centre; voxel: edge length (m);
    tsdf: (X, Y, Z) float32 in [-1, 1] (distance / trunc, positive in front of surfaces);
    weight: (X, Y, Z) float32 (0 = never observed); trunc: truncation distance (m).
    """

    origin: np.ndarray
    voxel: float
    tsdf: np.ndarray
    weight: np.ndarray
    trunc: float
    max_weight: float = 64.0

    @classmethod
    def empty(cls, lo, hi, voxel: float, trunc_voxels: float = 3.0) -> TsdfVolume:
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        check_shape("lo", lo, (3,))
        check_shape("hi", hi, (3,))
        shape = tuple(int(n) for n in np.ceil((hi - lo) / voxel).astype(int) + 1)
        return cls(lo, float(voxel), np.ones(shape, np.float32), np.zeros(shape, np.float32),
                   trunc_voxels * voxel)

    def _centres(self) -> np.ndarray:
        if not hasattr(self, "_cache"):
            axes = [self.origin[i] + self.voxel * np.arange(n, dtype=np.float32)
                    for i, n in enumerate(self.tsdf.shape)]
            g = np.meshgrid(*axes, indexing="ij")
            self._cache = np.stack([a.ravel() for a in g], axis=1).astype(np.float32)
        return self._cache

    def integrate(self, depth: np.ndarray, K: np.ndarray, world_from_cam: np.ndarray) -> None:
        """Fuse one depth map. depth: (H, W) metric camera z (0 / non-finite = no measurement);
        K: (3, 3) intrinsics (OpenCV pixel centres); world_from_cam: (4, 4)."""
        depth = np.asarray(depth, np.float32)
        check_shape("K", np.asarray(K), (3, 3))
        check_shape("world_from_cam", np.asarray(world_from_cam), (4, 4))
        h, w = depth.shape
        r = np.asarray(world_from_cam[:3, :3], np.float32)
        t = np.asarray(world_from_cam[:3, 3], np.float32)
        p = (self._centres() - t) @ r  # cam coordinates: R^T (x - t)
        z = p[:, 2]
        front = z > 1e-3
        zf = np.where(front, z, 1.0)
        u = np.floor(K[0, 0] * p[:, 0] / zf + K[0, 2] + 0.5).astype(np.int64)
        v = np.floor(K[1, 1] * p[:, 1] / zf + K[1, 2] + 0.5).astype(np.int64)
        ok = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        idx = np.flatnonzero(ok)
        d = depth[v[idx], u[idx]]
        has = np.isfinite(d) & (d > 0)
        idx, d = idx[has], d[has]
        sdf = d - z[idx]
        near = sdf > -self.trunc  # not far behind the surface (occluded: unknown)
        idx, sdf = idx[near], sdf[near]
        val = np.minimum(1.0, sdf / self.trunc)
        ts, wt = self.tsdf.reshape(-1), self.weight.reshape(-1)
        w0 = wt[idx]
        ts[idx] = (ts[idx] * w0 + val) / (w0 + 1.0)
        wt[idx] = np.minimum(w0 + 1.0, self.max_weight)

    def mesh(self, min_weight: float = 1.0):
        """Marching cubes of the zero level over the observed voxels (weight >= min_weight);
        a trimesh.Trimesh in world coordinates (no colours)."""
        try:
            from skimage.measure import marching_cubes
        except ImportError as e:  # optional: the tsdf extra
            raise ImportError(
                "TSDF meshing needs scikit-image: pip install -e '.[tsdf]' (or scikit-image)"
            ) from e
        import trimesh

        observed = self.weight >= min_weight
        verts, faces, _, _ = marching_cubes(self.tsdf, level=0.0, spacing=(self.voxel,) * 3,
                                            mask=observed, allow_degenerate=False)
        # marching_cubes orients faces towards increasing values (free space): keep that
        m = trimesh.Trimesh(verts + self.origin, faces[:, ::-1], process=True)
        m.remove_unreferenced_vertices()
        return m


def noisy_depth(depth: np.ndarray, rng: np.random.Generator,
                max_range: float = 7.5, dropout: float = 0.03,
                noise_scale: float = 0.5) -> np.ndarray:
    """A depth sensor's view of the exact depth ``depth`` (H, W; 0 = nothing): see the module
    docstring; ``noise_scale`` scales the axial noise and the quantisation step (0.5: the
    Kinect-v1 model at half, a newer sensor, since the boxes scene is viewed from 3-7 m).
    Returns (H, W) float32, 0 where there is no measurement."""
    import cv2

    d = np.asarray(depth, np.float32).copy()
    valid = (d > 0) & (d < max_range)
    d[~valid] = 0.0
    # mixed pixels across discontinuities: a small blur of the (filled) depth
    filled = np.where(valid, d, max_range).astype(np.float32)
    mixed = cv2.GaussianBlur(filled, (0, 0), 0.8)
    # the usual edge filter drops pixels whose 3x3 depth range is large
    rng_local = cv2.dilate(filled, np.ones((3, 3))) - cv2.erode(filled, np.ones((3, 3)))
    keep = valid & (rng_local < 0.08 * filled) & (mixed < max_range * 0.98)
    d = np.where(keep, mixed, 0.0)
    # axial noise and disparity quantisation
    sigma = noise_scale * (0.0012 + 0.0019 * (d - 0.4) ** 2)
    d = d + rng.normal(0, 1, d.shape).astype(np.float32) * sigma
    step = noise_scale * 0.0028 * d**2
    d = np.where(d > 0, np.round(d / np.maximum(step, 1e-6)) * step, 0.0)
    # blob dropouts: a smooth random field thresholded to ``dropout`` of the pixels
    if dropout > 0:
        field = cv2.GaussianBlur(rng.normal(0, 1, d.shape).astype(np.float32), (0, 0), 4.0)
        d[field > np.quantile(field, 1.0 - dropout)] = 0.0
    return np.where(keep, d, 0.0).astype(np.float32)


def _scan_poses(n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """A handheld capture: two loose arcs in front of the boxes' wall at two heights, aimed at
    points around the boxes (the RGB-D camera that made the mesh, not the photos)."""
    from pgt_eval import _look_at

    poses = []
    for i in range(n):
        a = -1.1 + 2.2 * (i % (n // 2)) / max(n // 2 - 1, 1)
        high = i >= n // 2
        r = 3.2 + 0.8 * rng.uniform() + (0.4 if high else 0.0)
        eye = np.array([r * np.sin(a), -r * np.cos(a), (2.3 if high else 1.2) + 0.2 * rng.normal()])
        target = np.array([0.0, 0.8, 0.5]) + rng.normal(0, [0.6, 0.5, 0.2])
        poses.append(_look_at(eye, target))
    return poses


def _jitter(world_from_cam: np.ndarray, rot_deg: float, trans: float,
            rng: np.random.Generator) -> np.ndarray:
    from pgt_eval import perturb_pose

    return perturb_pose(world_from_cam, abs(rng.normal(0, rot_deg)), abs(rng.normal(0, trans)), rng)


def tsdf_fuse_mesh(scene, seed: int = 0, n_views: int = 40, voxel: float = 0.04,
                   size: tuple[int, int] = (160, 120), bounds=BOXES_BOUNDS,
                   tracking_deg: float = 0.15, tracking_m: float = 0.01,
                   keep_fraction: float = 0.3):
    """The trimesh ``scene`` (e.g. ``boxes_scene()``) as an RGB-D scan makes it: ``n_views``
    depth maps rendered along ``_scan_poses`` at ``size``, degraded by ``noisy_depth``, fused
    into a ``TsdfVolume`` (``voxel`` m, truncation 3 voxels) at poses with a tracking error
    (``tracking_deg`` / ``tracking_m`` standard deviations), marching cubes, quadric decimation
    to ``keep_fraction`` of the faces (fast_simplification, when installed). Returns a
    grey trimesh. Needs scikit-image (see ``TsdfVolume.mesh``)."""
    import trimesh

    from pgt_check.render import make_renderer, mesh_from_trimesh
    from pgt_check.types import Camera

    rng = np.random.default_rng(seed)
    w, h = size
    cam = Camera.pinhole(w, h, 0.9 * w, 0.9 * w, (w - 1) / 2, (h - 1) / 2)
    vol = TsdfVolume.empty(*bounds, voxel=voxel)
    r = make_renderer(mesh_from_trimesh(scene, shading="shaded"))
    try:
        for pose in _scan_poses(n_views, rng):
            d = noisy_depth(r.render(cam, pose).depth, rng)
            vol.integrate(d, cam.K, _jitter(pose, tracking_deg, tracking_m, rng))
    finally:
        r.close()
    m = vol.mesh()
    if keep_fraction < 1.0:
        try:
            import fast_simplification

            v, f = fast_simplification.simplify(m.vertices.astype(np.float32), m.faces,
                                                target_reduction=1.0 - keep_fraction)
            m = trimesh.Trimesh(v, f, process=True)
        except ImportError:  # the fused mesh as it is
            pass
    m.visual.vertex_colors = np.array([[170, 170, 170, 255]] * len(m.vertices), np.uint8)
    return m


def clutter(seed: int = 0):
    """Objects in the photos that the scan lacks (trimesh list): a person's legs and feet
    beside the boxes, a cylinder (a bin), cables on the floor (thin bent bars), a bag."""
    import trimesh

    rng = np.random.default_rng(seed)
    parts = []
    for dx in (-0.12, 0.12):  # legs and feet
        leg = trimesh.creation.cylinder(radius=0.06, height=0.9)
        leg.apply_translation([1.9 + dx, -0.2, 0.45])
        foot = trimesh.creation.box([0.11, 0.27, 0.09])
        foot.apply_translation([1.9 + dx, -0.27, 0.045])
        parts += [leg, foot]
    bin_ = trimesh.creation.cylinder(radius=0.22, height=0.6)
    bin_.apply_translation([0.9, -0.7, 0.3])
    bag = trimesh.creation.box([0.35, 0.2, 0.28])
    bag.apply_transform(trimesh.transformations.rotation_matrix(0.5, [0, 0, 1]))
    bag.apply_translation([-1.7, -0.5, 0.14])
    parts += [bin_, bag]
    for _ in range(2):  # cables: chains of thin bars wandering over the floor
        p = np.array([rng.uniform(-1.5, 1.0), rng.uniform(-1.2, -0.6), 0.012])
        ang = rng.uniform(0, np.pi)
        for _ in range(6):
            ang += rng.normal(0, 0.5)
            seg = 0.4
            bar = trimesh.creation.box([seg, 0.025, 0.025])
            bar.apply_transform(trimesh.transformations.rotation_matrix(ang, [0, 0, 1]))
            mid = p + 0.5 * seg * np.array([np.cos(ang), np.sin(ang), 0])
            bar.apply_translation(mid)
            parts.append(bar)
            p = p + seg * np.array([np.cos(ang), np.sin(ang), 0])
    for m in parts:
        rgb = rng.integers(30, 120, 3)
        m.visual.vertex_colors = np.array([[*rgb, 255]] * len(m.vertices), np.uint8)
    return parts


def degrade_photo(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A handheld camera's photo: exposure gain 0.55-1.45 and gamma, vignetting, defocus blur
    (sigma 0.6-1.8 px) or a short motion blur, sensor noise."""
    import cv2

    h, w = img.shape[:2]
    img = np.clip(img * rng.uniform(0.55, 1.45), 0, 1) ** rng.uniform(0.8, 1.25)
    yy, xx = np.mgrid[0:h, 0:w]
    rr = np.hypot((xx - w / 2) / w, (yy - h / 2) / h)
    img = img * (1.0 - 0.5 * rr**2)[..., None].astype(np.float32)
    if rng.uniform() < 0.3:  # motion blur: a line kernel of 3-7 px
        k = int(rng.integers(3, 8))
        ker = np.zeros((k, k), np.float32)
        ker[k // 2] = 1.0 / k
        rot = cv2.getRotationMatrix2D(((k - 1) / 2, (k - 1) / 2), rng.uniform(0, 180), 1.0)
        ker = cv2.warpAffine(ker, rot, (k, k))
        img = cv2.filter2D(img.astype(np.float32), -1, ker / max(ker.sum(), 1e-6))
    else:
        img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), rng.uniform(0.6, 1.8))
    return img + rng.normal(0, 0.025, img.shape).astype(np.float32)


def make_tsdf_scene(out_dir: str | Path, n_frames: int = 12, seed: int = 0,
                    size: tuple[int, int] = (320, 240), **fuse) -> Path:
    """A textureless scene as an RGB-D capture gives it (issue #29): ``tsdf.ply`` is
    ``tsdf_fuse_mesh`` of the boxes (``fuse``: its keyword arguments), the photos are of the
    clean boxes plus ``clutter`` (legs and feet, a bin, a bag, cables), ``degrade_photo`` and
    JPEG 75; LaMAR files with the TRUE poses. Returns the trajectory path. Needs scikit-image."""
    import trimesh

    from pgt_check.types import Camera
    from pgt_eval import _photograph_boxes, boxes_scene

    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    scene = boxes_scene(seed)
    tsdf_fuse_mesh(scene, seed, **fuse).export(out / "tsdf.ply")
    photo_scene = trimesh.Scene([*scene.geometry.values(), *clutter(seed)])
    w, h = size
    cam = Camera.pinhole(w, h, 0.9 * w, 0.9 * w, (w - 1) / 2, (h - 1) / 2)
    return _photograph_boxes(out, photo_scene, cam, n_frames, np.random.default_rng(seed + 2),
                             degrade_photo, 75)
