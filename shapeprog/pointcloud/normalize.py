"""The canonical frame of point clouds, and the way back to an input's own frame.

A cloud in any position, scale and up direction is mapped into the frame the training clouds are in
(:func:`normalize`), and everything computed there (points, executed cuboids, programs) is mapped back
with the returned :class:`Transform`.

**The rule.** Rotate the input so that its ``up`` axis becomes +y (ShapeAssembly's world is y-up),
then move the centre of its axis-aligned bounding box (AABB) to the origin and scale uniformly so that
the AABB's diagonal is :data:`CANONICAL_DIAGONAL` (2.0). Corpus shapes already sit almost there: the
root bbox is centred at the origin (the AABB centre of the executed leaves is off by 0.005 on
average) and their diagonals have a median of 2.04 (chair), 1.98 (table), 2.04 (storage), so a
typical corpus shape is scaled by 0.85 to 1.1. The AABB is used, not the largest distance from the
centre, because a subsampled surface cloud still reaches the AABB's faces while it misses the
corners that decide the largest distance.

**Programs.** Scaling every ``Cuboid``'s three dims by ``k`` scales the executed shape by ``k``
about the origin (attach, squeeze, reflect and translate arguments are relative to the cuboids), so a
uniform scale is written into the program text (:func:`scale_program`). A translation or a rotation
cannot be written in ShapeAssembly (the root bbox is always at the origin, y up, and the language has
no comments), so a program mapped back to an input's frame (:meth:`Transform.program_to_input`) is the
text at the input's scale plus two numbers kept beside it: ``offset`` (:attr:`Transform.center`) and
``rotation`` (:attr:`Transform.rotation`); the input-frame points are ``p @ rotation + offset`` for
the points ``p`` of the executed text (:meth:`Transform.place`). See ``docs/pointcloud.md``.

Example:
    >>> import numpy as np
    >>> pts = np.array([[0.0, 0.0, 0.0], [4.0, 3.0, 0.0], [2.0, 1.0, 0.0]])
    >>> unit, t = normalize(pts)
    >>> unit.round(6).tolist(), t.center, t.scale
    ([[-0.8, -0.6, 0.0], [0.8, 0.6, 0.0], [0.0, -0.2, 0.0]], (2.0, 1.5, 0.0), 0.4)
    >>> np.allclose(t.invert(unit), pts)
    True
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np
import torch

from ..execute import execute
from ..lang import Cuboid, Program

__all__ = ["CANONICAL_DIAGONAL", "UP_AXES", "Transform", "align_program", "normalize", "scale_program"]

#: The AABB diagonal of a cloud in the canonical frame (the corpus median is 2.0).
CANONICAL_DIAGONAL = 2.0

#: Rotation taking an input whose up direction is the key to the y-up canonical frame:
#: ``canonical = rotation @ input`` (proper rotations, determinant +1).
_ROTATIONS = {
    "y": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "z": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),    # z-up: (x, y, z) -> (x, z, -y)
    "x": ((0, -1, 0), (1, 0, 0), (0, 0, 1)),    # x-up: (x, y, z) -> (-y, x, z)
    "-y": ((1, 0, 0), (0, -1, 0), (0, 0, -1)),
    "-z": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
    "-x": ((0, 1, 0), (-1, 0, 0), (0, 0, 1)),
}
#: The ``up`` values :func:`normalize` accepts.
UP_AXES = tuple(_ROTATIONS)


def _check_up(up: str) -> str:
    if up not in _ROTATIONS:
        raise ValueError(f"`up` must be one of {', '.join(map(repr, UP_AXES))}, got {up!r}")
    return up


@dataclass(frozen=True)
class Transform:
    """The map from an input's frame to the canonical frame: ``canonical = rotation @ (x - center) * scale``.

    Attributes:
        center: the input-frame point (the AABB centre) that goes to the origin.
        scale: the uniform factor, ``CANONICAL_DIAGONAL / diagonal`` of the input's AABB.
        up: the input's up axis (``"y"``, ``"z"``, ``"x"`` or a negated one); see :data:`UP_AXES`.
    """

    center: tuple[float, float, float]
    scale: float
    up: str = "y"

    def __post_init__(self):
        _check_up(self.up)
        c = tuple(float(v) for v in self.center)
        if len(c) != 3 or not all(map(math.isfinite, c)):
            raise ValueError(f"`center` must be 3 finite numbers, got {self.center!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"`scale` must be a finite positive number, got {self.scale!r}")
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "scale", float(self.scale))

    @property
    def rotation(self) -> np.ndarray:
        """``(3, 3) float64``, canonical = rotation @ input (the identity for a y-up input)."""
        return np.array(_ROTATIONS[self.up], dtype=np.float64)

    def _arrays(self, x):
        if isinstance(x, torch.Tensor):
            dt = x.dtype if x.is_floating_point() else torch.float32
            return (torch.as_tensor(self.center, dtype=dt, device=x.device),
                    torch.as_tensor(self.rotation, dtype=dt, device=x.device), x.to(dt))
        x = np.asarray(x)
        dt = x.dtype if np.issubdtype(x.dtype, np.floating) else np.float64
        return np.asarray(self.center, dtype=dt), self.rotation.astype(dt), x.astype(dt, copy=False)

    @staticmethod
    def _check(x) -> None:
        if tuple(x.shape[-1:]) != (3,):
            raise ValueError(f"points must have shape (..., 3), got {tuple(x.shape)}")

    def apply(self, points):
        """Input frame -> canonical frame.

        Args:
            points: ``(..., 3) float``, a NumPy array or a torch tensor.

        Returns:
            The same type, shape and (floating) dtype.
        """
        self._check(points)
        c, r, x = self._arrays(points)
        return ((x - c) @ r.T) * self.scale

    def invert(self, points):
        """Canonical frame -> input frame (the inverse of :meth:`apply`); ``(..., 3)`` as there."""
        self._check(points)
        c, r, x = self._arrays(points)
        return (x / self.scale) @ r + c

    def place(self, points):
        """Points of a program text written by :meth:`program_to_input` (already at the input's scale)
        -> input frame: ``points @ rotation + center``."""
        self._check(points)
        c, r, x = self._arrays(points)
        return x @ r + c

    def program_to_input(self, program: Program) -> Program:
        """``program`` (canonical frame) at the input's scale: every Cuboid's dims divided by ``scale``.

        The result still executes y-up and centred at the origin; :meth:`place` (``offset`` =
        :attr:`center`, :attr:`rotation`) puts its points in the input's frame.
        """
        return scale_program(program, 1.0 / self.scale)

    def program_to_canonical(self, program: Program) -> Program:
        """The inverse of :meth:`program_to_input`: every Cuboid's dims times ``scale``."""
        return scale_program(program, self.scale)

    def to_dict(self) -> dict:
        """A JSON-able record: ``{"center": [x, y, z], "scale": s, "up": "y", "rotation": 3x3 rows}``.

        ``rotation`` is written for readers of the file; :meth:`from_dict` recomputes it from ``up``.
        """
        return {"center": list(self.center), "scale": self.scale, "up": self.up,
                "rotation": self.rotation.tolist()}

    @classmethod
    def from_dict(cls, d: Mapping) -> "Transform":
        """The transform of a :meth:`to_dict` record."""
        try:
            return cls(tuple(d["center"]), float(d["scale"]), str(d.get("up", "y")))
        except (KeyError, TypeError) as e:
            raise ValueError(f"not a Transform record ({type(e).__name__}: {e}): {d!r}") from None


def normalize(points, up: str = "y", diagonal: float = CANONICAL_DIAGONAL):
    """Map a cloud into the canonical frame (see the module docstring for the rule).

    Args:
        points: ``(N, 3) float``, NumPy or torch, in any position and scale.
        up: the input's up axis, one of :data:`UP_AXES` (``"z"`` for z-up scans).
        diagonal: the AABB diagonal in the canonical frame.

    Returns:
        ``(normalised points, Transform)``; the points have the input's type and floating dtype.

    Raises:
        ValueError: a shape other than ``(N, 3)`` with ``N >= 1``, a NaN or infinite coordinate, or
            all points at one place (zero diagonal).
    """
    _check_up(up)
    shape = tuple(points.shape)
    if len(shape) != 2 or shape[1] != 3 or shape[0] < 1:
        raise ValueError(f"`points` must have shape (N, 3) with N >= 1, got {shape}")
    x = points.detach().cpu().double().numpy() if isinstance(points, torch.Tensor) else np.asarray(points, np.float64)
    if not np.isfinite(x).all():
        raise ValueError("`points` contains NaN or infinite coordinates")
    if not (math.isfinite(diagonal) and diagonal > 0):
        raise ValueError(f"`diagonal` must be a finite positive number, got {diagonal!r}")
    lo, hi = x.min(0), x.max(0)
    diag = float(np.linalg.norm(hi - lo))
    if not diag > 0:
        raise ValueError(f"all {shape[0]} points are at one place: the cloud has no extent to normalise")
    t = Transform(tuple((lo + hi) / 2), diagonal / diag, up)
    return t.apply(points), t


def scale_program(program: Program, factor: float) -> Program:
    """``program`` with every ``Cuboid``'s dims (sub-program bboxes included) times ``factor``.

    The executed shape is the original scaled by ``factor`` about the origin: attach, squeeze,
    reflect and translate arguments are relative to the cuboids and the bbox, so they stay. The
    exceptions are the executor's discrete decisions that float rounding or an absolute threshold
    (e.g. 1e-4 in the second attach rule) can flip: about 0.5 % of the corpus programs execute more
    than 1e-5 (relative) away from the scaled shape (``docs/pointcloud.md``, Normalisation).

    Args:
        program: a parsed program.
        factor: a finite positive number.

    Returns:
        A new :class:`~shapeprog.lang.Program` (numbers are printed with ``repr``; pass
        ``decimals`` to :func:`shapeprog.lang.to_text` to round them).
    """
    factor = float(factor)
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"`factor` must be a finite positive number, got {factor!r}")
    blocks = []
    for b in program.blocks:
        stmts = tuple(dataclasses.replace(s, l=s.l * factor, h=s.h * factor, w=s.w * factor)
                      if isinstance(s, Cuboid) else s for s in b.statements)
        blocks.append(dataclasses.replace(b, statements=stmts))
    return dataclasses.replace(program, blocks=tuple(blocks))


