from __future__ import annotations

import numpy as np
import pytest

from pgt_check.errors import InputError
from pgt_check.io import parse_camera_spec
from pgt_check.types import Camera


def test_pinhole_spec_half_pixel() -> None:
    """The spec is in COLMAP convention: cx=320 means the OpenCV principal point 319.5."""
    cam = parse_camera_spec("PINHOLE,640,480,525,526,320,240")
    assert cam == Camera.pinhole(640, 480, 525.0, 526.0, 319.5, 239.5)
    assert cam.to_colmap_params() == (525.0, 526.0, 320.0, 240.0)


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("simple_pinhole 64 48 50 32 24", Camera("SIMPLE_PINHOLE", 64, 48, (50.0, 31.5, 23.5))),
        (
            "OPENCV, 64, 48, 50, 51, 32, 24, 0.1, 0.01, 0.001, 0.002",
            Camera("OPENCV", 64, 48, (50, 51, 31.5, 23.5, 0.1, 0.01, 0.001, 0.002)),
        ),
    ],
)
def test_other_models_and_separators(spec: str, expected: Camera) -> None:
    assert parse_camera_spec(spec) == expected


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("", "empty"),
        ("FISHEYE_X,64,48,1,2,3", "expected a model"),
        ("PINHOLE,640,480,525,525,320", "expected 7 fields"),
        ("PINHOLE,640,480,525,525,320,x", "numeric"),
        ("PINHOLE,640.5,480,525,525,320,240", "integer"),
        ("PINHOLE,640,480,-525,525,320,240", "focal"),
        ("PINHOLE,0,480,525,525,320,240", "positive"),
    ],
)
def test_bad_specs(spec: str, fragment: str) -> None:
    with pytest.raises(InputError, match=fragment):
        parse_camera_spec(spec)


# --- the COLMAP pixel shift, one converter ---------------------------------------------------


def test_colmap_opencv_conversion_shifts_only_the_principal_point() -> None:
    from pgt_check.io.camera import colmap_to_opencv_params, opencv_to_colmap_params

    colmap = (500.0, 505.0, 320.0, 240.0, 0.1, -0.01, 0.001, 0.002)
    opencv = colmap_to_opencv_params("OPENCV", colmap)
    assert opencv == (500.0, 505.0, 319.5, 239.5, 0.1, -0.01, 0.001, 0.002)
    assert opencv_to_colmap_params("OPENCV", opencv) == colmap
    assert colmap_to_opencv_params("SIMPLE_RADIAL", (50, 32, 24, 0.5)) == (50, 31.5, 23.5, 0.5)
    # the Camera method and the LaMAR writer use the same converter
    cam = Camera("SIMPLE_RADIAL", 64, 48, colmap_to_opencv_params("SIMPLE_RADIAL", (50, 32, 24, 0)))
    assert cam.to_colmap_params() == (50.0, 32.0, 24.0, 0.0)
    with pytest.raises(ValueError, match="takes 4 parameters"):
        colmap_to_opencv_params("PINHOLE", (1, 2, 3))


def test_pycolmap_camera_agrees_on_the_pixel_convention() -> None:
    """A point on the optical axis projects to (cx, cy) in OpenCV pixels: pycolmap says cx+0.5."""
    from pgt_check.io.camera import distort_points, to_pycolmap

    cam = Camera.pinhole(64, 48, 50, 50, 31.5, 23.5)
    pc = to_pycolmap(cam)
    assert list(pc.params) == [50, 50, 32, 24]
    assert distort_points(cam, np.array([[31.5, 23.5], [10.0, 5.0]])) == pytest.approx(
        np.array([[31.5, 23.5], [10.0, 5.0]])
    )


# --- every model: distort with an independent formula, undistort, find the point -------------

W, H, F = 160, 120, 80.0
CX, CY = 79.5, 59.5  # OpenCV convention


