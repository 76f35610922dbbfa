"""Evaluation helpers shared by tests and benchmarks (not part of ``pgt_check``): injected pose
errors (per frame, shared, drift, intrinsics, time offset), ROC-AUC and generated scenes
(textureless boxes, scan-like meshes)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pgt_check.geometry.transforms import axis_angle_to_rotmat, move_pose
from pgt_check.types import Frame, Trajectory, check_shape


@dataclass(frozen=True)
class Perturbation:
    """An injected pose error: rotation (deg) about a random axis through the camera centre and
    a camera-centre translation (scene units) in a random direction."""

    frame_id: str
    rotation_deg: float
    translation: float


def perturb_pose(
    world_from_cam: np.ndarray, rotation_deg: float, translation: float, rng: np.random.Generator
) -> np.ndarray:
    """Return world_from_cam with a random-axis rotation (camera frame) and a centre shift."""
    world_from_cam = np.asarray(world_from_cam, dtype=np.float64)
    check_shape("world_from_cam", world_from_cam, (4, 4))
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    out = world_from_cam.copy()
    out[:3, :3] = world_from_cam[:3, :3] @ axis_angle_to_rotmat(axis, rotation_deg)
    out[:3, 3] = world_from_cam[:3, 3] + translation * direction
    return out


def perturb_trajectory(
    trajectory: Trajectory,
    fraction: float,
    rotation_deg: tuple[float, float],
    translation: tuple[float, float],
    seed: int = 0,
) -> tuple[Trajectory, list[Perturbation]]:
    """Perturb a random ``fraction`` of frames with rotation and translation drawn uniformly
    from the given (low, high) ranges. Returns the new trajectory and what was injected."""
    rng = np.random.default_rng(seed)
    n = len(trajectory)
    k = int(round(fraction * n))
    chosen = set(rng.choice(n, size=k, replace=False).tolist()) if k else set()
    return _perturb_chosen(trajectory, chosen, rotation_deg, translation, rng)


def _perturb_chosen(
    trajectory: Trajectory, chosen: set[int], rotation_deg: tuple[float, float],
    translation: tuple[float, float], rng: np.random.Generator,
) -> tuple[Trajectory, list[Perturbation]]:
    """The trajectory with each frame at a position in ``chosen`` moved by its own random
    rotation and translation (drawn in trajectory order from ``rng``), and what was injected."""
    frames: list[Frame] = []
    injected: list[Perturbation] = []
    for i, f in enumerate(trajectory.frames):
        if i in chosen:
            r = float(rng.uniform(*rotation_deg))
            t = float(rng.uniform(*translation))
            frames.append(f.with_pose(perturb_pose(f.world_from_cam, r, t, rng)))
            injected.append(Perturbation(f.frame_id, r, t))
        else:
            frames.append(f)
    return (
        Trajectory(tuple(frames), trajectory.source, trajectory.format, dict(trajectory.metadata)),
        injected,
    )


def perturb_runs(
    trajectory: Trajectory,
    fraction: float,
    rotation_deg: tuple[float, float],
    translation: tuple[float, float],
    run_length: tuple[int, int] = (2, 4),
    seed: int = 0,
) -> tuple[Trajectory, list[Perturbation]]:
    """Like ``perturb_trajectory``, but the wrong frames come in contiguous runs (trajectory
    order) of ``run_length`` (low, high; inclusive) frames, so that a wrong frame's neighbours
    (the references of relative evidence) are often wrong too. Each wrong frame has its own
    rotation (random axis) and translation (random direction), drawn uniformly from the ranges;
    runs never touch (a correct frame between two runs). ``round(fraction * n)`` frames in all
    (fewer only when the runs cannot be placed)."""
    rng = np.random.default_rng(seed)
    n = len(trajectory)
    k = int(round(fraction * n))
    chosen: set[int] = set()
    for _ in range(100 * max(1, n)):
        left = k - len(chosen)
        if left <= 0:
            break
        length = min(int(rng.integers(run_length[0], run_length[1] + 1)), left)
        start = int(rng.integers(0, max(1, n - length + 1)))
        span = range(start, min(n, start + length))
        # a run neither overlaps nor touches another one
        if any(i in chosen for i in range(max(0, start - 1), min(n, start + length + 1))):
            continue
        chosen.update(span)
    return _perturb_chosen(trajectory, chosen, rotation_deg, translation, rng)


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """ROC-AUC of ``scores`` (higher = more likely positive) against boolean ``labels``.

    Ties count one half (Mann-Whitney U). Non-finite scores are treated as the highest score
    (an unverifiable frame is flagged). Raises ValueError if only one class is present.
    """
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    labels = np.asarray(labels, dtype=bool).reshape(-1)
    check_shape("labels", labels, (len(scores),))
    pos, neg = scores[labels], scores[~labels]
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError("roc_auc needs both positive and negative labels")
    big = np.nanmax(np.where(np.isfinite(scores), scores, -np.inf))
    big = (big if np.isfinite(big) else 0.0) + 1.0
    pos = np.where(np.isfinite(pos), pos, big)
    neg = np.where(np.isfinite(neg), neg, big)
    greater = (pos[:, None] > neg[None, :]).sum()
    ties = (pos[:, None] == neg[None, :]).sum()
    return float((greater + 0.5 * ties) / (len(pos) * len(neg)))


# -- errors that neighbouring frames share (see README "What a verdict proves") ---------------
def _random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def shared_transform(
    traj: Trajectory, rotation_deg: float, translation: float, scale: float = 1.0, seed: int = 0
) -> np.ndarray:
    """A similarity ``moved_world_from_world`` about the camera centroid: rotation (random
    axis), translation (random direction, scene units), scale. (4, 4) float64."""
    rng = np.random.default_rng(seed)
    c = np.mean([f.center for f in traj.frames], axis=0)
    r = axis_angle_to_rotmat(_random_unit(rng), rotation_deg)
    m = np.eye(4)
    m[:3, :3] = scale * r
    m[:3, 3] = c - scale * r @ c + translation * _random_unit(rng)
    return m


def move_trajectory(traj: Trajectory, moved_from_world: np.ndarray) -> Trajectory:
    """Every pose moved by one rigid / similarity transform (a misregistered trajectory)."""
    frames = [f.with_pose(move_pose(f.world_from_cam, moved_from_world)) for f in traj.frames]
    return Trajectory(frames, traj.source, traj.format)


def drift_trajectory(
    traj: Trajectory, start: float, rotation_deg: float, translation: float, seed: int = 0
) -> tuple[Trajectory, list[str]]:
    """A drifting segment: from fraction ``start`` of the frames to the end the error grows
    linearly to ``rotation_deg`` + ``translation`` (one axis and direction, about each camera
    centre). Returns the trajectory and the ids of the drifting frames."""
    rng = np.random.default_rng(seed)
    axis, direction = _random_unit(rng), _random_unit(rng)
    n = len(traj.frames)
    i0 = int(round(start * n))
    frames, ids = [], []
    for i, f in enumerate(traj.frames):
        if i < i0:
            frames.append(f)
            continue
        a = (i - i0 + 1) / (n - i0)
        m = np.eye(4)
        m[:3, :3] = axis_angle_to_rotmat(axis, rotation_deg * a)
        c = f.center
        m[:3, 3] = c - m[:3, :3] @ c + translation * a * direction
        frames.append(f.with_pose(move_pose(f.world_from_cam, m)))
        ids.append(f.frame_id)
    return Trajectory(frames, traj.source, traj.format), ids


def change_intrinsics(
    traj: Trajectory, focal_scale: float = 1.0, principal_shift: tuple[float, float] = (0, 0)
) -> Trajectory:
    """Every frame's camera with a focal length scaled and a principal point shifted (px)."""
    from dataclasses import replace

    frames = []
    for f in traj.frames:
        cam = f.camera
        fx, fy = cam.focal
        cx, cy = cam.principal_point
        new = type(cam).pinhole(cam.width, cam.height, fx * focal_scale, fy * focal_scale,
                                cx + principal_shift[0], cy + principal_shift[1])
        if cam.model not in ("PINHOLE", "SIMPLE_PINHOLE"):
            raise ValueError(f"change_intrinsics supports pinhole cameras, got {cam.model}")
        frames.append(replace(f, camera=new))
    return Trajectory(frames, traj.source, traj.format)


