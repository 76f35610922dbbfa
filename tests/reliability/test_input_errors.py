"""Class 1: usage, input and setup errors exit 2 with one line naming the file / option, never a
traceback, and before any frame is measured."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest


def _ply(path, vertices, faces=()):
    head = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z"]
    if faces:
        head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    body = [" ".join(str(v) for v in p) for p in vertices]
    body += ["3 " + " ".join(str(i) for i in f) for f in faces]
    path.write_text("\n".join([*head, "end_header", *body]) + "\n")
    return path


def _bad_mesh(kind, tmp_path):
    rng = np.random.default_rng(0)
    if kind == "empty_glb":
        p = tmp_path / "m.glb"
        p.write_bytes(b"")
    elif kind == "random_ply":
        p = tmp_path / "m.ply"
        p.write_bytes(b"ply\nformat binary_little_endian 1.0\n" + rng.bytes(4096))
    elif kind == "garbage_obj":
        p = tmp_path / "m.obj"
        p.write_bytes(rng.bytes(2048))
    elif kind == "no_faces":
        p = _ply(tmp_path / "m.ply", rng.normal(size=(50, 3)).round(3).tolist())
    elif kind == "nan_vertices":
        p = _ply(tmp_path / "m.ply", [[0, 0, 0], [1, 0, 0], ["nan", 1, 0]], [(0, 1, 2)])
    else:
        raise AssertionError(kind)
    return p


@pytest.mark.parametrize("kind", ["empty_glb", "random_ply", "garbage_obj", "no_faces",
                                  "nan_vertices"])
def test_broken_mesh_exits_2(kind, tmp_path, cli, base_args, case):
    mesh = _bad_mesh(kind, tmp_path)
    args = base_args()
    args[args.index("--mesh") + 1] = str(mesh)
    rc, _, err = cli(*args)
    last = err.strip().splitlines()[-1]
    case(f"mesh: {kind}", "2, one line naming the mesh", f"{rc}: {last[:140]}")
    assert rc == 2
    assert last.startswith("pgt-check: error: ") and str(mesh) in last
    assert "Traceback" not in err and err.count("pgt-check: error") == 1
    assert not (tmp_path / "out" / "records.jsonl").exists()  # found before the run


def test_out_is_a_file_exits_2(tmp_path, cli, base_args, case):
    f = tmp_path / "taken"
    f.write_text("x")
    rc, _, err = cli(*base_args(out=f))
    case("--out is an existing file", "2, names --out", f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and "--out" in err and "Traceback" not in err


def test_out_under_proc_exits_2(cli, base_args, case):
    from pathlib import Path

    rc, _, err = cli(*base_args(out=Path("/proc/pgt-check-out")))
    case("--out under /proc", "2, names --out", f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and "--out" in err and "Traceback" not in err


def test_config_file_json_list_exits_2(tmp_path, cli, base_args, case):
    cfg = tmp_path / "c.json"
    cfg.write_text("[1, 2]")
    rc, _, err = cli(*base_args("--config", str(cfg)))
    case("config file is a JSON list", "2, names the file", f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and str(cfg) in err and "table" in err and "Traceback" not in err


def test_unknown_matcher_exits_2(cli, base_args, case):
    rc, _, err = cli(*base_args("--matcher", "foo"))
    case("--matcher foo", "2, usage", f"{rc}: {err.strip().splitlines()[-1][:120]}")
    assert rc == 2 and "--matcher" in err and "Traceback" not in err


def test_loftr_without_weights_is_setup_error(cli, base_args, case):
    pytest.importorskip("kornia")
    rc, _, err = cli(*base_args("--matcher", "loftr"))
    case("--matcher loftr without weights", "2, setup error before the run",
         f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and "loftr" in err.lower() and "Traceback" not in err


def test_mariner_missing_weights_is_setup_error(tmp_path, cli, base_args, case):
    rc, _, err = cli(*base_args("--enhance-method", "mariner", "--weights",
                                str(tmp_path / "missing.pt")))
    case("--enhance-method mariner --weights missing.pt", "2, setup error (not per frame)",
         f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and "Traceback" not in err
    assert "missing.pt" in err or "pip install" in err  # weights named, or the extra is absent
    assert not (tmp_path / "out" / "records.jsonl").exists()


def test_report_on_corrupt_outputs(tmp_path, cli, base_args, case):
    out = tmp_path / "out"
    rc, _, _ = cli(*base_args())
    assert rc == 0
    (out / "summary.json").write_text("{not json")
    rc, _, err = cli("report", str(out))
    case("report: corrupt summary.json", "rebuilt, exit = gate (0)", f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 0 and "Traceback" not in err
    assert json.loads((out / "summary.json").read_text())["gate"]["passed"]
    (out / "run.json").write_bytes(struct.pack("<4d", 1, 2, 3, 4))
    rc, _, err = cli("report", str(out))
    case("report: corrupt run.json", "2, names the file", f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and "run.json" in err and "Traceback" not in err
