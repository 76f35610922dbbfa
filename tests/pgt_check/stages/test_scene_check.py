"""The enhancer's scene check stage: one decision per run, from the run's own frames."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pgt_check.config import RunConfig
from pgt_check.errors import ConfigError
from pgt_check.stages.scene_check import needs_scene_check, resolve_enhancer_output
from pgt_check.types import Camera, Frame


def _frames(n: int) -> list[Frame]:
    cam = Camera("PINHOLE", 64, 48, (50.0, 50.0, 32.0, 24.0))
    return [Frame(f"f{i}", cam, np.eye(4), f"{i}.png", Path(f"/nonexistent/{i}.png"), float(i))
            for i in range(n)]


def _config(**enhance: Any) -> RunConfig:
    return RunConfig.from_dict({"input": {"trajectory": "t.txt", "mesh": "m.ply"},
                                "enhance": {"mode": "always", "method": "mariner", **enhance}})


@dataclass
class _Enhancer:
    gains: list[float]
    output: str = "auto"
    calls: int = 0

    def scene_scores(self, render, reference, target):
        if self.gains is None:
            return None
        g = self.gains[self.calls % len(self.gains)]
        self.calls += 1
        return 15.0 + g, 15.0


@dataclass
class _Checker:
    enhancer: Any
    config: Any = None
    missing: set[str] = field(default_factory=set)
    asked: list[str] = field(default_factory=list)

    def scene_triple(self, frame):
        self.asked.append(frame.frame_id)
        if frame.frame_id in self.missing:
            return None
        z = np.zeros((4, 4, 3), np.float32)
        return z, z, z


def _refs(frames):
    return {f.frame_id: (frames[(i + 1) % len(frames)],) for i, f in enumerate(frames)}


def test_only_mariner_runs_with_auto_output_need_it() -> None:
    assert needs_scene_check(_config())
    assert not needs_scene_check(_config(output="model"))
    assert not needs_scene_check(_config(method="reproject"))
    assert not needs_scene_check(_config(mode="never"))
    with pytest.raises(ConfigError, match="output"):
        _config(output="decoder")


@pytest.mark.parametrize(("gains", "want"), [([1.0, 1.2, 0.8, 1.5], "model"),
                                             ([-3.0, -2.0, -4.0, 0.5], "base"),
                                             ([0.3, -0.4, 0.2, -0.2], "base")])
def test_the_scene_decides_the_output(gains: list[float], want: str) -> None:
    frames = _frames(40)
    enh = _Enhancer(gains)
    checker = _Checker(enh)
    cfg = resolve_enhancer_output(_config(scene_check_frames=12), frames, _refs(frames), checker)
    assert cfg.enhance.output == want and enh.output == want
    assert checker.config is cfg and enh.calls == 12 and len(set(checker.asked)) == 12


def test_too_few_usable_frames_keep_the_base() -> None:
    frames = _frames(12)
    checker = _Checker(_Enhancer([2.0]), missing={f.frame_id for f in frames[3:]})
    cfg = resolve_enhancer_output(_config(), frames, _refs(frames), checker)
    assert cfg.enhance.output == "base"


def test_frames_without_references_are_not_scored() -> None:
    frames = _frames(10)
    checker = _Checker(_Enhancer([2.0]))
    refs = {f.frame_id: () for f in frames[:4]} | {f.frame_id: (frames[0],) for f in frames[4:]}
    resolve_enhancer_output(_config(), frames, refs, checker)
    assert set(checker.asked) == {f.frame_id for f in frames[4:]}


def test_a_model_without_a_base_keeps_its_output() -> None:
    frames = _frames(10)
    cfg = resolve_enhancer_output(_config(), frames, _refs(frames), _Checker(_Enhancer(None)))
    assert cfg.enhance.output == "model"


def test_runs_that_need_no_check_are_unchanged() -> None:
    cfg = _config(output="model")
    checker = _Checker(_Enhancer([5.0]))
    assert resolve_enhancer_output(cfg, _frames(10), {}, checker) is cfg and not checker.asked


@pytest.mark.enhance
@pytest.mark.slow
def test_a_run_records_the_scene_checks_choice(sample_scene, tmp_path) -> None:
    """A whole run with MaRINeR and ``enhance.output = auto``: a decoder that damages the
    scene (it brightens every pixel) is replaced by its matching-only base, which config.json
    records; an explicit ``model`` is left alone."""
    import json

    torch = pytest.importorskip("torch")
    from mariner_core.enhancer import save_checkpoint
    from mariner_core.frozen import FrozenMariner, FrozenMarinerConfig
    from pgt_check.runner import run

    torch.manual_seed(0)
    model = FrozenMariner(FrozenMarinerConfig(top_k=2, channels=4, blocks=(1, 1, 1),
                                              patch_size=3, gated=True))
    with torch.no_grad():
        model.head.bias[:3] = 0.6
        model.head.bias[3] = 4.0
    weights = tmp_path / "damaging.pt"
    save_checkpoint(model, weights)
    outputs = {}
    for output in ("auto", "model"):
        out = tmp_path / output
        cfg = RunConfig.from_dict({
            "input": {"trajectory": str(sample_scene / "trajectories.txt"),
                      "mesh": str(sample_scene / "mesh.glb")},
            "out": str(out), "limit": 8, "report_details": 0,
            "enhance": {"mode": "always", "method": "mariner", "weights": str(weights),
                        "output": output, "scene_check_frames": 8,
                        "reference": {"count": 1}},
            "run_checks": {"enabled": False}, "correct": {"frames": "none"},
        })
        run(cfg)
        outputs[output] = json.loads((out / "config.json").read_text())["enhance"]["output"]
    assert outputs == {"auto": "base", "model": "model"}
