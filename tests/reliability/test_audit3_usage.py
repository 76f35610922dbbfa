"""Third audit (#39), usage and input errors: an empty ``--out``, a JSON config that names a
key twice and a COLMAP camera of no size are input errors (exit 2, one line naming the
option, key or file and line), never a run that exits 0."""

from __future__ import annotations

import json

import pytest


def _error_line(err: str) -> str:
    assert "Traceback" not in err
    return err.strip().splitlines()[-1] if err.strip() else ""


@pytest.mark.parametrize("out", ["", "   "])
def test_empty_out_is_a_usage_error(out, scene, tmp_path, cli, base_args, case, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an empty path would have meant the current directory
    args = base_args()
    args[args.index("--out") + 1] = out
    rc, _, err = cli(*args)
    line = _error_line(err)
    case(f"--out {out!r}", "2, names out", f"{rc}: {line[:120]}")
    assert rc == 2 and "out" in line
    assert list(tmp_path.iterdir()) == [scene]  # nothing written


@pytest.mark.parametrize("command", ["report", "compare", "enhance"])
def test_subcommand_empty_out_is_a_usage_error(command, scene, tmp_path, cli, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = {"report": ["report", " "],
            "compare": ["compare", scene / "trajectories.txt", scene / "trajectories.txt",
                        "--out", ""],
            "enhance": ["enhance", scene / "images", "reproject", "--out", ""]}[command]
    rc, _, err = cli(*argv)
    assert rc == 2 and "expected a path" in _error_line(err)
    assert list(tmp_path.iterdir()) == [scene]


def test_api_empty_out_is_an_input_error(scene):
    from pgt_check.api import check
    from pgt_check.errors import InputError

    with pytest.raises(InputError, match="out"):
        check(scene / "trajectories.txt", scene / "mesh.glb", out=" ", limit=1)


def test_json_config_duplicate_key_exits_2(tmp_path, cli, base_args, case):
    """The last of two keys used to win silently: a FAIL frame passed the gate of
    max_fail_fraction 1.0 although the file also said 0.0."""
    cfg = tmp_path / "c.json"
    cfg.write_text('{"gate": {"max_fail_fraction": 0.0, "max_fail_fraction": 1.0}}')
    rc, _, err = cli(*base_args("--config", cfg))
    line = _error_line(err)
    case("JSON config with a key twice", "2, names the key", f"{rc}: {line[:140]}")
    assert rc == 2 and "duplicate key 'max_fail_fraction'" in line and "c.json" in line
    assert not (tmp_path / "out" / "records.jsonl").exists()


def test_json_config_duplicate_top_level_key(tmp_path):
    from pgt_check.config import load_config_file
    from pgt_check.errors import ConfigError

    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"limit": 1})[:-1] + ', "limit": 2}')
    with pytest.raises(ConfigError, match="duplicate key 'limit'"):
        load_config_file(cfg)
    from pgt_check.config.load import load_config_file as load_plain

    cfg.write_text('{"a": {"k": 0.5}, "b": {"k": 1}}')  # one name in two tables is fine
    assert load_plain(cfg) == {"a": {"k": 0.5}, "b": {"k": 1}}


@pytest.mark.parametrize("size", ["-640 480", "640 0"])
def test_colmap_camera_without_size_exits_2(size, scene, tmp_path, cli, case):
    model = tmp_path / "colmap"
    model.mkdir()
    (model / "cameras.txt").write_text(f"# cameras\n1 PINHOLE {size} 500 500 320 240\n")
    (model / "images.txt").write_text("1 1 0 0 0 0 0 0 1 frame-000000.jpg\n\n")
    (model / "points3D.txt").write_text("")
    rc, _, err = cli(model, "--mesh", scene / "mesh.glb", "--images", scene / "images",
                     "--out", tmp_path / "out", "-q")
    line = _error_line(err)
    case(f"COLMAP camera of size {size}", "2, names cameras.txt and the line",
         f"{rc}: {line[:140]}")
    assert rc == 2 and "cameras.txt:2" in line and "positive image size" in line
