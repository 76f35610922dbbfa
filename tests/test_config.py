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
        ({"verdict": {"shared_checks": "ture"}}, "true/false"),
    ],
)
def test_bad_config_is_an_error(data, msg):
    with pytest.raises(ConfigError, match=msg):
        RunConfig.from_dict(data)


def test_fingerprint_holds_what_the_measurement_reads():
    fp = lambda d: RunConfig.from_dict(d).measurement_fingerprint()  # noqa: E731
    never = {"enhance": {"mode": "never"}}
    # verdict-only settings never change it
    assert fp({}) == fp({"verdict": {"min_inliers": 50, "max_fail_fraction": 0.2}})
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
