"""The ShapeAssembly AST: the statements (:class:`Cuboid`, :class:`Attach`, :class:`Squeeze`,
:class:`Reflect`, :class:`Translate`), :class:`Block` and :class:`Program`, frozen dataclasses, and the
names of faces and axes. Standard library only. :mod:`shapeprog.lang` parses and prints them and exports
every name of this module.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Union

__all__ = [
    "AXES",
    "CORPUS_DECIMALS",
    "FACES",
    "NUM_FIELDS",
    "Attach",
    "Block",
    "Cuboid",
    "Program",
    "Reflect",
    "Squeeze",
    "Statement",
    "Translate",
]


#: Decimals of the corpus's numbers: programs the package writes (VAE samples, fits) are rounded to them.
CORPUS_DECIMALS = 3

#: Face names; index k of the local axis they are normal to is FACE_AXIS[face].
FACES = ("right", "left", "top", "bot", "front", "back")
AXES = ("X", "Y", "Z")


# ----------------------------------------------------------------------------- AST


@dataclass(frozen=True, slots=True)
class Cuboid:
    """``name = Cuboid(l, h, w, aligned)``; extents along local x, y (up), z."""

    name: str
    l: float
    h: float
    w: float
    aligned: bool


@dataclass(frozen=True, slots=True)
class Attach:
    """``attach(a, b, x1, y1, z1, x2, y2, z2)``: move ``a`` so that its local point
    (x1, y1, z1) meets the local point (x2, y2, z2) of ``b``."""

    a: str
    b: str
    x1: float
    y1: float
    z1: float
    x2: float
    y2: float
    z2: float


@dataclass(frozen=True, slots=True)
class Squeeze:
    """``squeeze(a, b, c, face, u, v)``: place ``a`` between ``b`` (on side ``face``)
    and ``c`` (opposite side); (u, v) are the free coordinates in increasing axis order."""

    a: str
    b: str
    c: str
    face: str
    u: float
    v: float


@dataclass(frozen=True, slots=True)
class Reflect:
    """``reflect(a, axis)``: a mirrored copy of ``a`` through the bbox's centre plane."""

    a: str
    axis: str


@dataclass(frozen=True, slots=True)
class Translate:
    """``translate(a, axis, n, d)``: ``n`` copies of ``a``, the last one ``d`` (a fraction
    of the bbox extent along ``axis``) away from ``a``."""

    a: str
    axis: str
    n: int
    d: float


Statement = Union[Cuboid, Attach, Squeeze, Reflect, Translate]

#: The continuous number fields of each statement type, in text order: the order of
#: :func:`numbers`, :func:`replace_numbers` and the executor's parameter vector.
NUM_FIELDS = {
    Cuboid: ("l", "h", "w"),
    Attach: ("x1", "y1", "z1", "x2", "y2", "z2"),
    Squeeze: ("u", "v"),
    Reflect: (),
    Translate: ("d",),
}


@dataclass(frozen=True, slots=True)
class Block:
    """``Assembly <name> { statements }``; ``statements[0]`` is ``bbox = Cuboid(...)``."""

    name: str
    statements: tuple[Statement, ...]

    @property
    def bbox(self) -> Cuboid:
        return self.statements[0]  # type: ignore[return-value]

    def cuboids(self) -> list[Cuboid]:
        return [s for s in self.statements if isinstance(s, Cuboid)]


@dataclass(frozen=True, slots=True, weakref_slot=True)  # the editor caches per program by weak reference
class Program:
    """A ShapeAssembly program: blocks in breadth-first (file) order, root first.

    ``flat`` is True for the single-block format without the ``Assembly`` wrapper.
    """

    blocks: tuple[Block, ...]
    flat: bool = False

    @property
    def root(self) -> Block:
        return self.blocks[0]

    def block(self, name: str) -> Block:
        """The block called ``name`` (e.g. ``"Program_2"``); KeyError if absent."""
        for b in self.blocks:
            if b.name == name:
                return b
        raise KeyError(name)

    def children(self, block: Block) -> list[Block | None]:
        """One entry per Cuboid line of ``block`` (bbox first): the sub-program block or None."""
        names = {b.name: b for b in self.blocks}
        return [names.get(c.name) if c.name.startswith("Program_") else None for c in block.cuboids()]

    def __repr__(self) -> str:
        """One line: the blocks, statements and cuboids (``to_text(program)`` prints the program)."""
        n_stmts = sum(len(b.statements) for b in self.blocks)
        n_cubes = sum(len(b.cuboids()) - 1 for b in self.blocks)
        kind = "flat" if self.flat else "corpus"
        return (f"<Program ({kind} format): {len(self.blocks)} block{'s' * (len(self.blocks) != 1)}, "
                f"{n_stmts} statements, {n_cubes} cuboids besides the bboxes; print with shapeprog.to_text>")
