"""Training-time augmentation of target images."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["jitter"]

_CENTRE = 32.5  # Keras' centre h / 2 + 0.5


def jitter(images, generator, shift: float = 3.0, zoom: float = 2.0 / 64.0):
    """The 2D training augmentation: a Keras-style random affine per image, nearest-neighbour.

    Output pixel ``p = (row, col)`` samples the input at ``Z (p - c) + t + c`` with ``c = (32.5, 32.5)``,
    ``t = (t_row, t_col)`` each uniform in ``[-shift, shift]`` and ``Z = diag(z_row, z_col)`` each uniform
    in ``[1 - zoom, 1 + zoom]``; samples outside the canvas take the nearest edge value
    (``scipy.ndimage.affine_transform(order=0, mode='nearest')``). Per image the draws come in the order
    ``t_row, t_col, z_row, z_col`` (the spec's section (c)).

    Args:
        images: (B, 64, 64) bool, NumPy array or torch tensor.
        generator: ``numpy.random.Generator`` or ``torch.Generator`` (consumed: 4 uniforms per image).
        shift: translation range in pixels (3 in the reference).
        zoom: zoom range (2/64 in the reference).

    Returns:
        (B, 64, 64) bool, the same type (and device) as ``images``.
    """
    from scipy.ndimage import affine_transform  # lazy: scipy is only needed when augmenting

    is_torch = isinstance(images, torch.Tensor)
    arr = images.detach().cpu().numpy() if is_torch else np.asarray(images)
    if arr.ndim != 3 or arr.shape[1:] != (64, 64):
        raise ValueError(f"images must be (B, 64, 64), got shape {tuple(arr.shape)}")
    B = arr.shape[0]
    if isinstance(generator, torch.Generator):
        u = torch.rand((B, 4), generator=generator, dtype=torch.float64).numpy()
    elif isinstance(generator, np.random.Generator):
        u = generator.random((B, 4))
    else:
        raise TypeError(f"generator must be a numpy.random.Generator or torch.Generator, got {type(generator).__name__}")
    t = -shift + 2.0 * shift * u[:, :2]
    z = (1.0 - zoom) + 2.0 * zoom * u[:, 2:]
    c = np.array([_CENTRE, _CENTRE])
    src = arr.astype(np.uint8)
    out = np.empty_like(src)
    for b in range(B):
        affine_transform(src[b], z[b], offset=t[b] + c - z[b] * c, output=out[b], order=0, mode="nearest")
    out = out.astype(bool)
    return torch.from_numpy(out).to(images.device) if is_torch else out
