"""Model configuration for the MaRINeR network (a frozen dataclass, strict ``from_dict``)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

__all__ = ["MarinerConfig"]


@dataclass(frozen=True)
class MarinerConfig:
    """Hyper-parameters of the MaRINeR generator (defaults = the spec / released config).

    Attributes:
        channels: feature channels at every level (C).
        encoder_blocks: ResBlocks per encoder level (L1, L2, L3).
        decoder_blocks: ResBlocks after fusion at (L3, L2, L1) = (N3, N2, N1).
        patch_size: MEM patch size p (odd).
        block_size: MEM render block size b in L3 pixels.
        window_factor: MEM relative reference window factor rho.
        dilations: Stage-A (coarse) dilations whose cosine maps are summed.
        iterations: default number of refinement iterations K.
        global_skip: add the (current) rendering to the output (off in the released config).
        render_multiple: the rendering is padded (replicate, split evenly) to this multiple.
        reference_multiple: the reference is padded (replicate, bottom/right) to this multiple.
        min_reference_size: smallest reference side in pixels (L3 must hold a 15x15 window).
    """

    channels: int = 64
    encoder_blocks: tuple[int, int, int] = (4, 4, 4)
    decoder_blocks: tuple[int, int, int] = (12, 8, 4)
    patch_size: int = 3
    block_size: int = 8
    window_factor: float = 1.5
    dilations: tuple[int, ...] = (1, 2, 3)
    iterations: int = 2
    global_skip: bool = False
    render_multiple: int = 32
    reference_multiple: int = 16
    min_reference_size: int = 60

    def __post_init__(self) -> None:
        # Normalise lists (e.g. from JSON / asdict round trips) to tuples.
        for name in ("encoder_blocks", "decoder_blocks", "dilations"):
            object.__setattr__(self, name, tuple(int(v) for v in getattr(self, name)))
        if self.channels < 1:
            raise ValueError(f"channels must be >= 1, got {self.channels}")
        if len(self.encoder_blocks) != 3 or len(self.decoder_blocks) != 3:
            raise ValueError("encoder_blocks and decoder_blocks need exactly 3 entries (L1..L3)")
        if self.patch_size != 3:
            raise ValueError(
                f"patch_size {self.patch_size} is not supported: only 3 (the spec value)"
            )
        if self.block_size < 2:
            raise ValueError(f"block_size must be >= 2, got {self.block_size}")
        if not self.dilations or min(self.dilations) < 1:
            raise ValueError(f"dilations must be positive, got {self.dilations}")
        if max(self.dilations) > self.block_size // 2 - 1:
            raise ValueError(
                f"dilations {self.dilations} reach outside a {self.block_size}-px block"
            )
        if self.iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {self.iterations}")
        if self.render_multiple % (4 * self.block_size) != 0:
            raise ValueError(
                f"render_multiple ({self.render_multiple}) must be a multiple of "
                f"4 * block_size ({4 * self.block_size}) so L3 splits into whole blocks"
            )
        if self.reference_multiple % 4 != 0:
            raise ValueError("reference_multiple must be a multiple of 4 (two stride-2 levels)")

    def to_dict(self) -> dict[str, Any]:
        """Plain-python dict (lists instead of tuples) suitable for checkpoints and JSON."""
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MarinerConfig:
        """Build a config; unknown keys raise ``ValueError`` naming the allowed ones."""
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise ValueError(f"unknown MarinerConfig key(s) {unknown} (allowed: {sorted(allowed)})")
        return cls(**data)
