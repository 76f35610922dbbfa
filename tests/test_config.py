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
        ({"fail_fast": 1}, "true/false"),
    ],
)
def test_bad_config_is_an_error(data, msg):
    with pytest.raises(ConfigError, match=msg):
        RunConfig.from_dict(data)


def test_fingerprint_ignores_verdict_thresholds_only():
    a = RunConfig()
    b = RunConfig.from_dict({"verdict": {"threshold_px": 3.0}})
    c = RunConfig.from_dict({"match": {"method": "orb"}})
    assert a.measurement_fingerprint() == b.measurement_fingerprint()
    assert a.measurement_fingerprint() != c.measurement_fingerprint()


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
    from pgt_check.cli import build_parser, load_config
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
