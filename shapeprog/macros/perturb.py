"""Parameter perturbation of hierarchical macro programs (the ShapeMOD paper's Fig. 7 protocol).

A program's *continuous parameters* are its free float parameters
(:func:`shapeprog.macros.execute.hierarchy_parameters`) less those of every block's bbox line (the given
frame of a sub-program, not a call) and less those that set a translate count (a whole number,
structure). A base program (the :class:`~shapeprog.macros.Library` without macros, i.e. ShapeAssembly's
own lines) exposes every float of its lines; a macro program only its macro calls' free floats, which the
macros map (affinely) to several executor numbers. :func:`perturb` adds ``sigma * N(0, 1)`` to each
continuous parameter, maps the parameters to the executor's numbers and keeps those in the language's
ranges (:data:`MIN_DIM`; attach, squeeze and translate coordinates in [0, 1]), then executes.

Decisions where the paper is silent (``docs/shapemod.md``, "Perturbation study"): absolute noise in the
programs' units (PartNet's unit-height shapes), the bbox lines and translate counts are fixed, the
clamping is done on the executor's numbers so that both kinds of program are clamped alike.

Example:
    >>> import numpy as np
    >>> from shapeprog.macros import hierarchy
    >>> h = hierarchy.parse("# Program_0\\nbbox = Cuboid(1.0, 1.0, 1.0, True)\\n"
    ...                     "c = Cuboid(0.5, 0.2, 0.5, True)\\nattach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n\\n")
    >>> pp = PerturbablePrograms([h])
    >>> pp.n_continuous
    [9]
    >>> shapes = pp.perturb(0.0, np.random.default_rng(0))
    >>> shapes[0].shape
    torch.Size([1, 8, 3])
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ..execute import ExecutionPlan
from .execute import _N_NUMBERS, compile_hierarchy, hierarchy_parameters
from .grammar import TranslateLine
from .lang import parameters
from .library import Library

__all__ = ["COORD_RANGE", "MIN_DIM", "PerturbablePrograms", "continuous_mask"]

#: Smallest cuboid dimension after perturbation (a perturbed dim below it is raised to it).
MIN_DIM = 0.01
#: The range of attach points, squeeze coordinates and translate distances (bounding-box fractions).
COORD_RANGE = (0.0, 1.0)


def continuous_mask(h, library: Library | None = None) -> np.ndarray:
    """``(P,) bool``: which free parameters of hierarchical macro program ``h`` are continuous (module
    docstring): not a block's bbox floats, not feeding a translate count."""
    masks = []

    for p in h.programs:
        lib = (Library() if library is None else library).with_program(p)
        exp = lib.expand(p)
        m = np.ones(len(parameters(p)), dtype=bool)
        m[:3] = False  # the bbox line's dims come first
        for line, forms in zip(exp.lines, exp.floats):
            if type(line) is TranslateLine:
                for i, _ in forms[0].terms:
                    m[i] = False
        masks.append(m)
    return np.concatenate(masks) if masks else np.zeros(0, dtype=bool)


class PerturbablePrograms:
    """Hierarchical macro programs compiled once for perturbed execution.

    Args:
        programs: :class:`~shapeprog.macros.hierarchy.MacroHierarchy` objects (each block carrying its
            definitions, as :func:`shapeprog.macros.refactor` writes them).
        library: functions the blocks call without defining them.

    Attributes:
        n_continuous: the number of continuous parameters of each program.
    """

    def __init__(self, programs: Sequence, library: Library | None = None):
        self.compiled = [compile_hierarchy(h, library) for h in programs]
        self.params = [hierarchy_parameters(h, torch.float64) for h in programs]
        self.masks = [torch.from_numpy(continuous_mask(h, library)) for h in programs]
        self.n_continuous = [int(m.sum()) for m in self.masks]
        self.low, self.high = [], []
        for c in self.compiled:
            lo, hi = [], []
            for block in c.program.blocks:
                for st in block.statements:
                    kind = type(st).__name__
                    n = _N_NUMBERS[kind]
                    if kind == "Cuboid":
                        lo += [MIN_DIM] * n
                        hi += [float("inf")] * n
                    else:
                        lo += [COORD_RANGE[0]] * n
                        hi += [COORD_RANGE[1]] * n
            self.low.append(torch.tensor(lo, dtype=torch.float64))
            self.high.append(torch.tensor(hi, dtype=torch.float64))
        self.plan = ExecutionPlan([c.program for c in self.compiled], torch.float32)

    def __len__(self) -> int:
        return len(self.compiled)

    def numbers(self, sigma: float, rng: np.random.Generator) -> list[torch.Tensor]:
        """Per program, the executor's numbers ``(S,) float64`` after adding ``sigma * N(0, 1)`` to every
        continuous parameter (one draw per parameter from ``rng``, programs in order) and clamping.
        A number is clamped only when the noise moved it (an unperturbed one stays as the program has it)."""
        if not sigma >= 0:
            raise ValueError(f"`sigma` must be >= 0, got {sigma}")
        out = []
        for c, x, m, lo, hi in zip(self.compiled, self.params, self.masks, self.low, self.high):
            noise = torch.from_numpy(rng.standard_normal(int(m.sum())))
            y = x.clone()
            y[m] += sigma * noise
            base = c.numbers(x)
            num = c.numbers(y)
            moved = num != base
            num = torch.where(moved, torch.minimum(torch.maximum(num, lo), hi), num)
            out.append(num)
        return out

    def perturb(self, sigma: float, rng: np.random.Generator) -> list[torch.Tensor]:
        """The leaf corners ``(L, 8, 3) float32`` of every program, its continuous parameters perturbed
        (:meth:`numbers`)."""
        nums = self.numbers(sigma, rng)
        with torch.no_grad():
            shapes = self.plan.run([n.float() for n in nums])
        return [s.corners.detach() for s in shapes]
