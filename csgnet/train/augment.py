"""Training-time augmentation: the 2D jitter of target images, and the mirror symmetries of 3D programs."""

from __future__ import annotations

from functools import lru_cache
from itertools import product

import numpy as np
import torch

from ..lang import Draw
from ..primitives import SIZE
from ..vocab import vocabulary

__all__ = ["jitter", "jitter_reference", "symmetry_tables", "mirror_programs", "mirror_volumes", "mirror_pairs"]


@lru_cache(maxsize=None)
def symmetry_tables(dim: int = 3) -> torch.Tensor:
    """Token maps of the 3D canvas symmetries that every primitive type keeps: the 8 mirrorings of the axes
    (centre ``c`` → ``64 - c``) times the exchange of the first two axes (cylinders stand along the third).

    A mirrored program draws the mirrored shape moved by one voxel (exactly ``flip`` then ``roll 1`` along
    the mirrored axis, tested), so it keeps the sampler's rules. Some primitives that fit the canvas do not
    fit it mirrored (their mirror image is not in the vocabulary): their entry is -1.

    Returns:
        ``(16, V) int64``: row 0 the identity.
    """
    if dim != 3:
        raise ValueError(f"the program symmetries are defined for 3D programs, got dim {dim}")
    vocab = vocabulary(dim)
    rows = []
    for swap, flips in product((False, True), product((False, True), repeat=3)):
        row = []
        for i, draw in enumerate(vocab._draws):
            if not isinstance(draw, Draw):
                row.append(i)
                continue
            p = list(draw.params)
            for a in range(3):
                if flips[a]:
                    p[a] = SIZE - p[a]
            if swap:
                p[0], p[1] = p[1], p[0]
            try:
                row.append(vocab.index(Draw(draw.kind, tuple(p))))
            except KeyError:
                row.append(-1)
        rows.append(row)
    return torch.tensor(rows, dtype=torch.int64)


def _mirrored(tokens: torch.Tensor, generator: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """The mapped programs and ``(B,) int64`` symmetry of each (0 where a program stays as it is)."""
    tables = symmetry_tables(3).to(tokens.device)
    g = torch.as_tensor(generator.integers(0, len(tables), size=tokens.shape[0]), device=tokens.device)
    mapped = tables[g[:, None], tokens]
    keep = (mapped < 0).any(1)
    return torch.where(keep[:, None], tokens, mapped), torch.where(keep, torch.zeros_like(g), g)


def mirror_programs(tokens: torch.Tensor, generator: np.random.Generator) -> torch.Tensor:
    """3D programs ``(B, T)`` (``$``-padded token indices), each mapped by one of the 16
    :func:`symmetry_tables` drawn uniformly (one draw per program, always consumed); a program with a
    primitive whose image is not in the vocabulary stays as it is."""
    return _mirrored(tokens, generator)[0]


def mirror_volumes(volumes: torch.Tensor, symmetry: torch.Tensor) -> torch.Tensor:
    """Map each volume by a symmetry of :func:`symmetry_tables`, as the mapped program's render moves: each
    mirrored axis flipped and rolled by one voxel, then the first two axes exchanged.

    Args:
        volumes: ``(B, 64, 64, 64)`` bool.
        symmetry: ``(B,) int64`` row of :func:`symmetry_tables` per volume (0: the identity).
    """
    out = volumes.clone()
    for g in torch.unique(symmetry).tolist():
        if g == 0:
            continue
        rows = torch.nonzero(symmetry == g).flatten()
        x = volumes[rows]
        for a in range(3):
            if (g >> (2 - a)) & 1:  # the flips of the axes, x first (symmetry_tables' order)
                x = torch.roll(torch.flip(x, [a + 1]), 1, a + 1)
        out[rows] = x.transpose(1, 2) if g >= 8 else x
    return out


def mirror_pairs(tokens: torch.Tensor, volumes: torch.Tensor, generator: np.random.Generator
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """3D (program, target) pairs ``(B, T)``, ``(B, 64, 64, 64)`` both mapped by one of the 16 symmetries
    drawn uniformly per pair (:func:`mirror_programs`, :func:`mirror_volumes`): a program that draws its
    target draws the mapped target. A pair whose program has no image stays as it is."""
    mapped, g = _mirrored(tokens, generator)
    return mapped, mirror_volumes(volumes, g)

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
    is_torch = isinstance(images, torch.Tensor)
    shape = tuple(images.shape) if is_torch else np.shape(images)
    if len(shape) != 3 or tuple(shape[1:]) != (64, 64):
        raise ValueError(f"images must be (B, 64, 64), got shape {tuple(shape)}")
    B = shape[0]
    z, offset = _draws(B, generator, shift, zoom)
    # The transform is diagonal, so each output row (column) reads one source row (column): the source
    # index is computed per image and axis in float64 on the CPU (z * p + offset, nearest = floor(x + 0.5),
    # clamped for mode 'nearest'; pixel for pixel what scipy's affine_transform(order=0) gives, tested), and
    # the pixels are gathered where the images are (on the GPU during GPU training), in one indexing
    # operation for the batch. Inputs are cast through uint8 to bool, as the scipy version did.
    p = np.arange(64, dtype=np.float64)
    src = np.clip(np.floor(z[:, :, None] * p + offset[:, :, None] + 0.5), 0, 63).astype(np.int64)  # (B, 2, 64)
    if is_torch:
        idx = torch.from_numpy(src).to(images.device)
        b = torch.arange(B, device=images.device)[:, None, None]
        img = images if images.dtype == torch.bool else images.to(torch.uint8).bool()
        return img[b, idx[:, 0, :, None], idx[:, 1, None, :]]
    arr = np.asarray(images)
    arr = arr if arr.dtype == bool else arr.astype(np.uint8).astype(bool)
    return arr[np.arange(B)[:, None, None], src[:, 0, :, None], src[:, 1, None, :]]


def _draws(B: int, generator, shift: float, zoom: float) -> tuple[np.ndarray, np.ndarray]:
    """Per image, the zooms ``z`` and offsets (``t + c - z c``), both ``(B, 2)`` float64 in (row, col) order,
    from 4 uniforms per image drawn in the order ``t_row, t_col, z_row, z_col``."""
    if isinstance(generator, torch.Generator):
        u = torch.rand((B, 4), generator=generator, dtype=torch.float64).numpy()
    elif isinstance(generator, np.random.Generator):
        u = generator.random((B, 4))
    else:
        raise TypeError(f"generator must be a numpy.random.Generator or torch.Generator, got {type(generator).__name__}")
    t = -shift + 2.0 * shift * u[:, :2]
    z = (1.0 - zoom) + 2.0 * zoom * u[:, 2:]
    return z, t + _CENTRE - z * _CENTRE


def jitter_reference(images, generator, shift: float = 3.0, zoom: float = 2.0 / 64.0):
    """:func:`jitter` as its executable definition: ``scipy.ndimage.affine_transform(order=0,
    mode='nearest')`` image by image on the CPU, with the same draws. Slow; for tests and benchmarks.

    Returns:
        (B, 64, 64) bool NumPy array.
    """
    from scipy.ndimage import affine_transform  # lazy: scipy only for this augmentation

    arr = (images.detach().cpu().numpy() if isinstance(images, torch.Tensor) else np.asarray(images)).astype(np.uint8)
    z, offset = _draws(arr.shape[0], generator, shift, zoom)
    out = np.empty_like(arr)
    for b in range(arr.shape[0]):
        affine_transform(arr[b], z[b], offset=offset[b], output=out[b], order=0, mode="nearest")
    return out.astype(bool)
