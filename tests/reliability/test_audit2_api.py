"""Second hostile-input audit (issue #25): the Python API fails closed like the CLI.

``pgt_check.api.check``, ``frames_dataframe`` and ``compare.compare_trajectories`` raise the
documented ``InputError`` (one line, naming the argument) for an argument of the wrong type, a
bad setting and a checker that cannot be built (``CheckerSetupError``), never a raw
``TypeError`` / ``AttributeError`` / ``RuntimeError``."""

from __future__ import annotations

from pathlib import Path

import pytest

from pgt_check.errors import InputError, SetupError

FAST = {"report_details": 0, "enhance": {"mode": "never"}, "correct": {"frames": "none"}}


def _one_line(err: BaseException) -> str:
    text = str(err)
    assert "\n" not in text and text
    return text


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"config": 5}, r"config must be a RunConfig, a dict .* got int"),
        ({"config": [1]}, r"config must be a RunConfig, a dict .* got list"),
        ({"config": b"cfg.json"}, r"config must be .* got bytes"),
        ({"config": {1: 2}}, r"setting names must be strings"),
        ({"config": {"verdict": {1: 2, "x": 3}}}, r"VerdictConfig: unknown key"),
        ({"limit": "3"}, r"RunConfig.limit"),
        ({"limit": True}, r"RunConfig.limit"),
        ({"verdict": "strict"}, r"RunConfig.verdict: expected a table"),
        ({"verdict": {"threshold_px": "a"}}, r"VerdictConfig.threshold_px"),
        ({"out": 5}, r"RunConfig.out: expected a string"),
        ({"no_such_setting": 1}, r"unknown key 'no_such_setting'"),
    ],
)
def test_check_bad_config_and_settings(kwargs, match, scene, tmp_path, case):
    from pgt_check.api import check

    with pytest.raises(InputError, match=match) as info:
        check(scene / "trajectories.txt", scene / "mesh.glb", **{"out": str(tmp_path / "o"),
                                                                  **FAST, **kwargs})
    shown = ", ".join(f"{k}={v!r}" for k, v in kwargs.items())
    case(f"API check({shown})", "InputError, one line",
         f"{type(info.value).__name__}: {_one_line(info.value)[:110]}")
    assert not (tmp_path / "o" / "records.jsonl").exists()  # refused before any frame


@pytest.mark.parametrize(
    ("trajectory", "mesh", "match"),
    [
        (5, "MESH", r"trajectory must be a pose file path .* or a pgt_check.types.Trajectory; "
                    r"got int"),
        (None, "MESH", r"trajectory must be .* got NoneType"),
        (["a.txt"], "MESH", r"trajectory must be .* got list"),
        ("TRAJ", None, r"mesh must be a file path .* got NoneType"),
        ("TRAJ", 5, r"mesh must be a file path .* got int"),
        ("TRAJ", "", r"mesh must be a file path"),
    ],
)
def test_check_wrong_argument_types(trajectory, mesh, match, scene, tmp_path):
    from pgt_check.api import check

    trajectory = scene / "trajectories.txt" if trajectory == "TRAJ" else trajectory
    mesh = scene / "mesh.glb" if mesh == "MESH" else mesh
    with pytest.raises(InputError, match=match) as info:
        check(trajectory, mesh, out=str(tmp_path / "o"), **FAST)
    _one_line(info.value)


def test_check_accepts_path_objects_in_settings(scene, tmp_path):
    """``out=Path(...)`` (and paths inside sections) are paths like strings, not type errors."""
    from pgt_check.api import check

    out = tmp_path / "o"
    df = check(scene / "trajectories.txt", scene / "mesh.glb", out=out, limit=1,
               input={"images": scene / "images.txt"}, **FAST)
    assert df.attrs["out"] == str(out) and (out / "frames.csv").is_file()
    assert list(df["verdict"]) == ["PASS"]


