"""File writing shared by the output writers (``pgt_check.common.files``, re-exported here)."""

from __future__ import annotations

from pgt_check.common.files import atomic_write_bytes, atomic_write_text

__all__ = ["atomic_write_bytes", "atomic_write_text"]
