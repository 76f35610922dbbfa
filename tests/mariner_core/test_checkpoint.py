"""Reading checkpoint files (``mariner_core.checkpoint``): what both loaders refuse."""

from __future__ import annotations

import pytest
import torch

from mariner_core.checkpoint import CHECKPOINT_KEYS, read_checkpoint
from mariner_core.enhancer import save_checkpoint
from mariner_core.frozen import FrozenMariner, FrozenMarinerConfig


def test_a_saved_checkpoint_reads_back_with_its_three_parts(tmp_path):
    model = FrozenMariner(FrozenMarinerConfig(channels=8))
    path = save_checkpoint(model, tmp_path / "m.pt")
    ckpt = read_checkpoint(path)
    assert set(ckpt) == CHECKPOINT_KEYS
    assert ckpt["config"] == model.cfg.to_dict()
    assert set(ckpt["state_dict"]) == set(model.state_dict())


def test_a_missing_file_or_another_dict_is_refused(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        read_checkpoint(tmp_path / "none.pt")
    torch.save({"state_dict": {}}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a MaRINeR checkpoint"):
        read_checkpoint(tmp_path / "other.pt")
    torch.save([1, 2], tmp_path / "list.pt")
    with pytest.raises(ValueError, match="got list"):
        read_checkpoint(tmp_path / "list.pt")
