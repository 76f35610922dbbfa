"""The run's input checks (``pgt_check.stages.inputs``): the memory pre-check before anything loads."""

from __future__ import annotations

import pytest

import pgt_check.render
from pgt_check.cli import main
from pgt_check.config import RunConfig
from pgt_check.errors import SetupError
from pgt_check.render import memory
from pgt_check.stages.inputs import check_mesh_memory, load_trajectory


def _no_mesh_load(*args, **kwargs):
    raise AssertionError("the mesh was loaded although the run does not fit in memory")


def test_cli_refuses_a_run_that_does_not_fit_before_loading(tmp_path, capsys, monkeypatch,
                                                              sample_scene):
    monkeypatch.setattr(memory, "available_memory", lambda: 1024 * 1024)  # 1 MiB free
    monkeypatch.setattr(pgt_check.render, "load_mesh", _no_mesh_load)
    out = tmp_path / "o"
    rc = main([str(sample_scene / "trajectories.txt"), "--mesh", str(sample_scene / "mesh.glb"),
               "--out", str(out)])
    assert rc == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if "error" in ln.lower()]
    assert len(err) == 1 and err[0].startswith("pgt-check: error: ")
    assert "not enough memory for this mesh" in err[0] and "but 1 MiB available" in err[0]
    assert "mesh.glb" in err[0] and "42 faces" in err[0]
    assert not (out / "records.jsonl").exists()  # nothing was measured


def test_worker_processes_count_in_the_estimate(sample_scene, monkeypatch):
    cfg = {"input": {"trajectory": str(sample_scene / "trajectories.txt"),
                     "mesh": str(sample_scene / "mesh.glb")}}
    frames = load_trajectory(RunConfig.from_dict(cfg)).frames
    cam = frames[0].camera
    counts = memory.read_mesh_counts(sample_scene / "mesh.glb")
    serial = memory.estimate_run_memory(counts, cam.width, cam.height)
    # room for one process but not for three workers: only the process pool is refused
    monkeypatch.setattr(memory, "available_memory", lambda: serial)
    check_mesh_memory(RunConfig.from_dict(cfg), frames)
    with pytest.raises(SetupError, match="3 worker processes"):
        check_mesh_memory(RunConfig.from_dict({**cfg, "executor": "process", "workers": 3}),
                          frames)
    # a remote Dask cluster's workers are on other machines: this process alone counts
    check_mesh_memory(RunConfig.from_dict({**cfg, "executor": "dask",
                                           "scheduler": "tcp://head:8786"}), frames)


def test_memory_estimate_uses_the_working_size_not_the_camera_size():
    """A camera 10,000x larger than its photos is rendered at the working size (its frames are
    UNVERIFIABLE image_size_mismatch, not a refused run); without a working size, the pixel
    cap bounds it."""
    from types import SimpleNamespace

    from pgt_check.config import RunConfig
    from pgt_check.stages.inputs import _largest_render

    def frame(w, h):
        return SimpleNamespace(camera=SimpleNamespace(width=w, height=h))

    cfg = RunConfig()
    huge = [frame(6_400_000, 4_800_000), frame(640, 480)]
    w, h = _largest_render(cfg, huge)
    longest = max(cfg.match.resize_max, cfg.edges.resize_max)
    assert max(w, h) == longest and abs(w / h - 4 / 3) < 0.01
    assert _largest_render(cfg, [frame(320, 240)]) == (320, 240)
    free = RunConfig.from_dict({"match": {"resize_max": 0}, "edges": {"resize_max": 0},
                                "input": {"max_image_pixels": 1_000_000}})
    w, h = _largest_render(free, huge)
    assert w * h <= 1_000_000 and w * h > 0.9e6