def time_offset_trajectory(traj: Trajectory, offset: int) -> Trajectory:
    """Each image paired with the pose ``offset`` frames later (clamped at the ends): a time
    offset between the image stream and the poses."""
    n = len(traj.frames)
    frames = [
        f.with_pose(traj.frames[min(max(i + offset, 0), n - 1)].world_from_cam)
        for i, f in enumerate(traj.frames)
    ]
    return Trajectory(frames, traj.source, traj.format)


# -- a generated textureless scene (plain boxes on a floor), for the geometric-edge path -------
def _look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    m[:3, 3] = eye
    return m


def boxes_scene(seed: int = 0):
    """Plain-coloured boxes of different sizes on a grey floor and a back wall (trimesh Scene):
    no texture at all, only geometry."""
    import trimesh

    def coloured(mesh, rgb):
        mesh.visual.vertex_colors = np.array([[*rgb, 255]] * len(mesh.vertices), np.uint8)
        return mesh

    floor = trimesh.Trimesh([[-6, -6, 0], [6, -6, 0], [6, 6, 0], [-6, 6, 0]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    wall = trimesh.Trimesh([[-6, 4, 0], [6, 4, 0], [6, 4, 3], [-6, 4, 3]],
                           [[0, 1, 2], [0, 2, 3]], process=False)
    parts = [coloured(floor, (150, 150, 150)), coloured(wall, (175, 175, 170))]
    rng = np.random.default_rng(seed)
    for x, y, sx, sy, sz in [(0, 0, 0.8, 0.6, 0.7), (1.3, 0.6, 0.5, 0.5, 1.2),
                             (-1.2, 0.8, 0.6, 0.9, 0.5), (0.4, 1.8, 1.2, 0.4, 0.9),
                             (-0.6, -1.0, 0.4, 0.4, 0.4), (-2.0, 2.5, 0.7, 0.7, 1.6)]:
        box = trimesh.creation.box(extents=[sx, sy, sz])
        box.apply_translation([x, y, sz / 2])
        parts.append(coloured(box, tuple(int(c) for c in rng.integers(60, 200, 3))))
    return trimesh.Scene(parts)


def _photograph_boxes(out: Path, photo_scene, cam, n_frames: int, rng: np.random.Generator,
                      degrade, jpeg_quality: int) -> Path:
    """Photos of ``photo_scene`` along an arc in front of the boxes' wall (vertex colours mixed
    with head-light shading, then ``degrade(img, rng)``, JPEG) and LaMAR files with the TRUE
    poses in ``out``; returns the trajectory path. Shared by the generated scenes."""
    import cv2

    from pgt_check.io.lamar_write import write_lamar
    from pgt_check.render import make_renderer, mesh_from_trimesh

    coloured = make_renderer(mesh_from_trimesh(photo_scene))
    shaded = make_renderer(mesh_from_trimesh(photo_scene, shading="shaded"))
    frames = []
    try:
        for i in range(n_frames):
            a = -0.9 + 1.8 * i / max(n_frames - 1, 1)  # an arc in front of the wall
            r = 4.0 + 0.5 * np.sin(3 * a)
            eye = np.array([r * np.sin(a), -r * np.cos(a), 1.6 + 0.3 * np.cos(2 * a)])
            pose = _look_at(eye, np.array([0.0, 0.6, 0.5]))
            img = 0.4 * shaded.render(cam, pose).rgb + 0.65 * coloured.render(cam, pose).rgb
            img = degrade(img, rng)
            name = f"images/{i:04d}.jpg"
            cv2.imwrite(str(out / name),
                        cv2.cvtColor((np.clip(img, 0, 1) * 255).astype(np.uint8),
                                     cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            frames.append(Frame(f"{i}", cam, pose, image_path=name, image_file=out / name,
                                timestamp=float(i)))
    finally:
        coloured.close()
        shaded.close()
    write_lamar(Trajectory(tuple(frames), str(out), "lamar"), out)
    return out / "trajectories.txt"


def make_textureless_scene(out_dir: str | Path, n_frames: int = 24, seed: int = 0,
                           size: tuple[int, int] = (320, 240)) -> Path:
    """Write a textureless scene: ``boxes.ply`` (plain vertex colours), photos rendered at the
    true poses (colours mixed with head-light shading, blur, noise, JPEG), and LaMAR files
    (``sensors.txt``, ``images.txt``, ``trajectories.txt``) with the TRUE poses. Returns the
    trajectory path. The camera circles the boxes at 3.5-4.5 m, looking at the centre."""
    import cv2
    import trimesh

    from pgt_check.types import Camera

    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    scene = boxes_scene(seed)
    mesh = trimesh.util.concatenate(list(scene.geometry.values()))
    mesh.export(out / "boxes.ply")  # generated here: not a copy of any shared dataset
    w, h = size
    cam = Camera.pinhole(w, h, 0.9 * w, 0.9 * w, (w - 1) / 2, (h - 1) / 2)

    def degrade(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        img = cv2.GaussianBlur(img, (0, 0), 0.7)
        return img + rng.normal(0, 0.015, img.shape).astype(np.float32)

    return _photograph_boxes(out, scene, cam, n_frames, np.random.default_rng(seed), degrade, 85)


def textureless_scene(out_dir: str | Path, n_frames: int = 24) -> tuple[Trajectory, Path]:
    """The textureless scene in ``out_dir`` (written first if missing): (trajectory, mesh)."""
    from pgt_check.io import read_trajectory

    out = Path(out_dir)
    if not (out / "trajectories.txt").is_file():
        make_textureless_scene(out, n_frames)
    return read_trajectory(out / "trajectories.txt"), out / "boxes.ply"


# -- a scan-like version of the textureless scene (issue #29) ---------------------------------
def scan_like_mesh(mesh, seed: int = 0, edge_len: float = 0.08, noise: float = 0.01,
                   smooth_iters: int = 6, hole_fraction: float = 0.04, keep_fraction: float = 0.5):
    """The boxes mesh as a depth-sensor scan would make it (a documented approximation of TSDF
    fusion of noisy depth, without marching cubes, which needs scikit-image): subdivided to
    ~``edge_len`` m, vertices moved by Gaussian noise (``noise`` m) along their normals,
    Taubin smoothing (rounded edges and creases, no shrinking), blob-shaped holes (about
    ``hole_fraction`` of the faces removed around random seeds), quadric decimation to
    ``keep_fraction`` of the faces (fast_simplification, when installed). Returns a trimesh."""
    import trimesh

    rng = np.random.default_rng(seed)
    m = trimesh.Trimesh(mesh.vertices.copy(), mesh.faces.copy(), process=True)
    v, f = trimesh.remesh.subdivide_to_size(m.vertices, m.faces, max_edge=edge_len)
    m = trimesh.Trimesh(v, f, process=True)
    m.vertices += m.vertex_normals * rng.normal(0, noise, (len(m.vertices), 1))
    trimesh.smoothing.filter_taubin(m, lamb=0.5, nu=0.53, iterations=smooth_iters)
    centres = m.triangles_center
    drop = np.zeros(len(m.faces), bool)
    n_holes = max(1, int(hole_fraction * len(m.faces) / 60))
    for c in centres[rng.choice(len(centres), n_holes, replace=False)]:
        drop |= np.linalg.norm(centres - c, axis=1) < rng.uniform(0.08, 0.25)
    m.update_faces(~drop)
    m.remove_unreferenced_vertices()
    try:
        import fast_simplification

        v, f = fast_simplification.simplify(m.vertices.astype(np.float32), m.faces,
                                            target_reduction=1.0 - keep_fraction)
        m = trimesh.Trimesh(v, f, process=False)
    except ImportError:  # the noisy, smoothed, holed mesh as it is
        pass
    m.visual.vertex_colors = np.array([[170, 170, 170, 255]] * len(m.vertices), np.uint8)
    return m


def make_scan_like_scene(out_dir: str | Path, n_frames: int = 12, seed: int = 0,
                         size: tuple[int, int] = (320, 240)) -> Path:
    """A textureless scene as a handheld RGB-D capture gives it: the mesh ``scan.ply`` is
    ``scan_like_mesh`` of the boxes (rounded, holed, decimated, no colours), the photos are of
    the clean boxes plus objects that are not in the mesh (a cylinder, a thin cable-like bar),
    with exposure changes (gain 0.6-1.4), blur (sigma 0.7-1.8 px), noise and JPEG. LaMAR files
    with the TRUE poses. Returns the trajectory path."""
    import cv2
    import trimesh

    from pgt_check.types import Camera

    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    scene = boxes_scene(seed)
    clean = trimesh.util.concatenate(list(scene.geometry.values()))
    scan_like_mesh(clean, seed).export(out / "scan.ply")
    extra = [trimesh.creation.cylinder(radius=0.25, height=1.0), trimesh.creation.box([2.5, 0.05, 0.05])]
    extra[0].apply_translation([0.9, -0.6, 0.5])
    extra[1].apply_translation([-0.3, -0.4, 0.03])
    for e in extra:
        e.visual.vertex_colors = np.array([[90, 80, 70, 255]] * len(e.vertices), np.uint8)
    photo_scene = trimesh.Scene([*scene.geometry.values(), *extra])
    w, h = size
    cam = Camera.pinhole(w, h, 0.9 * w, 0.9 * w, (w - 1) / 2, (h - 1) / 2)

    def degrade(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        img = img * rng.uniform(0.6, 1.4)
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.7, 1.8))
        return img + rng.normal(0, 0.03, img.shape).astype(np.float32)

    return _photograph_boxes(out, photo_scene, cam, n_frames, np.random.default_rng(seed + 1),
                             degrade, 75)


# -- the TSDF-fused scene (issue #29) lives in pgt_eval.tsdf (marching cubes needs scikit-image)
from pgt_eval.tsdf import TsdfVolume, make_tsdf_scene, noisy_depth, tsdf_fuse_mesh  # noqa: E402, F401
