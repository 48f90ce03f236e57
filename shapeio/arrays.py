"""NumPy views of array-likes, torch tensors included, without importing torch."""

from __future__ import annotations

import numpy as np

__all__ = ["as_numpy"]


def as_numpy(x) -> np.ndarray:
    """``x`` as a NumPy array; a torch tensor is detached and moved to the CPU first."""
    if type(x).__module__.startswith("torch"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)
