"""The ShapeCoder paper's studies beyond its tables: perturbed programs (Table 4 right), noisy primitive input
(section 7.5) and a simple generative model over programs with abstractions (section 7.6).

* :func:`perturb` adds ``sigma * N(0, 1)`` to every free number of a program (its float literals: with a
  library, the abstraction calls' parameters; without one, every number of the naive program), so that the
  relations an abstraction captures survive the noise. :func:`perturbation_fd` executes the perturbed
  programs and compares them with held-out shapes by the Fréchet distance of the generation tables'
  PointNet features (:mod:`shapeprog.vae.genmetrics`; the ShapeMOD paper's perturbation study, Fig. 7).
* :func:`noisy` adds ``sigma * N(0, 1)`` to the dimensions and positions of a shape's primitives (rotations
  kept), rounded to the data's two decimals, dimensions at least :data:`MIN_DIM`.
* :class:`PieceSampler` is a generative model over programs: the number of top-level pieces, each piece's
  template (the piece with its numbers abstracted) by frequency, and the template's numbers from a Gaussian
  per slot, fitted to a set of programs (with abstractions, or naive).

Example:
    >>> import random
    >>> from shapeprog.coder.lang import parse, to_text
    >>> p = parse("Move(Cuboid(0.1,0.5,0.1),-0.4,0.2,0.1)")
    >>> to_text(perturb(p, 0.0, random.Random(0))) == to_text(p)
    True
    >>> free_numbers(p)
    6
"""
from __future__ import annotations

import math
import random
from collections import Counter
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from ..vae.genmetrics import classifier_features, frechet_distance
from .execute import ExecutionError, corners, execute
from .lang import Call, Expr, Library, Num, ProgramError, to_text, walk
from .proposal import pieces
from .search import union

__all__ = ["MIN_DIM", "PieceSampler", "execute_corners", "free_numbers", "noisy", "perturb", "perturbation_fd",
           "shape_features", "template"]

#: The smallest dimension of a noisy primitive (the data's precision).
MIN_DIM = 0.01


def _map_nums(expr: Expr, fn) -> Expr:
    if isinstance(expr, Num):
        return Num(fn(expr.value))
    if isinstance(expr, Call):
        return Call(expr.fn, tuple(_map_nums(a, fn) for a in expr.args))
    return expr


def free_numbers(expr: Expr) -> int:
    """The float literals of a program (its free numbers)."""
    return sum(1 for n in walk(expr) if isinstance(n, Num))


def perturb(expr: Expr, sigma: float, rng: random.Random) -> Expr:
    """``expr`` with ``sigma * N(0, 1)`` added to each float literal (in tree order, drawn from ``rng``)."""
    if not (isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"sigma must be a finite number >= 0, got {sigma!r}")
    return _map_nums(expr, lambda v: v + sigma * rng.gauss(0.0, 1.0) if sigma else v)


def execute_corners(expr: Expr, library: Library, strict: bool = True):
    """The ``(P, 8, 3)`` corners of a program's primitives (each dimension's magnitude, at least
    :data:`MIN_DIM`: noise can flip a dimension's sign, and the data has a few zero dimensions), or None when
    it does not execute (no part, an execution error, or with ``strict`` a hard error such as a reflected
    part on the wrong side of its plane)."""
    try:
        prims = execute(expr, library, strict=strict, orient=False)
    except (ExecutionError, ProgramError, ValueError, OverflowError, ZeroDivisionError):
        return None
    if not prims:
        return None
    return corners([tuple(max(abs(v), MIN_DIM) for v in p[:3]) + tuple(p[3:]) for p in prims])


def shape_features(corner_sets: Sequence, seed: int = 0) -> np.ndarray:
    """PointNet features of shapes given as corners (:func:`shapeprog.vae.genmetrics.classifier_features`:
    the generation tables' classifier, 2,500 surface points per shape from one generator seeded ``seed``)."""
    return classifier_features([torch.as_tensor(c, dtype=torch.float32) for c in corner_sets], seed=seed)


