"""Programs as renderer input: programs or token indices to kind codes and parameters, and the cache of
packed vocabulary primitives."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ..lang import Program, parse
from .. import primitives as P
from ..vocab import codes, vocabulary, write_codes
from .raster import _blocks, _canvas_words, _slab_range, draw_packed

# ------------------------------------------------------------------------------------------------
# encoding programs

def encode_programs(programs: Sequence[Program | str], dim: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Programs (objects or text) -> ``kinds (B, T) int64`` and ``params (B, T, 5) int64``.

    Text is parsed non-strictly, so structurally invalid programs encode (and render empty).
    """
    progs = [parse(p, dim, strict=False) if isinstance(p, str) else p for p in programs]
    T = max([len(p) for p in progs] + [1])
    kinds = np.full((len(progs), T), codes().stop, dtype=np.int64)
    params = np.zeros((len(progs), T, P.MAX_PARAMS), dtype=np.int64)
    for b, p in enumerate(progs):
        if p.dim != dim:
            raise ValueError(f"program {b} is {p.dim}D, expected {dim}D: {p.text()!r}")
        write_codes(p.tokens, kinds[b], params[b])
    return torch.from_numpy(kinds).to(device), torch.from_numpy(params).to(device)


def encode_tokens(tokens: torch.Tensor, dim: int, lengths: torch.Tensor | None = None):
    """Token indices ``(B, T)`` -> ``kinds (B, T)`` and ``params (B, T, 5)`` on the same device.

    Positions at or after ``lengths`` (if given) or after the first ``$`` become padding.
    """
    tokens = torch.as_tensor(tokens)
    if tokens.dim() != 2:
        raise ValueError(f"tokens must be (B, T), got shape {tuple(tokens.shape)}")
    vocab = vocabulary(dim)
    if tokens.numel() and (int(tokens.min()) < 0 or int(tokens.max()) >= len(vocab)):
        raise ValueError(f"token indices must lie in [0, {len(vocab)}) for the {dim}D vocabulary, "
                         f"got range [{int(tokens.min())}, {int(tokens.max())}]")
    cache = primitive_cache(dim, tokens.device)
    tokens = tokens.long()
    flat = tokens.reshape(-1)
    kinds = cache.kinds.index_select(0, flat).view(tokens.shape)
    params = cache.params.index_select(0, flat).view(tokens.shape + (5,))
    if lengths is not None:
        pos = torch.arange(tokens.shape[1], device=tokens.device)[None, :]
        kinds = torch.where(pos < torch.as_tensor(lengths, device=tokens.device)[:, None], kinds, codes().stop)
    return kinds, params


class PrimitiveCache:
    """Packed canvases of vocabulary primitives, computed on first use from the shared geometry.

    Nothing is read from disk: an entry is drawn by :func:`draw_packed` the first time a token is seen
    on a device and kept for the life of the process (2D: 200 KB for all 396 primitives; 3D: 32 KB per
    primitive, at most 217 MB if every one of the 6631 is used).
    """

    def __init__(self, dim: int, device):
        vocab = vocabulary(dim)
        k, p = vocab.table()
        self.dim = dim
        self.kinds = torch.from_numpy(k).to(device)
        self.params = torch.from_numpy(p).to(device)
        self.words = torch.empty((len(vocab),) + _canvas_words(dim), dtype=torch.int64, device=device)
        self.have = torch.zeros(len(vocab), dtype=torch.bool, device=device)
        # first and last non-empty block (see _blocks) of each cached entry, on the CPU
        self.lo = np.full(len(vocab), _blocks(dim)[0], np.int64)
        self.hi = np.full(len(vocab), -1, np.int64)

    def _ensure(self, ids) -> None:
        """Draw the entries of ``ids`` (token indices, NumPy or torch) that are not cached yet."""
        if self.have.device.type == "cpu":
            ids = np.unique(ids.numpy() if isinstance(ids, torch.Tensor) else ids)
            missing = ids[~self.have.numpy()[ids]]
            if not len(missing):
                return
            missing = torch.from_numpy(missing)
        else:
            ids = torch.unique(torch.as_tensor(ids, device=self.have.device))
            missing = ids[~self.have[ids]]
            if not missing.numel():
                return
        words = draw_packed(self.kinds[missing], self.params[missing], self.dim)
        self.words[missing] = words
        self.have[missing] = True
        m = missing.cpu().numpy()
        n_sl, bw = _blocks(self.dim)
        self.lo[m], self.hi[m] = _slab_range((words.view(len(m), n_sl, bw) != 0).any(-1).cpu().numpy())

    def get(self, ids: torch.Tensor, out: torch.Tensor | None = None) -> torch.Tensor:
        """(N,) token indices of primitives -> (N, *C) packed canvases (``out``: a (N, words) buffer)."""
        if ids.numel() == 0:
            return self.words[ids]
        self._ensure(ids)
        flat = self.words.view(self.words.shape[0], -1)
        if out is not None:
            return torch.index_select(flat, 0, ids, out=out)
        return flat.index_select(0, ids).view((-1,) + self.words.shape[1:])


_PRIM_CACHES: dict = {}
P.on_change(_PRIM_CACHES.clear)


def primitive_cache(dim: int, device) -> PrimitiveCache:
    """The process-wide :class:`PrimitiveCache` of ``dim`` on ``device``."""
    key = (dim, str(torch.device(device)))
    if key not in _PRIM_CACHES:
        _PRIM_CACHES[key] = PrimitiveCache(dim, device)
    return _PRIM_CACHES[key]