def _corners_of(program: Optional[Program]) -> torch.Tensor:
    if program is None:
        return torch.zeros(0, 8, 3)
    try:
        with torch.no_grad():
            return execute(program).corners
    except ValueError:
        return torch.zeros(0, 8, 3)


def align_program(program: Program, diagonal: float = CANONICAL_DIAGONAL) -> tuple[Program, np.ndarray]:
    """Scale ``program`` uniformly so that its executed cuboids' bounding box has ``diagonal``, and the offset
    ``(3,) float64`` that moves that box's centre to the origin (executed points + offset = aligned shape).

    Raises:
        ValueError: the program executes to no cuboid.
    """
    return _align_executed(program, _corners_of(program), diagonal)


def _align_executed(program: Program, corners: torch.Tensor,
                    diagonal: float = CANONICAL_DIAGONAL) -> tuple[Program, np.ndarray]:
    """:func:`align_program` given the program's executed corners ``(L, 8, 3)``."""
    c = corners.double()
    if len(c) == 0:
        raise ValueError("the program executes to no cuboid")
    flat = c.reshape(-1, 3)
    lo, hi = flat.min(0).values, flat.max(0).values
    diag = float((hi - lo).norm())
    if not diag > 0:
        raise ValueError("the program's cuboids have no extent")
    k = diagonal / diag
    return scale_program(program, k), (-(lo + hi) / 2 * k).numpy()
