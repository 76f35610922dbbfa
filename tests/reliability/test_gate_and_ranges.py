"""Classes 2 and 4: the gate fails closed (nothing or too little verified, internal errors), and
every numeric option is range-checked in one place (CLI and config files alike)."""

from __future__ import annotations

import json
import shutil

import pytest

from pgt_check.config import RunConfig
from pgt_check.errors import ConfigError
from pgt_check.verdict.run_stats import gate


@pytest.mark.parametrize(
    "option,value",
    [
        ("--max-fail-fraction", "nan"),
        ("--max-fail-fraction", "-0.1"),
        ("--threshold-px", "nan"),
        ("--threshold-px", "inf"),
        ("--threshold-px", "-3"),
        ("--min-coverage", "nan"),
        ("--max-unverifiable-fraction", "1.5"),
        ("--limit", "-22"),
        ("--limit", "0"),
        ("--max-keypoints", "0"),
        ("--resize-max", "-5"),
        ("--max-image-pixels", "0"),
        ("--max-internal-errors", "-1"),
    ],
)
def test_out_of_range_option_exits_2(option, value, cli, base_args, tmp_path, case):
    args = base_args()
    if option == "--limit":
        args = args[: args.index("--limit")] + args[args.index("--limit") + 2:]
    rc, _, err = cli(*args, option, value)
    last = err.strip().splitlines()[-1]
    case(f"{option} {value}", "2, names the option", f"{rc}: {last[:140]}")
    assert rc == 2 and option in last and "Traceback" not in err
    assert not (tmp_path / "out").exists()  # refused before anything is written


def test_config_file_gets_the_same_checks(tmp_path, cli, base_args, case):
    cfg = tmp_path / "c.json"
    cfg.write_text('{"gate": {"max_fail_fraction": NaN}}')  # Python's json reads NaN
    rc, _, err = cli(*base_args("--config", str(cfg)))
    case("config file: max_fail_fraction NaN", "2, names the key",
         f"{rc}: {err.strip().splitlines()[-1][:140]}")
    assert rc == 2 and "max_fail_fraction" in err
    with pytest.raises(ConfigError, match="threshold_px"):
        RunConfig.from_dict({"verdict": {"threshold_px": -1.0}})


def test_resize_max_zero_means_original_size():
    assert RunConfig.from_dict({"match": {"resize_max": 0}}).match.resize_max is None
    from pgt_check.commands.check import build_parser, load_config

    args = build_parser().parse_args(["t.txt", "--mesh", "m.ply", "--resize-max", "0"])
    assert load_config(args).match.resize_max is None


def test_all_images_missing_fails_the_gate(scene, cli, base_args, case):
    shutil.rmtree(scene / "images")
    rc, out, _ = cli(*base_args())
    case("all images missing", "1, no frame verified", f"{rc}: {out.splitlines()[1][:140]}")
    assert rc == 1 and "no frame was verified" in out


def test_camera_far_larger_than_photos_is_size_mismatch(scene, cli, base_args, tmp_path, case):
    sensors = scene / "sensors.txt"
    head, row = sensors.read_text().splitlines()
    parts = [p.strip() for p in row.split(",")]
    parts[4:] = [str(float(x) * 10000) for x in parts[4:]]
    parts[4], parts[5] = str(int(float(parts[4]))), str(int(float(parts[5])))
    sensors.write_text(head + "\n" + ", ".join(parts) + "\n")
    rc, out, _ = cli(*base_args())
    reasons = json.loads((tmp_path / "out" / "summary.json").read_text())["statistics"][
        "unverifiable_reasons"]
    case("camera 10,000x larger than its photos", "1, image_size_mismatch",
         f"{rc}: {reasons}")
    assert rc == 1 and reasons == {"image_size_mismatch": 2}


def test_gate_function_fails_closed():
    from pgt_check.config import GateConfig

    cfg = GateConfig()
    assert cfg.max_unverifiable_fraction < 1.0  # a default limit exists
    assert not gate({"PASS": 0, "FAIL": 0, "UNVERIFIABLE": 5}, GateConfig(
        max_unverifiable_fraction=1.0))[0]  # nothing verified: fails whatever the limit
    assert gate({"PASS": 9, "UNVERIFIABLE": 1}, cfg, {"low_coverage": 1})[0]
    ok, why = gate({"PASS": 9, "UNVERIFIABLE": 1}, cfg, {"internal_error": 1})
    assert not ok and "internal" in why
    assert gate({"PASS": 9, "UNVERIFIABLE": 1}, GateConfig(max_internal_errors=1),
                {"worker_crashed": 1})[0]
    assert not gate({"PASS": 4, "UNVERIFIABLE": 6}, cfg)[0]  # > default 0.5