def test_check_config_file_errors_are_input_errors(scene, tmp_path):
    from pgt_check.api import check

    bad = tmp_path / "c.json"
    bad.write_text("[1, 2]")
    for config in (bad, str(tmp_path / "missing.json")):
        with pytest.raises(InputError):
            check(scene / "trajectories.txt", scene / "mesh.glb", config=config, **FAST)


def test_checker_setup_error_is_an_input_error():
    """A checker that cannot be built in a worker ends the run as a SetupError (InputError)."""
    from pgt_check.config import RunConfig
    from pgt_check.executor import CheckerSetupError, iter_results

    def no_gl() -> None:
        raise RuntimeError("no GL context available (test)")

    with pytest.raises(InputError, match="building the checker failed.*no GL context") as info:
        list(iter_results([], no_gl, RunConfig()))
    assert isinstance(info.value, CheckerSetupError) and isinstance(info.value, SetupError)
    assert isinstance(info.value, RuntimeError)  # callers that caught it as one still do


def _setup_fails(*args, **kwargs):
    from pgt_check.executor import CheckerSetupError

    raise CheckerSetupError("building the checker failed: RuntimeError: no GL context (test)")


def test_api_setup_failure_raises_input_error(scene, tmp_path, monkeypatch, case):
    from pgt_check import runner
    from pgt_check.api import check

    monkeypatch.setattr(runner, "check_frames", _setup_fails)
    with pytest.raises(InputError, match="no GL context") as info:
        check(scene / "trajectories.txt", scene / "mesh.glb", out=str(tmp_path / "o"), limit=1,
              **FAST)
    case("API: the checker cannot be built in a worker (CheckerSetupError)", "InputError",
         f"{type(info.value).__name__}: {_one_line(info.value)[:110]}")


def test_cli_setup_failure_exits_2_one_line(monkeypatch, cli, base_args, case):
    from pgt_check import runner

    monkeypatch.setattr(runner, "check_frames", _setup_fails)
    rc, _, err = cli(*base_args())
    case("CLI: the checker cannot be built in a worker", "2, one line",
         f"{rc}: {err.strip()[:120]}")
    assert rc == 2 and "Traceback" not in err
    assert err.strip().splitlines() == [err.strip()] and "no GL context" in err


@pytest.mark.parametrize("rows", [5, None, "PASS", [1], [{"frame_id": "a"}, "b"]])
def test_frames_dataframe_wrong_rows(rows):
    from pgt_check.api import frames_dataframe

    with pytest.raises(InputError, match=r"rows(\[\d+\])? must be"):
        frames_dataframe(rows)


def test_frames_dataframe_orders_columns():
    from pgt_check.api import frames_dataframe

    df = frames_dataframe([{"extra": 1, "verdict": "PASS", "frame_id": "a"}])
    assert list(df.columns)[:2] == ["frame_id", "verdict"] and df.loc[0, "extra"] == 1


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((5, "T"), {}, r"a must be a pgt_check.types.Trajectory"),
        (("T", None), {}, r"b must be a pgt_check.types.Trajectory"),
        (("T", "T", 5), {}, r"mesh must be a file path or None"),
        (("T", "T"), {"settings": [1]}, r"settings must be a dict"),
        (("T", "T", "MESH"), {"settings": {"x": 1}}, r"unknown key 'x'"),
        (("T", "T"), {"limit": "2"}, r"--limit: expected an integer"),
    ],
)
def test_compare_api_wrong_types(args, kwargs, match, sample_scene):
    from pgt_check.io import read_trajectory
    from pgt_check.stages.compare import compare_trajectories

    traj = read_trajectory(sample_scene / "trajectories.txt")
    mesh = Path(sample_scene / "mesh.glb")
    args = tuple(traj if a == "T" else mesh if a == "MESH" else a for a in args)
    with pytest.raises(InputError, match=match):
        compare_trajectories(*args, **kwargs)
