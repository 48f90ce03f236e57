"""Programs as renderer input: programs or token indices to kind codes and parameters, and the cache of
packed vocabulary primitives."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from .. import primitives as P
from ..lang import MAX_TOKENS, Draw, Program, draw_token, parse, split_tokens
from ..vocab import codes, vocabulary
from .raster import _blocks, _canvas_words, _slab_range, draw_packed

# ------------------------------------------------------------------------------------------------
# encoding programs

# (dim, token text) -> (code, vocabulary index or -1, *parameters zero-padded to MAX_PARAMS), or None for
# a token that is not a valid dim-D token (parse then raises the located error)
_ENTRIES: dict = {}
_ENTRIES_MAX = 1 << 17


def _entry(dim: int, text: str):
    """The code row of one token text (see ``_ENTRIES``), computed once per text."""
    key = (dim, text)
    try:
        return _ENTRIES[key]
    except KeyError:
        pass
    c = codes()
    vocab = vocabulary(dim)
    if text in c.op:
        entry = (c.op[text], vocab.op_index(text)) + (0,) * P.MAX_PARAMS
    else:
        d = draw_token(text, dim)
        entry = None if d is None else (
            (c.kind[d.kind], vocab._index.get(d.text(long=False), -1)) + d.params
            + (0,) * (P.MAX_PARAMS - len(d.params)))
    if len(_ENTRIES) >= _ENTRIES_MAX:
        _ENTRIES.clear()
    _ENTRIES[key] = entry
    return entry


def _program_entries(program: Program | str, dim: int, b: int) -> list:
    """The code rows of one program's tokens (text: from the per-token cache, no objects built)."""
    if isinstance(program, str):
        pieces = split_tokens(program)
        if pieces is not None and len(pieces) <= MAX_TOKENS:  # else parse raises the located error
            get = _ENTRIES.get
            rows = [get((dim, t)) or _entry(dim, t) for t in pieces]
            if None not in rows:
                return rows
        program = parse(program, dim, strict=False)  # raises the located ParseError
    if program.dim != dim:
        raise ValueError(f"program {b} is {program.dim}D, expected {dim}D: {program.text()!r}")
    return [_entry(dim, t.text(long=False) if isinstance(t, Draw) else t.op) for t in program.tokens]


def _encode(programs: Sequence[Program | str], dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``kinds (B, T)``, ``params (B, T, 5)`` and, when every primitive is a vocabulary token, the
    token indices ``(B, T)`` (``$``-padded; else None), all int64 NumPy arrays."""
    rows = [_program_entries(p, dim, b) for b, p in enumerate(programs)]
    lengths = np.array([len(r) for r in rows], dtype=np.int64)
    B, T = len(rows), int(lengths.max(initial=1))
    table = np.array([e for r in rows for e in r], dtype=np.int64).reshape(-1, 2 + P.MAX_PARAMS)
    used = np.arange(T)[None, :] < lengths[:, None]
    kinds = np.full((B, T), codes().stop, dtype=np.int64)
    params = np.zeros((B, T, P.MAX_PARAMS), dtype=np.int64)
    kinds[used], params[used] = table[:, 0], table[:, 2:]
    ids = None
    if (table[:, 1] >= 0).all():
        ids = np.full((B, T), vocabulary(dim).stop, dtype=np.int64)
        ids[used] = table[:, 1]
    return kinds, params, ids


def encode_programs(programs: Sequence[Program | str], dim: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Programs (objects or text) -> ``kinds (B, T) int64`` and ``params (B, T, 5) int64``.

    Text is parsed non-strictly, so structurally invalid programs encode (and render empty); a
    malformed text raises the :class:`~csgnet.lang.ParseError` of :func:`~csgnet.lang.parse`.
    """
    kinds, params, _ = _encode(programs, dim)
    return torch.from_numpy(kinds).to(device), torch.from_numpy(params).to(device)


def encode_programs_ids(programs: Sequence[Program | str], dim: int, device=None):
    """:func:`encode_programs`, plus the token indices ``(B, T) int64`` of the programs when every
    primitive is a vocabulary token (the renderer then takes primitives from the
    :class:`PrimitiveCache` instead of drawing them), else None."""
    kinds, params, ids = _encode(programs, dim)
    return (torch.from_numpy(kinds).to(device), torch.from_numpy(params).to(device),
            None if ids is None else torch.from_numpy(ids).to(device))


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


@P.on_change
def _table_changed() -> None:
    _PRIM_CACHES.clear()
    _ENTRIES.clear()


def primitive_cache(dim: int, device) -> PrimitiveCache:
    """The process-wide :class:`PrimitiveCache` of ``dim`` on ``device``."""
    key = (dim, str(torch.device(device)))
    if key not in _PRIM_CACHES:
        _PRIM_CACHES[key] = PrimitiveCache(dim, device)
    return _PRIM_CACHES[key]
