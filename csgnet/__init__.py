"""CSGNet: the CSG language, its batched renderer, metrics and (later) neural shape parsers.

Entry points:

* :func:`parse` / :func:`to_text`: program text <-> :class:`Program`.
* :func:`vocabulary`: the 2D (400) and 3D (6635) token tables.
* :func:`render`: programs -> bool arrays ``(N, 64, 64)`` or ``(N, 64, 64, 64)``.
* :mod:`csgnet.metrics`: chamfer distance and IoU as the paper computes them.
* :func:`parse_shape`: a shape file (image, grid, mesh) or array -> its program, as ``python -m csgnet
  parse`` does it (beam search, refinement, a short program).
* :func:`load_pretrained` / :func:`infer`: the shipped neural parsers and program inference on
  bool images / volumes (:mod:`csgnet.inference`); models in :mod:`csgnet.models`, decoding in
  :mod:`csgnet.decode`, Lightning training in :mod:`csgnet.train.supervised`, tables in :mod:`csgnet.paper.tables`.
* :func:`refine` / :func:`refine_beams`: Powell refinement of a program's parameters toward a target
  image (chamfer or IoU) or volume (IoU) (:mod:`csgnet.refinement`).
"""

from __future__ import annotations

import importlib

import numpy as np

from .lang import Draw, Op, ParseError, Program, is_valid, parse, parse_lines, to_text
from .vocab import Vocabulary, vocabulary

__all__ = [
    "Draw",
    "Op",
    "ParseError",
    "Program",
    "Vocabulary",
    "is_valid",
    "parse",
    "parse_lines",
    "render",
    "to_text",
    "vocabulary",
]


def render(programs, dim: int = 2, device=None) -> np.ndarray:
    """Render programs to bool arrays.

    Args:
        programs: a program (text or :class:`Program`), a sequence of them, or token indices
            ``(N, T)`` (int array or tensor, padded with ``$``).
        dim: 2 or 3.
        device: torch device for the batched renderer (default CPU).

    Returns:
        ``(N, 64, 64)`` bool in 2D, ``(N, 64, 64, 64)`` in 3D (``N = 1`` for a single program).
        Invalid programs render all False.
    """
    import torch  # lazy: `import csgnet` (the language) loads neither torch nor the renderer

    from . import renderer as _r  # lazy, as torch above

    if isinstance(programs, (str, Program)):
        programs = [programs]
    if isinstance(programs, (np.ndarray, torch.Tensor)):
        out = _r.render_tokens(torch.as_tensor(programs, device=device), dim)
    else:
        out = _r.render_programs(list(programs), dim, device)
    return out.cpu().numpy()


def __getattr__(name):  # lazy submodules: csgnet.metrics etc. without work at import
    if name in {"metrics", "export", "data", "renderer", "primitives", "refinement", "models", "score",
                "decode", "train", "paper", "inference"}:
        return importlib.import_module(f".{name}", __name__)
    if name in {"load_pretrained", "infer", "load_model", "load_shape", "parse_shape"}:  # of csgnet.inference
        return getattr(importlib.import_module(".inference", __name__), name)
    if name in {"refine", "refine_beams"}:  # functions of csgnet.refinement
        return getattr(importlib.import_module(".refinement", __name__), name)
    raise AttributeError(f"module 'csgnet' has no attribute {name!r}")
