"""Inference API and checkpoints: ``Enhancer.from_pretrained(...).enhance(render, reference)``.

Images at the API are RGB in [0, 1]:

* numpy: ``float32`` arrays ``(H, W, 3)`` or batched ``(N, H, W, 3)``;
* torch: floating tensors ``(3, H, W)`` or ``(N, 3, H, W)`` on any device.

``enhance`` returns the same type, layout and size as the render (torch outputs go back to the
render's device; values clamped to [0, 1]). ``enhance_working`` first resizes both images so their
shorter side is ``short_side`` (the method's native scale, ~160-320 px), enhances, and returns the
result *at working size* together with the factors that map working pixels to input pixels:
``x_in = (x_work + 0.5) * scale_x - 0.5`` (OpenCV pixel centres), same for y.

Checkpoint format (``save_checkpoint``): ``{"config": MarinerConfig.to_dict(), "state_dict": ...,
"meta": {...}}``, loaded with ``torch.load(weights_only=True)`` and ``strict=True``.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from .checkpoint import CHECKPOINT_KEYS, read_checkpoint  # noqa: F401  (re-exported)
from .config import MarinerConfig
from .frozen import ARCHITECTURE as FROZEN_ARCHITECTURE
from .frozen import OUTPUTS, FrozenMariner, FrozenMarinerConfig
from .model import Mariner

logger = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_CHECKPOINT",
    "EnhanceResult",
    "Enhancer",
    "build_model",
    "export_weights",
    "load_checkpoint",
    "save_checkpoint",
]

DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "weights" / "mariner.pt"
#: default bound on the global matching of a frozen-matcher model: render x reference relu3_3
#: positions compared. It admits a 640x480 render with a 640x480 reference (3.7e8); the cost
#: and memory grow with the square of the image area (a 1416x1064 pair is 8.8e9).
MAX_MATCH_PAIRS = 4.0e8
FORMAT_VERSION = 1


def save_checkpoint(
    model: Mariner | FrozenMariner,
    path: str | Path,
    extra: dict[str, Any] | None = None,
    fp16: bool = False,
) -> Path:
    """Write ``{"config", "state_dict", "meta"}``; ``fp16`` halves floating tensors on disk.

    ``extra`` goes into ``meta`` and must hold only plain python values / tensors (it is read
    back with ``weights_only=True``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sd = {
        k: (v.detach().to("cpu", torch.float16) if fp16 and v.is_floating_point() else v.cpu())
        for k, v in model.state_dict().items()
    }
    meta = {"format_version": FORMAT_VERSION, "torch": str(torch.__version__), "fp16": bool(fp16)}
    meta.update(extra or {})
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save({"config": model.cfg.to_dict(), "state_dict": sd, "meta": meta}, tmp)
    tmp.replace(path)
    return path


def build_model(config: dict[str, Any]) -> Mariner | FrozenMariner:
    """The network a checkpoint's ``config`` describes: ``architecture: "frozen-vgg"`` builds a
    :class:`FrozenMariner` (frozen matcher + trained fusion), anything else the spec network."""
    if config.get("architecture") == FROZEN_ARCHITECTURE:
        return FrozenMariner(FrozenMarinerConfig.from_dict(config))
    return Mariner(MarinerConfig.from_dict(config))


def load_checkpoint(
    path: str | Path, map_location: str | torch.device = "cpu"
) -> Mariner | FrozenMariner:
    """Load a checkpoint strictly (``weights_only=True``, ``strict=True``) into a fresh model."""
    ckpt = read_checkpoint(path, map_location)
    model = build_model(dict(ckpt["config"]))
    model.load_state_dict(ckpt["state_dict"], strict=True)  # fp16 storage: copied to float32
    logger.info("loaded MaRINeR checkpoint %s (meta %s)", path, ckpt["meta"])
    return model


@dataclass(frozen=True)
class EnhanceResult:
    """Enhanced image at working size; ``x_in = (x + 0.5) * scale_x - 0.5``, same for y."""

    image: np.ndarray | torch.Tensor
    scale_x: float
    scale_y: float


def _resolve_device(device: str | torch.device) -> torch.device:
    if str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but CUDA is not available")
    return dev


def _to_tensor(img: np.ndarray | torch.Tensor, name: str) -> tuple[torch.Tensor, str, bool]:
    """-> ((N, 3, H, W) float32 tensor, kind 'numpy'|'torch', batched?)."""
    if isinstance(img, np.ndarray):
        if img.dtype != np.float32:
            raise ValueError(f"{name}: numpy images must be float32 RGB in [0, 1], got {img.dtype}")
        if img.ndim not in (3, 4) or img.shape[-1] != 3:
            raise ValueError(f"{name}: expected (H, W, 3) or (N, H, W, 3), got {img.shape}")
        img = np.ascontiguousarray(img) if img.flags.writeable else np.array(img)  # torch warns
        t = torch.from_numpy(img)
        batched = img.ndim == 4
        t = (t if batched else t[None]).permute(0, 3, 1, 2)
        return t, "numpy", batched
    if isinstance(img, torch.Tensor):
        if not img.is_floating_point():
            raise ValueError(f"{name}: torch images must be floating in [0, 1], got {img.dtype}")
        if img.ndim not in (3, 4) or img.shape[-3] != 3:
            raise ValueError(f"{name}: expected (3, H, W) or (N, 3, H, W), got {tuple(img.shape)}")
        batched = img.ndim == 4
        return (img if batched else img[None]), "torch", batched
    raise ValueError(f"{name}: expected a numpy array or torch tensor, got {type(img).__name__}")


def _from_tensor(
    t: torch.Tensor, kind: str, batched: bool, like: np.ndarray | torch.Tensor
) -> np.ndarray | torch.Tensor:
    if kind == "numpy":
        arr = t.float().permute(0, 2, 3, 1).cpu().numpy()
        return arr if batched else arr[0]
    out = t.to(device=like.device, dtype=like.dtype)  # type: ignore[arg-type]  # a tensor here
    return out if batched else out[0]


def resize_short_side(x: torch.Tensor, short_side: int) -> torch.Tensor:
    """Resize (N, 3, H, W) so min(H, W) == short_side (bicubic, antialiased, aspect kept)."""
    h, w = x.shape[-2:]
    f = short_side / min(h, w)
    size = (max(1, round(h * f)), max(1, round(w * f)))
    if size == (h, w):
        return x
    return F.interpolate(x, size=size, mode="bicubic", align_corners=False, antialias=True).clamp(
        0.0, 1.0
    )


class Enhancer:
    """Inference wrapper around a :class:`Mariner` model (eval mode, no grad, deterministic)."""

    def __init__(
        self, model: Mariner | FrozenMariner, device: str | torch.device = "cpu",
        fp16: bool = False, max_match_pairs: float | None = MAX_MATCH_PAIRS,
    ):
        """``max_match_pairs``: refuse inputs whose global matching (frozen-matcher models)
        compares more render x reference positions than this (None: no bound)."""
        self.device = _resolve_device(device)
        self.max_match_pairs = max_match_pairs
        if fp16 and self.device.type != "cuda":
            raise ValueError("fp16 autocast is only supported on CUDA devices")
        self.fp16 = fp16
        self.model = model.to(self.device).eval()

    @classmethod
    def from_pretrained(
        cls, path: str | Path | None = None, device: str | torch.device = "cpu", fp16: bool = False
    ) -> Enhancer:
        """Load a checkpoint (default: the shipped ``mariner_core/weights/mariner.pt``).

        ``device`` is ``"cpu"`` (default), ``"cuda"``, ``"cuda:N"`` or ``"auto"`` (CUDA when
        available); ``fp16`` enables float16 autocast on CUDA.
        """
        p = DEFAULT_CHECKPOINT if path is None else Path(path)
        if not p.is_file():
            hint = (
                " (the default checkpoint is not shipped yet: train one and save it with "
                "mariner_core.save_checkpoint)"
                if path is None
                else ""
            )
            raise FileNotFoundError(f"MaRINeR checkpoint not found: {p}{hint}")
        return cls(load_checkpoint(p), device=device, fp16=fp16)

    def check_size(self, render_hw: tuple[int, int], reference_hw: tuple[int, int]) -> None:
        """Raise ValueError (before any work) when a render / reference pair of these sizes
        exceeds ``max_match_pairs``: the global matching's time and memory grow with the
        product of the two images' areas."""
        if self.max_match_pairs is None or not isinstance(self.model, FrozenMariner):
            return
        pairs = FrozenMariner.match_pairs(render_hw, reference_hw)
        if pairs > self.max_match_pairs:
            (h, w), (hr, wr) = render_hw, reference_hw
            raise ValueError(
                f"render {w}x{h} with reference {wr}x{hr} needs {pairs:.2g} patch comparisons, "
                f"above max_match_pairs={self.max_match_pairs:.2g} (time and memory grow with "
                "the square of the image area): use enhance_working(render, reference, "
                "short_side=160), the method's native scale, or pass a larger max_match_pairs"
            )

    def _check_output(self, output: str) -> None:
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        if output != "model" and not isinstance(self.model, FrozenMariner):
            raise ValueError(f"output={output!r} needs a frozen-matcher model (it has a "
                             "matching-only base); this checkpoint is the spec network")

    @torch.inference_mode()
    def _run_outputs(
        self, x: torch.Tensor, ref: torch.Tensor, iterations: int | None, output: str
    ) -> list[torch.Tensor]:
        self._check_output(output)
        self.check_size((x.shape[-2], x.shape[-1]), (ref.shape[-2], ref.shape[-1]))
        x = x.to(self.device, torch.float32)
        ref = ref.to(self.device, torch.float32)
        if ref.shape[0] == 1 and x.shape[0] > 1:
            ref = ref.expand(x.shape[0], -1, -1, -1)
        with torch.autocast(self.device.type, dtype=torch.float16, enabled=self.fp16):
            if isinstance(self.model, FrozenMariner):
                ys = self.model(x, ref, iterations=iterations, output=output)
            else:
                ys = self.model(x, ref, iterations=iterations)[-1:]
        return [y.float().clamp_(0.0, 1.0) for y in ys]

    def _run(
        self, x: torch.Tensor, ref: torch.Tensor, iterations: int | None, output: str = "model"
    ) -> torch.Tensor:
        return self._run_outputs(x, ref, iterations, output)[-1]

    def enhance(
        self,
        render: np.ndarray | torch.Tensor,
        reference: np.ndarray | torch.Tensor,
        iterations: int | None = None,
        output: str = "model",
    ) -> np.ndarray | torch.Tensor:
        """Enhance at the given size; returns the render's type, layout and size, in [0, 1].

        The reference may differ in size (>= ``cfg.min_reference_size`` px per side); a single
        reference is broadcast over a batch of renders. Sizes whose matching exceeds
        ``max_match_pairs`` raise ValueError naming :meth:`enhance_working`. ``output``: as
        :meth:`enhance_working`.
        """
        x, kind, batched = _to_tensor(render, "render")
        ref, _, _ = _to_tensor(reference, "reference")
        if output == "both":
            raise ValueError("enhance returns one image: output 'model' or 'base'")
        return _from_tensor(self._run(x, ref, iterations, output), kind, batched, render)

    def enhance_working(
        self,
        render: np.ndarray | torch.Tensor,
        reference: np.ndarray | torch.Tensor,
        short_side: int = 160,
        iterations: int | None = None,
        output: str = "model",
    ) -> EnhanceResult:
        """Resize both images to ``short_side`` (shorter side), enhance, return at working size.

        Returns an :class:`EnhanceResult` whose image has the render's type/layout at working
        size and ``scale_x = W_in / W_work``, ``scale_y = H_in / H_work``. ``output``: "model"
        or "base" (the matching-only base of a frozen-matcher model; ``scene_check`` says
        which one a scene should get).
        """
        self._check_output(output)
        if output == "both":
            raise ValueError("enhance_working returns one image: output 'model' or 'base'")
        if short_side < self.model.cfg.min_reference_size:
            raise ValueError(
                f"short_side {short_side} is below the minimum reference size "
                f"{self.model.cfg.min_reference_size}"
            )
        x, kind, batched = _to_tensor(render, "render")
        ref, _, _ = _to_tensor(reference, "reference")
        h, w = x.shape[-2:]
        xw = resize_short_side(x.float(), short_side)
        refw = resize_short_side(ref.float(), short_side)
        y = self._run(xw, refw, iterations, output)
        return EnhanceResult(
            _from_tensor(y, kind, batched, render),
            scale_x=w / xw.shape[-1],
            scale_y=h / xw.shape[-2],
        )


def export_weights(
    run_checkpoint: str | Path,
    dst: str | Path,
    iterations: int | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Turn a run's ``last.pt`` (resumable) or ``best.pt`` into a shipped fp16 checkpoint.

    ``iterations`` overrides the stored default number of refinement iterations (it does not
    change the weights).
    """
    st = torch.load(run_checkpoint, map_location="cpu", weights_only=True)
    if "model" in st:  # resumable last.pt: the config comes from the run folder
        run_cfg = json.loads((Path(run_checkpoint).parent / "config.json").read_text())
        cfg = MarinerConfig.from_dict(run_cfg["model"])
        state, meta = (
            st["model"],
            {"step": st["step"], "samples": st["samples"], "elapsed_s": st["elapsed_s"]},
        )
    else:
        cfg = MarinerConfig.from_dict(dict(st["config"]))
        state = st["state_dict"]
        meta = {k: v for k, v in st["meta"].items() if k in ("step", "samples", "elapsed_s")}
    if iterations is not None:
        cfg = MarinerConfig.from_dict({**cfg.to_dict(), "iterations": int(iterations)})
    model = Mariner(cfg)
    model.load_state_dict(
        {k: v.float() if v.is_floating_point() else v for k, v in state.items()}, strict=True
    )
    meta.update(extra or {})
    return save_checkpoint(model, dst, extra=meta, fp16=True)
