"""Pictures of ShapeCoder programs, as the paper's Fig. 6: the shapes that use an abstraction, with the
parts its calls make in one colour and the other parts in another (:func:`usage_sheet`), and random
dreams of a function (:func:`dream_sheet`, :mod:`shapeprog.coder.dream`). Uses
:func:`shapeprog.picture.render_grid`.

Example:
    >>> from shapeprog.coder.lang import Library, parse, parse_abstraction
    >>> lib = Library().add(parse_abstraction("P(w: Float, x: Float) = SymRef(Move(Cuboid(w,0.5,w),x,0.0,0.0),AX)"))
    >>> prog = parse("Union(P(0.1,-0.4),Move(Cuboid(1.0,0.1,1.0),0.0,0.3,0.0))", lib)
    >>> parts, labels = labelled_corners(prog, lib, "P")
    >>> parts.shape, labels.tolist()
    ((3, 8, 3), [1, 1, 0])
"""
from __future__ import annotations

import numpy as np

from .dream import function_dreams
from .execute import corners, run
from .lang import Call, Expr, Library, walk
from .proposal import pieces

__all__ = ["dream_sheet", "labelled_corners", "usage_sheet"]


def labelled_corners(program: Expr, library: Library, name: str) -> tuple:
    """The corners of a program's parts ``(P, 8, 3)`` in the picture module's corner order, and a label
    per part: 1 for the parts of top-level pieces that call ``name``, 0 for the others."""
    out, labels = [], []
    for piece in pieces(program):
        ex = run(piece, library)
        prims = [(*p.dims, *p.center, 0.0, 0.0, 0.0) for p in ex.parts]
        c = corners(prims) if prims else np.zeros((0, 8, 3))
        # rotate each part's corners about its centre by its rotation matrix
        for k, p in enumerate(ex.parts):
            c[k] = (c[k] - p.center) @ p.rot.T + p.center
        out.append(c[:, ::-1, :])  # corners() lists -,-,- first; the picture module +,+,+ first
        uses = any(isinstance(n, Call) and n.fn == name for n in walk(piece))
        labels += [int(uses)] * len(ex.parts)
    return np.concatenate(out, 0), np.array(labels)


def usage_sheet(programs, library: Library, name: str, path=None, count: int = 4, size: int = 192) -> np.ndarray:
    """A row of up to ``count`` programs that call abstraction ``name`` (the first ones), the parts of its
    calls in the second palette colour. Returns the ``(size, count * size, 3) uint8`` picture (written as
    PNG to ``path`` when given).

    Raises:
        ValueError: no program calls ``name``.
    """
    from shapeprog.picture import render_grid  # lazy: pictures bring PIL

    using = [p for p in programs if any(isinstance(n, Call) and n.fn == name for n in walk(p))][:count]
    if not using:
        raise ValueError(f"no program calls {name!r}")
    return render_grid([labelled_corners(p, library, name) for p in using], path, cols=count, size=size)


def dream_sheet(name: str, library: Library, path=None, count: int = 4, size: int = 192, seed: int = 0) -> np.ndarray:
    """A row of ``count`` random valid dreams of function ``name`` (an abstraction of ``library``,
    ``SymRef`` or ``SymTrans``; :func:`shapeprog.coder.dream.function_dreams` with ``seed``), every part
    in the second palette colour. Returns the ``(size, count * size, 3) uint8`` picture (written as PNG
    to ``path`` when given).

    Raises:
        ValueError: no valid dream was found (the function was abandoned).
    """
    from shapeprog.picture import render_grid  # lazy: pictures bring PIL


    fd = function_dreams(name, library, n=count, seed=seed, timeout=60.0)
    if not fd.dreams:
        raise ValueError(f"no valid dream of {name!r} ({sum(fd.failures.values())} rejected)")
    return render_grid([labelled_corners(d.expr, library, name) for d in fd.dreams], path, cols=count, size=size)
