import json

import pytest

from pgt_check.config import RunConfig, load_config_file
from pgt_check.errors import ConfigError


def test_defaults_round_trip():
    c = RunConfig()
    assert RunConfig.from_dict(c.to_dict()) == c


@pytest.mark.parametrize(
    "data,msg",
    [
        ({"match": {"max_kpts": 5}}, "unknown key 'max_kpts'"),
        ({"nope": 1}, "unknown key 'nope'"),
        ({"match": {"max_keypoints": "many"}}, "expected an integer"),
        ({"render": {"shading": "glossy"}}, "not one of"),
        ({"verdict": {"threshold_px": "x"}}, "does not fit"),
        ({"fail_fast": 2}, "true/false"),
        ({"run_checks": {"enabled": "ture"}}, "true/false"),
    ],
)
def test_bad_config_is_an_error(data, msg):
    with pytest.raises(ConfigError, match=msg):
        RunConfig.from_dict(data)


def test_fingerprint_holds_what_the_measurement_reads():
    fp = lambda d: RunConfig.from_dict(d).measurement_fingerprint()  # noqa: E731
    never = {"enhance": {"mode": "never"}}
    # verdict-only settings never change it
    assert fp({}) == fp({"verdict": {"min_inliers": 50}, "gate": {"max_fail_fraction": 0.2}})
    # the threshold does not change a raw-only measurement ...
    assert fp(never) == fp({**never, "verdict": {"threshold_px": 3.0}})
    # ... but drives the --enhance auto decision (the default), and min_coverage always
    assert fp({}) != fp({"verdict": {"threshold_px": 3.0}})
    assert fp(never) != fp({**never, "verdict": {"min_coverage": 0.5}})
    assert fp({}) != fp({"match": {"method": "orb"}})


def test_load_config_file(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"match": {"method": "akaze"}}))
    assert RunConfig.from_dict(load_config_file(p)).match.method == "akaze"
    t = tmp_path / "c.toml"
    t.write_text('[verdict]\nthreshold_px = 4.0\n')
    assert RunConfig.from_dict(load_config_file(t)).verdict.threshold_px == 4.0
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(ConfigError, match="cannot parse"):
        load_config_file(bad)


def test_presets_are_valid_configs_and_cli_options_override_them():
    from pgt_check.commands.check import build_parser, load_config
    from pgt_check.config import PRESETS

    for name in PRESETS:
        args = build_parser().parse_args(["t.txt", "--mesh", "m.ply", "--preset", name])
        assert isinstance(load_config(args), RunConfig)
    args = build_parser().parse_args(["t.txt", "--mesh", "m.ply", "--preset", "fast",
                                      "--matcher", "orb"])
    c = load_config(args)
    assert c.match.method == "orb" and c.match.resize_max == 320 and c.enhance.mode == "never"
    balanced = load_config(build_parser().parse_args(["t.txt", "--mesh", "m", "--preset", "balanced"]))
    assert balanced.enhance.mode == "auto" and balanced.enhance.method == "reproject"


def test_settings_of_the_older_layout_are_read_at_their_new_place(tmp_path):
    """config.json of runs before the gate and run-level sections (issue #26) still loads: the
    moved keys land in ``gate`` / ``run_checks``; a key given at both places is an error."""
    from pgt_check.config import load_config_file
    from pgt_check.errors import ConfigError

    old = {"verdict": {"threshold_px": 6.0, "max_fail_fraction": 0.25, "shared_checks": False,
                       "calibration_translation": True},
           "correct": {"frames": "none", "registration_rounds": 2}}
    cfg = RunConfig.from_dict(old)
    assert cfg.verdict.threshold_px == 6.0 and cfg.gate.max_fail_fraction == 0.25
    assert cfg.run_checks.enabled is False and cfg.run_checks.calibration_translation is True
    assert cfg.run_checks.refine_rounds == 2 and cfg.correct.frames == "none"
    assert old["verdict"]["max_fail_fraction"] == 0.25  # the caller's dict is not changed
    path = tmp_path / "config.json"
    path.write_text(json.dumps(old))
    assert RunConfig.from_dict(load_config_file(path)) == cfg
    with pytest.raises(ConfigError, match="gate.max_fail_fraction"):
        RunConfig.from_dict({"verdict": {"max_fail_fraction": 0.1},
                             "gate": {"max_fail_fraction": 0.2}})
    with pytest.raises(ConfigError):
        RunConfig.from_dict({"gate": {"shared_checks": False}})  # not a gate setting
