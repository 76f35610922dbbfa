"""The memory pre-check: counts from file headers, the estimate, available memory, refusal."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from pgt_check.errors import SetupError
from pgt_check.render import memory
from pgt_check.render.memory import (
    MeshCounts,
    available_memory,
    check_memory_fits,
    estimate_run_memory,
    obj_counts,
    parse_cgroup_room,
    parse_meminfo,
    read_mesh_counts,
)


def _grid(n: int) -> trimesh.Trimesh:
    """A coloured n x n vertex grid: 2 (n - 1)^2 faces."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n], 1), np.stack([i + 1, i + n + 1, i + n], 1)])
    return trimesh.Trimesh(v, f, vertex_colors=np.full((n * n, 4), 200, np.uint8),
                           process=False)


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_ply_counts_come_from_the_header(tmp_path, encoding):
    path = tmp_path / "grid.ply"
    path.write_bytes(trimesh.exchange.ply.export_ply(_grid(12), encoding=encoding))
    assert read_mesh_counts(path) == MeshCounts(144, 2 * 11 * 11, exact=True)


def test_obj_counts_are_exact_across_chunk_boundaries(tmp_path):
    path = tmp_path / "grid.obj"
    _grid(9).export(path)
    expected = MeshCounts(81, 2 * 8 * 8)
    assert read_mesh_counts(path) == expected
    for chunk in (3, 7, 64, 1000):  # line starts split between reads are counted once
        assert obj_counts(path, chunk=chunk) == expected


def test_glb_counts_match_the_loaded_mesh(sample_scene):
    path = sample_scene / "mesh.glb"
    loaded = trimesh.load(path, force="mesh", process=False)
    counts = read_mesh_counts(path)
    assert counts.exact and counts.n_faces == len(loaded.faces)


def test_unknown_format_is_a_low_guess_from_the_file_size(tmp_path):
    path = tmp_path / "scan.off"
    path.write_bytes(b"x" * 40_000)
    counts = read_mesh_counts(path)
    assert not counts.exact and counts.n_faces == 40_000 // memory.GUESS_FILE_BYTES_PER_FACE


def test_estimate_grows_with_faces_and_workers():
    sizes = [estimate_run_memory(MeshCounts(f // 2, f), 640, 480) for f in (150_000, 1_500_000,
                                                                           15_000_000)]
    assert sizes[0] < sizes[1] < sizes[2]
    # about linear in the faces once the fixed renderer cost is small beside the mesh
    assert 8 < (sizes[2] - sizes[0]) / (sizes[1] - sizes[0]) < 12
    one = estimate_run_memory(MeshCounts(1_000_000, 2_000_000), 640, 480)
    assert estimate_run_memory(MeshCounts(1_000_000, 2_000_000), 1280, 960) > one
    two = estimate_run_memory(MeshCounts(1_000_000, 2_000_000), 640, 480, workers=2)
    four = estimate_run_memory(MeshCounts(1_000_000, 2_000_000), 640, 480, workers=4)
    assert one < two < four
    # every process also keeps its latest renders (render.cache): counted per worker
    from pgt_check.render.cache import DEFAULT_MAX_BYTES

    tiny = MeshCounts(4, 2)
    assert estimate_run_memory(tiny, 64, 48) > DEFAULT_MAX_BYTES
    assert (estimate_run_memory(tiny, 64, 48, workers=2)
            - estimate_run_memory(tiny, 64, 48, workers=1)) > DEFAULT_MAX_BYTES
    with pytest.raises(ValueError):
        estimate_run_memory(MeshCounts(3, 1), 0, 480)


def test_the_estimate_covers_the_measured_peak():
    """reports/scaling.md: 15 M faces / 7.6 M vertices peaked 2.08 GiB above the process base."""
    need = estimate_run_memory(MeshCounts(7_608_154, 15_000_000), 640, 480)
    assert 2.08 * 2**30 < need < 1.25 * 2.08 * 2**30


def test_meminfo_and_cgroup_parsing(tmp_path):
    text = "MemTotal:       24684084 kB\nMemFree:  100 kB\nMemAvailable:   2048 kB\n"
    assert parse_meminfo(text) == 2048 * 1024
    assert parse_meminfo("MemTotal: 5 kB\n") is None
    assert parse_cgroup_room("max\n", "123\n") is None
    assert parse_cgroup_room("1000\n", "400\n") == 600
    proc, cg = tmp_path / "proc", tmp_path / "cg"
    proc.mkdir()
    cg.mkdir()
    (proc / "meminfo").write_text(text)
    assert available_memory(proc, cg) == 2048 * 1024  # no cgroup files: MemAvailable alone
    (cg / "memory.max").write_text("1048576\n")
    (cg / "memory.current").write_text("524288\n")
    assert available_memory(proc, cg) == 524288  # the lower of the two
    assert available_memory(tmp_path / "none", tmp_path / "none") is None


def test_refuses_a_mesh_that_does_not_fit(tmp_path):
    path = tmp_path / "grid.ply"
    _grid(30).export(path)
    need = estimate_run_memory(read_mesh_counts(path), 640, 480)
    counts, est, avail = check_memory_fits(path, 640, 480, available=need)  # just fits
    assert (counts.n_faces, est, avail) == (2 * 29 * 29, need, need)
    with pytest.raises(SetupError) as err:
        check_memory_fits(path, 640, 480, workers=2, available=need)
    msg = str(err.value)
    assert "\n" not in msg and "not enough memory" in msg and "1,682 faces" in msg
    assert "2 worker processes" in msg and "fewer --workers" in msg


def test_unknown_available_memory_never_refuses(tmp_path, monkeypatch):
    path = tmp_path / "grid.ply"
    _grid(5).export(path)
    monkeypatch.setattr(memory, "available_memory", lambda: None)
    assert check_memory_fits(path, 640, 480)[2] is None
