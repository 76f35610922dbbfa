"""Second audit (#25), property-based: every reader and the config / trusted-summary loaders,
fed random mutations of a valid file, either load it or raise ``InputError`` (never another
exception: no IndexError, ZeroDivisionError, RecursionError, UnicodeError, TypeError ...)."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pgt_check.errors import InputError

#: tokens a careless or hostile file holds where numbers, names or brackets belong
_TOKENS = [b"0", b"-0", b"nan", b"inf", b"-1", b"1e400", b"99999999999999999999999", b"", b" ",
           b",", b"\x00", b"\xff\xfe", b"\xef\xbb\xbf", b"\n", b"#", b"[", b"{", b"]", b"}",
           b'"', b"null", b"true", b"[[[[[[[[", b"0.0", b"1", b"2", b"PINHOLE", b"cam0",
           b"a.png", b"\xe9", b"=1+1", b"7"]

_SETTINGS = settings(max_examples=40, deadline=None, derandomize=True,
                     suppress_health_check=[HealthCheck.function_scoped_fixture,
                                            HealthCheck.too_slow])


@st.composite
def mutations(draw) -> list[tuple[str, int, bytes]]:
    """A few edits: (kind, relative position in 0..999, bytes)."""
    edit = st.tuples(st.sampled_from(["replace", "insert", "delete", "truncate", "token"]),
                     st.integers(0, 999),
                     st.one_of(st.sampled_from(_TOKENS), st.binary(max_size=6)))
    return draw(st.lists(edit, min_size=1, max_size=4))


def _mutate(data: bytes, edits: list[tuple[str, int, bytes]]) -> bytes:
    for kind, rel, payload in edits:
        pos = rel * len(data) // 1000
        if kind == "replace":
            data = data[:pos] + payload + data[pos + max(1, len(payload)):]
        elif kind == "insert":
            data = data[:pos] + payload + data[pos:]
        elif kind == "delete":
            data = data[:pos] + data[pos + 1 + rel % 7:]
        elif kind == "truncate":
            data = data[:pos]
        else:  # replace the token (run of non-separator bytes) at pos
            seps = b" ,\n\t:[]{}\""
            start = pos
            while start > 0 and data[start - 1] not in seps:
                start -= 1
            end = pos
            while end < len(data) and data[end] not in seps:
                end += 1
            data = data[:start] + payload + data[end:]
    return data


def _fails_closed(load: Callable[[], object]) -> None:
    try:
        load()
    except InputError:
        pass


def _png(path: Path, w: int = 32, h: int = 24) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.zeros((h, w, 3), np.uint8)).save(path)


_CAMERA = "PINHOLE,32,24,30,30,16,12"


def _seed_files(fmt: str, root: Path) -> tuple[Path, Callable[[], object]]:
    """A valid input of ``fmt`` under ``root`` (the file to mutate, the loader)."""
    from pgt_check.io import read_trajectory

    images = root / "images"
    for i in range(3):
        _png(images / f"{i}.png")
    if fmt == "lamar":
        (root / "sensors.txt").write_text(
            "# sensor_id, name, sensor_type, [sensor_params]+\n"
            "cam0, c, camera, PINHOLE, 32, 24, 30, 30, 16, 12\n")
        (root / "images.txt").write_text("".join(f"{i}, cam0, images/{i}.png\n" for i in range(3)))
        target = root / "trajectories.txt"
        target.write_text("".join(f"{i}, cam0, 1, 0, 0, 0, {i}, 0, 0\n" for i in range(3)))
        return target, lambda: read_trajectory(target, "lamar")
    if fmt == "lamar_sensors":
        target, _ = _seed_files("lamar", root)
        return root / "sensors.txt", lambda: read_trajectory(target, "lamar")
    if fmt == "tum":
        target = root / "tum.txt"
        target.write_text("".join(f"{i} {i} 0 0 0 0 0 1\n" for i in range(3)))
        return target, lambda: read_trajectory(target, "tum", images=images, camera=_CAMERA)
    if fmt == "tum_list":
        target = root / "rgb.txt"
        target.write_text("".join(f"{i} images/{i}.png\n" for i in range(3)))
        traj = root / "tum.txt"
        traj.write_text("".join(f"{i} {i} 0 0 0 0 0 1\n" for i in range(3)))
        return target, lambda: read_trajectory(traj, "tum", images=target, camera=_CAMERA)
    if fmt == "pgt":
        target = images / "poses.txt"
        target.write_text("".join(f"{i}.png 1 0 0 0 {i} 0 0 30\n" for i in range(3)))
        return target, lambda: read_trajectory(target, "pgt")
    if fmt == "hloc":
        target = root / "results.txt"
        target.write_text("".join(f"{i}.png 1 0 0 0 {i} 0 0\n" for i in range(3)))
        return target, lambda: read_trajectory(target, "hloc", images=images, camera=_CAMERA)
    if fmt in ("colmap_cameras", "colmap_images"):
        model = root / "sparse"
        model.mkdir()
        (model / "cameras.txt").write_text("1 PINHOLE 32 24 30 30 16 12\n")
        (model / "images.txt").write_text(
            "".join(f"{i + 1} 1 0 0 0 {i} 0 0 1 {i}.png\n\n" for i in range(3)))
        (model / "points3D.txt").write_text("")
        target = model / ("cameras.txt" if fmt == "colmap_cameras" else "images.txt")
        return target, lambda: read_trajectory(model, "colmap", images=images)
    if fmt == "nerfstudio":
        target = images / "transforms.json"
        frames = [{"file_path": f"{i}.png", "transform_matrix": np.eye(4).tolist()}
                  for i in range(3)]
        target.write_text(json.dumps({"camera_angle_x": 0.9, "w": 32, "h": 24, "k1": 0.0,
                                      "frames": frames}))
        return target, lambda: read_trajectory(target)
    if fmt == "dataparser":
        target, load = _seed_files("nerfstudio", root)
        dp = root / "dataparser_transforms.json"
        dp.write_text(json.dumps({"transform": np.eye(4)[:3].tolist(), "scale": 0.5}))
        return dp, lambda: read_trajectory(target, "nerfstudio", dataparser_transforms=dp)
    raise AssertionError(fmt)


@pytest.mark.parametrize("fmt", ["lamar", "lamar_sensors", "tum", "tum_list", "pgt", "hloc",
                                 "colmap_cameras", "colmap_images", "nerfstudio", "dataparser"])
@_SETTINGS
@given(edits=mutations())
def test_readers_load_or_raise_input_error(fmt, edits, tmp_path_factory):
    root = tmp_path_factory.mktemp(fmt)
    target, load = _seed_files(fmt, root)
    load()  # the seed itself is valid
    target.write_bytes(_mutate(target.read_bytes(), edits))
    try:
        _fails_closed(load)
    finally:
        shutil.rmtree(root, ignore_errors=True)


_CONFIG = {"limit": 3, "match": {"method": "orb", "max_keypoints": 500},
           "verdict": {"threshold_px": 4.0}, "gate": {"max_fail_fraction": 0.1},
           "edges": {"tile_grid": 3}, "workers": 2, "executor": "serial"}


@pytest.mark.parametrize("suffix", [".json", ".toml"])
@_SETTINGS
@given(edits=mutations())
def test_config_loader_loads_or_raises_input_error(suffix, edits, tmp_path_factory):
    from pgt_check.config import RunConfig, load_config_file

    root = tmp_path_factory.mktemp("config")
    path = root / f"c{suffix}"
    if suffix == ".json":
        path.write_text(json.dumps(_CONFIG))
    else:
        path.write_text('limit = 3\nworkers = 2\nexecutor = "serial"\n[match]\nmethod = "orb"\n'
                        'max_keypoints = 500\n[verdict]\nthreshold_px = 4.0\n[edges]\n'
                        'tile_grid = 3\n')
    RunConfig.from_dict(load_config_file(path))
    path.write_bytes(_mutate(path.read_bytes(), edits))
    _fails_closed(lambda: RunConfig.from_dict(load_config_file(path)))


@_SETTINGS
@given(edits=mutations())
def test_trusted_summary_loader_loads_or_raises_input_error(edits, tmp_path_factory):
    from pgt_check.verdict.calibration import load_trusted_calibrations, trusted_calibration

    root = tmp_path_factory.mktemp("summary")
    path = root / "summary.json"
    entry = {"status": "passed", "rotation": np.eye(3).tolist(), "focal_scale": 1.001,
             "translation": [0.0, 0.0, 0.01]}
    path.write_text(json.dumps({"shared_errors": {"calibration": {"cam": entry,
                                                                  "other": {"status": "x"}}}}))
    load_trusted_calibrations(str(path))
    path.write_bytes(_mutate(path.read_bytes(), edits))
    _fails_closed(lambda: trusted_calibration(str(path), ["cam"]))


@st.composite
def json_values(draw, depth: int = 0):
    leaves = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=5))
    if depth > 3:
        return draw(leaves)
    return draw(st.one_of(
        leaves,
        st.lists(st.deferred(lambda: json_values(depth + 1)), max_size=4),
        st.dictionaries(st.sampled_from(["rotation", "focal_scale", "translation", "calibration",
                                         "shared_errors", "cam", "frames", "limit", "verdict"]),
                        st.deferred(lambda: json_values(depth + 1)), max_size=4),
    ))


@_SETTINGS
@given(value=json_values())
def test_structured_json_fails_closed(value, tmp_path_factory):
    """Random JSON structures (a string where a table belongs, a 2x2 rotation, NaN ...) in a
    trusted summary, a config and a transforms.json."""
    from pgt_check.config import RunConfig, load_config_file
    from pgt_check.io import read_trajectory
    from pgt_check.verdict.calibration import trusted_calibration

    root = tmp_path_factory.mktemp("structured")
    for doc in (value, {"shared_errors": {"calibration": value}},
                {"shared_errors": {"calibration": {"cam": value}}}):
        p = root / "summary.json"
        p.write_text(json.dumps(doc))
        _fails_closed(lambda p=p: trusted_calibration(str(p), ["cam"]))
    cfg = root / "c.json"
    cfg.write_text(json.dumps(value if isinstance(value, dict) else {"verdict": value}))
    _fails_closed(lambda: RunConfig.from_dict(load_config_file(cfg)))
    tr = root / "transforms.json"
    tr.write_text(json.dumps({"w": 32, "h": 24, "fl_x": 30, "frames": [
        value, {"file_path": "a.png", "transform_matrix": value}]}))
    _fails_closed(lambda: read_trajectory(tr, "nerfstudio"))
