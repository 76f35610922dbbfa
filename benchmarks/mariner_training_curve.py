"""Learning curve of a ``mariner_core.train_frozen`` run: validation PSNR-Y and training loss.

Usage: python benchmarks/mariner_training_curve.py RUN_DIR [--out reports/mariner_training.png]

Reads ``RUN_DIR/log.csv`` (one row per validation) and plots the validation PSNR-Y of the four
validation groups (coloured / colourless renders, reference 20 frames away / Ref = target) with
the raw renders' PSNR-Y as dashed lines, and the training L1 loss, against training samples.
A run on several scenes (``SCENE/group`` columns) gets one more panel per scene: its far-reference
groups with the matching-only base (dotted), the learning curve per scene.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402
from _common import REPORTS  # noqa: E402

GROUPS = {
    "coloured_offset": "coloured, ref 20 frames away",
    "colourless_offset": "colourless, ref 20 frames away",
    "coloured_ref_target": "coloured, Ref = target",
    "colourless_ref_target": "colourless, Ref = target",
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("--out", type=Path, default=REPORTS / "mariner_training.png")
    a = p.parse_args(argv)
    log = pd.read_csv(a.run / "log.csv")
    scenes = sorted({c.split("/")[0] for c in log.columns if "/" in c})
    fig, axes = plt.subplots(1, 2 + len(scenes), figsize=(5.5 * (2 + len(scenes)), 4))
    ax, bx = axes[0], axes[1]
    for i, (col, label) in enumerate(GROUPS.items()):
        if col in log:
            ax.plot(log["samples"], log[col], marker="o", ms=3, color=f"C{i}", label=label)
    for i, col in enumerate(("coloured_offset_raw", "colourless_offset_raw")):
        if col in log:
            ax.axhline(log[col].iloc[0], ls="--", color=f"C{i}", lw=1,
                       label=f"raw render ({col.split('_')[0]})")
    ax.set_xlabel("training samples (crops)")
    ax.set_ylabel("validation PSNR-Y (dB)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    t = log.dropna(subset=["l1"])
    bx.plot(t["samples"], t["l1"], marker="o", ms=3, label="L1")
    bx.set_xlabel("training samples (crops)")
    bx.set_ylabel("training L1 (mean since the previous validation)")
    bx.grid(alpha=0.3)
    for sx, scene in zip(axes[2:], scenes, strict=True):
        for i, g in enumerate(("coloured_offset", "colourless_offset", "coloured_ref_target")):
            col = f"{scene}/{g}"
            if col in log and log[col].notna().any():
                sx.plot(log["samples"], log[col], marker="o", ms=3, color=f"C{i}",
                        label=GROUPS[g])
                if f"{col}_base" in log:
                    sx.plot(log["samples"], log[f"{col}_base"], ls=":", color=f"C{i}", lw=1,
                            label="matching-only base" if i == 0 else None)
        sx.set_title(scene, fontsize=9)
        sx.set_xlabel("training samples (crops)")
        sx.grid(alpha=0.3)
        sx.legend(fontsize=6)
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
