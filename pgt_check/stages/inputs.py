"""What a run reads, checked and keyed before any frame is measured: the trajectory
(``load_trajectory``), the preflight build of the frame checker (mesh, renderer, matcher,
enhancer: setup errors surface here, not per frame), image paths outside the dataset folder,
and the content hashes that key the stored measurements (``measurement_fingerprint`` for the
run, ``frame_input_keys`` per frame). Used by ``pgt_check.runner``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pgt_check.common.files import check_inputs_not_outputs
from pgt_check.config import RunConfig
from pgt_check.content_hash import content_hash
from pgt_check.errors import InputError, MissingExtraError, SetupError
from pgt_check.measure import SCHEMA_VERSION
from pgt_check.types import Frame, Trajectory

logger = logging.getLogger(__name__)


def load_trajectory(config: RunConfig) -> Trajectory:
    from pgt_check.io import read_trajectory

    inp = config.input
    if not inp.trajectory:
        raise InputError("no trajectory given")
    if not inp.mesh:
        raise InputError("no mesh given (--mesh)")
    if not Path(inp.mesh).is_file():
        raise InputError(f"mesh not found: {inp.mesh}")
    traj = read_trajectory(
        inp.trajectory,
        inp.format,
        images=inp.images,
        camera=inp.camera,
        sensors=inp.sensors,
        dataparser_transforms=inp.dataparser_transforms,
    )
    if len(traj) == 0:
        raise InputError(f"{inp.trajectory}: no frames with both a pose and an image")
    return traj


def run_output_paths(out: str | Path) -> list[Path]:
    """Every file and folder a run writes in ``out`` (an input there would be overwritten):
    ``OutputLayout.top_level``."""
    from pgt_check.output_layout import OUTPUTS

    return OUTPUTS.paths(out)


def check_side_inputs(config: RunConfig, frames: Sequence[Frame]) -> None:
    """Validate the run's other input files before any frame is measured (a typo must not cost
    the whole run): no input is one of the outputs the run writes into ``--out``;
    ``--calibration-from`` is a trusted summary.json with an estimate for every camera of
    ``frames``; the mesh fits in memory (``check_mesh_memory``). Raises InputError."""
    from pgt_check.measure.record import camera_key
    from pgt_check.verdict.calibration import trusted_calibration

    inp = config.input
    named: list[tuple[str, str | Path | None]] = [
        ("trajectory", inp.trajectory), ("mesh", inp.mesh), ("images", inp.images),
        ("sensors file", inp.sensors), ("dataparser transforms", inp.dataparser_transforms),
        ("--calibration-from summary", config.run_checks.calibration_from)]
    named += [("image", f.image_file) for f in frames]
    check_inputs_not_outputs(named, run_output_paths(config.out), "--out")
    if config.run_checks.calibration_from:
        trusted_calibration(
            config.run_checks.calibration_from, sorted({camera_key(f.camera) for f in frames})
        )
    check_mesh_memory(config, frames)


def check_mesh_memory(config: RunConfig, frames: Sequence[Frame]) -> None:
    """Refuse (SetupError, one line) a run whose mesh and render buffers will not fit in the
    available memory, estimated from the mesh file's header before anything is loaded
    (``pgt_check.render.memory``): one process renders (serial, or a remote Dask cluster whose
    workers are on other machines) or each of the local worker processes loads its own copy."""
    from pgt_check.render.memory import check_memory_fits

    if not config.input.mesh or not Path(config.input.mesh).is_file() or not frames:
        return  # a missing mesh is reported by the preflight
    workers = 0
    if config.executor == "process" or (config.executor == "dask" and not config.scheduler):
        from pgt_check.executor.common import default_workers

        workers = config.workers or default_workers()
    width, height = _largest_render(config, frames)
    counts, need, available = check_memory_fits(config.input.mesh, width, height, workers)
    logger.info(
        "mesh %s: %d faces%s; memory estimate %.2f GiB of %s available", config.input.mesh,
        counts.n_faces, "" if counts.exact else " (guessed from the file size)", need / 2**30,
        "unknown" if available is None else f"{available / 2**30:.1f} GiB")


def _largest_render(config: RunConfig, frames: Sequence[Frame]) -> tuple[int, int]:
    """The largest image the renderer draws: each camera scaled to the working size (the larger
    of the matching and the edge path's longest side; None = the camera's own size), at most
    ``input.max_image_pixels`` (a larger frame is UNVERIFIABLE before it is rendered)."""
    from pgt_check.io.photo import working_scale

    sides = (config.match.resize_max, config.edges.resize_max)
    longest = None if any(s is None for s in sides) else max(s for s in sides if s is not None)
    cap = config.input.max_image_pixels
    width = height = 1
    for f in frames:
        w, h = working_scale(f.camera.width, f.camera.height, longest)
        if cap is not None and w * h > cap:
            k = math.sqrt(cap / (w * h))
            w, h = max(1, int(w * k)), max(1, int(h * k))
        width, height = max(width, w), max(height, h)
    return width, height


def preflight(config: RunConfig, references: Any = None, panel_sink: Any = None) -> Any:
    """Build the frame checker once before the run: the mesh is loaded and validated, the
    renderer, matcher and (unless ``enhance.mode`` is never) the enhancer are built.

    Raises InputError for a mesh that cannot be loaded or is unusable (no faces, non-finite
    vertices), MissingExtraError for an extra that is not installed and SetupError for a method
    that cannot be built (missing weights, a backend that fails); nothing of this becomes a
    per-frame outcome. Returns the checker (the caller closes it).
    """
    import numpy as np

    from pgt_check.measure import FrameChecker

    checker = FrameChecker(config, dict(references or {}), panel_sink=panel_sink)
    mesh_path = config.input.mesh
    try:
        try:
            mesh = checker.mesh
        except (InputError, MemoryError):
            raise
        except Exception as err:  # trimesh raises many types for broken files
            raise InputError(f"{mesh_path}: cannot load mesh ({type(err).__name__}: {err})") from err
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        if faces.size == 0:
            raise InputError(f"{mesh_path}: the mesh has no triangles (a point cloud?)")
        if not np.isfinite(vertices).all():
            n = int((~np.isfinite(vertices).all(axis=1)).sum())
            raise InputError(f"{mesh_path}: {n} mesh vertices are not finite (NaN or inf)")
        stages = [
            (f"renderer {config.render.backend!r}", lambda: checker.renderer),
            (f"matcher {config.match.method!r}", lambda: checker.matcher),
        ]
        if config.enhance.mode != "never":
            stages.append((f"enhancer {config.enhance.method!r}", lambda: checker.enhancer))
        for what, build in stages:
            try:
                built = build()
                load = getattr(built, "_load", None)  # lazy model loaders (MaRINeR): load now
                if callable(load):
                    load()
            except (InputError, MemoryError):
                raise
            except ImportError as err:
                raise MissingExtraError(err.name or str(err), "enhance") from err
            except Exception as err:
                raise SetupError(f"cannot build the {what}: {type(err).__name__}: {err}") from err
    except BaseException:
        checker.close()
        raise
    return checker


def images_outside_dataset(config: RunConfig, frames: Sequence[Frame]) -> list[str]:
    """Image paths (as written) that lie outside the dataset folder: the trajectory's folder
    (the model folder for COLMAP) or the ``--images`` folder. Such paths are read, not refused
    (datasets often keep images elsewhere), but listed in the summary and the report."""
    traj = Path(config.input.trajectory)
    roots = [traj if traj.is_dir() else traj.parent]
    if config.input.images and Path(config.input.images).is_dir():
        roots.append(Path(config.input.images))
    norm_roots = [os.path.normpath(os.path.abspath(r)) for r in roots]
    out = []
    for f in frames:
        if f.image_file is None:
            continue
        p = os.path.normpath(os.path.abspath(f.image_file))
        if not any(p == r or p.startswith(r.rstrip(os.sep) + os.sep) for r in norm_roots):
            out.append(str(f.image_path or f.image_file))
    return out


def frame_input_keys(
    frames: Sequence[Frame], references: Any = None, hashes: dict[str, str] | None = None
) -> dict[str, str]:
    """Per-frame key of what the measurement reads besides the settings: the frame's pose,
    camera, image path and image content hash (``content_hash.content_hash``), and the same of its
    reference frames. A stored record whose key differs is measured again (a pose edited in
    place, a replaced photo). ``hashes``: filled with each image file's content hash."""
    import numpy as np

    cache: dict[str, str] = {} if hashes is None else hashes

    def part(f: Frame) -> dict[str, Any]:
        image = "none"
        if f.image_file is not None:
            k = str(f.image_file)
            if k not in cache:
                cache[k] = content_hash(k)
            image = cache[k]
        cam = f.camera
        return {
            "id": f.frame_id,
            "pose": np.asarray(f.world_from_cam, dtype=np.float64).tolist(),
            "camera": [cam.model, cam.width, cam.height, [float(x) for x in cam.params]],
            "image_path": str(f.image_path),
            "image": image,
        }

    refs = dict(references or {})
    keys = {}
    for f in frames:
        blob = {"frame": part(f), "refs": [part(r) for r in refs.get(f.frame_id, ())]}
        text = json.dumps(blob, sort_keys=True, default=str).encode()
        keys[f.frame_id] = hashlib.sha256(text).hexdigest()[:24]
    return keys