def _fisheye_theta(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.hypot(x, y)
    return r, np.arctan(r)


def _independent_distort(model: str, params: tuple, pts: np.ndarray) -> np.ndarray:
    """OpenCV-convention pixels of pinhole pixels ``pts`` under ``model`` (not via pycolmap)."""
    import cv2

    x, y = (pts[:, 0] - CX) / F, (pts[:, 1] - CY) / F
    if model == "OPENCV":
        obj = np.column_stack([x, y, np.ones_like(x)])
        k = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1]])
        out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), k, np.array(params[4:]))
        return out.reshape(-1, 2)
    if model == "OPENCV_FISHEYE":
        k = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1]])
        out = cv2.fisheye.distortPoints(
            np.column_stack([x, y])[None].astype(np.float64), k, np.array(params[4:])
        )
        return out.reshape(-1, 2)
    r, theta = _fisheye_theta(x, y)
    if model == "RADIAL_FISHEYE":
        k1, k2 = params[3:]
        theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4)
        scale = theta_d / r
    elif model == "SIMPLE_FISHEYE":
        scale = theta / r
    elif model == "FOV":
        omega = params[4]
        scale = np.arctan(2 * r * np.tan(omega / 2)) / (omega * r)
    else:
        raise AssertionError(model)
    return np.column_stack([F * x * scale + CX, F * y * scale + CY])


MODELS = {
    "OPENCV": (F, F, CX, CY, -0.25, 0.06, 0.002, -0.001),
    "OPENCV_FISHEYE": (F, F, CX, CY, 0.05, -0.02, 0.01, -0.002),
    "RADIAL_FISHEYE": (F, CX, CY, 0.04, -0.01),
    "SIMPLE_FISHEYE": (F, CX, CY),
    "FOV": (F, F, CX, CY, 0.9),
}


@pytest.mark.parametrize("model", sorted(MODELS))
def test_undistort_to_pinhole_puts_points_at_their_pinhole_projection(model: str) -> None:
    from pgt_check.io.camera import distort_points, undistort_to_pinhole

    cam = Camera(model, W, H, MODELS[model])
    assert cam.is_distorted
    rng = np.random.default_rng(7)
    pts = np.column_stack([rng.uniform(25, W - 25, 12), rng.uniform(20, H - 20, 12)])
    where = _independent_distort(model, MODELS[model], pts)
    np.testing.assert_allclose(distort_points(cam, pts), where, atol=1e-4)
    # a distorted photo: one Gaussian spot (sigma 1.2 px) at each distorted position
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    image = np.zeros((H, W), np.float64)
    for u, v in where:
        image += np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 1.2**2))
    photo = np.repeat(image[:, :, None], 3, axis=2).astype(np.float32)
    out, pinhole = undistort_to_pinhole(photo, cam)
    assert pinhole == cam.as_pinhole() and out.shape == photo.shape
    for u, v in pts:  # the spot's centroid lands at the pinhole projection
        x0, y0 = round(u), round(v)
        win = out[y0 - 4 : y0 + 5, x0 - 4 : x0 + 5, 0].astype(np.float64)
        wy, wx = np.mgrid[y0 - 4 : y0 + 5, x0 - 4 : x0 + 5]
        centroid = np.array([(win * wx).sum(), (win * wy).sum()]) / win.sum()
        assert np.hypot(*(centroid - (u, v))) < 0.5, (model, (u, v), centroid)


def test_undistort_matches_opencv_and_leaves_pinhole_images_alone() -> None:
    import cv2

    from pgt_check.io.camera import undistort_to_pinhole

    cam = Camera("OPENCV", W, H, MODELS["OPENCV"])
    rng = np.random.default_rng(0)
    photo = cv2.GaussianBlur(rng.random((H, W, 3)).astype(np.float32), (0, 0), 2)
    ours, _ = undistort_to_pinhole(photo, cam)
    ref = cv2.undistort(photo, cam.K, cam.dist_coeffs, None, cam.K)
    assert np.abs(ours - ref)[8:-8, 8:-8].max() < 2e-3
    pin = cam.as_pinhole()
    same, same_cam = undistort_to_pinhole(photo, pin)
    assert same is photo and same_cam is pin
    with pytest.raises(ValueError, match="to match the camera"):
        undistort_to_pinhole(photo[:10], cam)
    with pytest.raises(ValueError, match="no OpenCV distortion"):
        _ = Camera("OPENCV_FISHEYE", W, H, MODELS["OPENCV_FISHEYE"]).dist_coeffs