def perturbation_fd(programs: Sequence[Expr], library: Library, reference, sigmas: Sequence[float],
                    draws: int = 1, seed: int = 0) -> list:
    """``[(sigma, draw, FD, failed)]``: per sigma and draw, the Fréchet distance between the features of the
    executed perturbed ``programs`` and ``reference`` (features, or a ``(mu, cov)`` fit), and how many
    programs failed to execute (left out of that draw; hard errors are not failures here: a perturbed
    reflection that crosses its plane still makes a shape). Draw d of sigma s uses ``random.Random`` seeded with
    ``(seed, s, d)``, the same for every library, so two program sets of the same shapes get the same noise
    stream."""
    out = []
    for s in sigmas:
        for d in range(draws if s else 1):
            rng = random.Random(f"{seed}:{s!r}:{d}")
            got = [execute_corners(perturb(p, s, rng), library, strict=False) for p in programs]
            ok = [c for c in got if c is not None]
            if len(ok) < 2:
                raise ValueError(f"sigma {s}: fewer than 2 of {len(programs)} perturbed programs execute")
            out.append((float(s), d, frechet_distance(shape_features(ok, seed=seed), reference),
                        len(got) - len(ok)))
    return out


def noisy(prims: Sequence, sigma: float, rng: random.Random) -> tuple:
    """``prims`` (9-tuples) with ``sigma * N(0, 1)`` on each dimension and position (rotations kept), rounded to
    2 decimals, dimensions at least :data:`MIN_DIM`."""
    if not (isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"sigma must be a finite number >= 0, got {sigma!r}")
    out = []
    for p in prims:
        q = list(p)
        for j in range(6):
            v = round(q[j] + (sigma * rng.gauss(0.0, 1.0) if sigma else 0.0), 2) + 0.0
            q[j] = max(v, MIN_DIM) if j < 3 else v
        out.append(tuple(q))
    return tuple(out)


def template(piece: Expr) -> tuple:
    """``(key, values)``: a piece's text with every float literal as ``#`` and the literals in tree order."""
    values = [n.value for n in walk(piece) if isinstance(n, Num)]
    key = to_text(_map_nums(piece, lambda v: 0.0)).replace("0.0", "#")
    return key, values


@dataclass
class PieceSampler:
    """A generative model over programs (see the module docstring), fitted by :meth:`fit`.

    Attributes:
        counts: how many programs had k top-level pieces.
        templates: per template key, a representative piece and the ``(n, slots)`` values seen.
    """

    counts: Counter
    templates: dict

    @classmethod
    def fit(cls, programs: Sequence[Expr]) -> "PieceSampler":
        counts, templates = Counter(), {}
        for p in programs:
            ps = pieces(p)
            counts[len(ps)] += 1
            for piece in ps:
                key, values = template(piece)
                templates.setdefault(key, [piece, []])[1].append(values)
        if not counts:
            raise ValueError("no programs to fit")
        return cls(counts, {k: (piece, np.asarray(v, dtype=np.float64).reshape(len(v), -1))
                            for k, (piece, v) in templates.items()})

    def sample(self, rng: random.Random) -> Expr:
        """One program: k pieces (k by its frequency), each template by its frequency, its numbers from
        a Gaussian per slot (the slot's mean and standard deviation over the fitted pieces)."""
        ks, kw = zip(*sorted(self.counts.items()))
        k = rng.choices(ks, kw)[0]
        keys = sorted(self.templates)
        weights = [len(self.templates[t][1]) for t in keys]
        out = []
        for t in rng.choices(keys, weights, k=k):
            piece, values = self.templates[t]
            mu, sd = values.mean(0), values.std(0)
            draw = iter([float(m + s * rng.gauss(0.0, 1.0)) for m, s in zip(mu, sd)])
            out.append(_map_nums(piece, lambda v: next(draw)))
        return union(out)