def measurement_fingerprint(config: RunConfig, inputs: dict[str, str] | None = None) -> str:
    """Fingerprint of the stored measurements: their settings, the record layout and the
    content hashes of the run-wide inputs (``inputs``, e.g. the mesh). Per-frame inputs (pose,
    camera, image bytes) are keyed per record (``frame_input_keys``)."""
    if not inputs:
        return config.measurement_fingerprint(schema=SCHEMA_VERSION)
    return config.measurement_fingerprint(schema=SCHEMA_VERSION, inputs=inputs)


#: at most this many images' content hashes are kept in run.json (about 6 MB of its 64 MiB
#: bound); a bigger run keeps them per frame only (``frame_input_keys``)
MAX_RECORDED_IMAGE_HASHES = 50_000


def input_file_hashes(
    config: RunConfig, side_files: Sequence[str] = (), image_hashes: dict[str, str] | None = None,
    metadata: Any = None,
) -> dict[str, str]:
    """Absolute path -> ``content_hash.content_hash`` of every file the run's measurements read: the
    trajectory (a COLMAP model folder hashes by its files), sensors file, dataparser transforms,
    the files the reader found beside the trajectory (``metadata``, ``Trajectory.metadata``: a
    LaMAR session's sensors, images and rigs, hloc's intrinsics), the mesh and the side files
    its loader read (materials, textures, buffers), and the images (``image_hashes``: as
    ``frame_input_keys`` hashed them). run.json keeps them so that ``pgt-check report`` can
    tell which input changed since (``content_hash.changed_inputs``)."""
    inp = config.input
    named = [inp.trajectory, inp.sensors, inp.dataparser_transforms, inp.mesh]
    for key, value in dict(metadata or {}).items():
        if (key.endswith("_file") or key in ("intrinsics", "dataparser_transforms")) \
                and isinstance(value, str) and os.path.isfile(value):
            named.append(value)
    named += [f for f in side_files if not str(f).startswith("missing:")]
    out: dict[str, str] = {}
    for path in named:
        if path:
            key = os.path.abspath(path)
            if key not in out:
                out[key] = content_hash(path)
    images = {p: d for p, d in (image_hashes or {}).items() if d != "missing"}
    if len(images) > MAX_RECORDED_IMAGE_HASHES:  # run.json stays small enough to read back
        logger.info("%d images: their content hashes are kept per frame only (input_key), "
                    "pgt-check report checks the other inputs", len(images))
        return out
    for path, digest in images.items():
        out.setdefault(os.path.abspath(path), digest)
    return out
