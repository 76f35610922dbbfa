"""The bare idea of pgt-check, as a user writes it in an afternoon: for each frame, read the
photo, render the mesh at the pose, SIFT on both, ratio-test matching, a RANSAC homography and
its corner error. No verdicts, paths, run-level checks, corrections or report.

It is the baseline the default run is timed against (issue #28, ``reports/pipeline_timing.md``):
run it as a whole process beside ``pgt-check`` on the same frames, e.g.

    python benchmarks/bare_loop.py $PGT_SHARED_DATA/7scenes_redkitchen/trajectories.txt \
        --mesh $PGT_SHARED_DATA/7scenes_redkitchen/mesh.ply --limit 30

Same renderer as the run, longest side ``--resize-max`` (default 640 px: the issue's baseline;
the run's ``match.resize_max`` is 320 px since issue #28, its edge path 640 / 1024 px),
OpenCV SIFT with its default settings, brute-force k=2 matching, Lowe ratio 0.8,
``cv2.findHomography`` RANSAC at 3 px. Prints one line per frame and the median.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time


def corner_error(h, w: int, hgt: int) -> float:
    import numpy as np

    c = np.array([[0, 0, 1], [w - 1, 0, 1], [w - 1, hgt - 1, 1], [0, hgt - 1, 1]], float).T
    p = h @ c
    p = p[:2] / p[2]
    return float(np.mean(np.linalg.norm(p - c[:2], axis=0)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trajectory")
    ap.add_argument("--mesh", required=True)
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--resize-max", type=int, default=640)
    ap.add_argument("-q", "--quiet", action="store_true")
    args = ap.parse_args(argv)

    import cv2
    import numpy as np

    from pgt_check.io import load_image, read_trajectory
    from pgt_check.io.images import resize_image
    from pgt_check.io.photo import prepare_photo, working_scale
    from pgt_check.render import load_mesh, make_renderer

    t0 = time.perf_counter()
    frames = list(read_trajectory(args.trajectory).frames)[: args.limit]
    renderer = make_renderer(load_mesh(args.mesh))
    sift = cv2.SIFT_create()
    bf = cv2.BFMatcher(cv2.NORM_L2)
    errors = []
    try:
        for f in frames:
            photo, cam = prepare_photo(load_image(f.image_file), f.camera)
            size = working_scale(cam.width, cam.height, args.resize_max)
            cam_w = cam.scaled(size[0] / cam.width, size[1] / cam.height)
            photo_w = resize_image(photo, size)
            render = renderer.render(cam_w, f.world_from_cam)
            grey = [cv2.cvtColor((np.clip(im, 0, 1) * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
                    for im in (render.rgb, photo_w)]
            (k0, d0), (k1, d1) = (sift.detectAndCompute(g, None) for g in grey)
            err = float("inf")
            if d0 is not None and d1 is not None and len(k0) > 1 and len(k1) > 1:
                good = [m for m, n in (p for p in bf.knnMatch(d0, d1, k=2) if len(p) == 2)
                        if m.distance < 0.8 * n.distance]
                if len(good) >= 4:
                    p0 = np.float32([k0[m.queryIdx].pt for m in good])
                    p1 = np.float32([k1[m.trainIdx].pt for m in good])
                    h, _ = cv2.findHomography(p0, p1, cv2.RANSAC, 3.0)
                    if h is not None:
                        err = corner_error(h, *size) * cam.width / size[0]
            errors.append(err)
            if not args.quiet:
                print(f"{f.frame_id}: corner error {err:.2f} px")
    finally:
        renderer.close()
    finite = [e for e in errors if np.isfinite(e)]
    print(f"{len(frames)} frames in {time.perf_counter() - t0:.2f} s; median corner error "
          f"{statistics.median(finite) if finite else float('nan'):.2f} px "
          f"({len(finite)} with a homography)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
