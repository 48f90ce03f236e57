"""The experiments of the ShapeAssembly, ShapeMOD and ShapeCoder papers: one list, one command.

``python -m shapeprog paper --list`` prints one line per experiment (``ID STATUS description``);
``python -m shapeprog paper run ID [--quick]`` runs one (:mod:`shapeio.experiments`). Each system keeps its
entries beside its code (:mod:`shapeprog.vae.paper`, :mod:`shapeprog.macros.paper`, :mod:`shapeprog.coder.paper`);
this module only joins them, so listing them imports no model code.
"""
from __future__ import annotations

from .coder.paper import EXPERIMENTS as CODER
from .macros.paper import EXPERIMENTS as MACROS
from .vae.paper import EXPERIMENTS as ASSEMBLY

__all__ = ["EXPERIMENTS"]

EXPERIMENTS = (*ASSEMBLY, *MACROS, *CODER)
