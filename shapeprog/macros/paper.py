"""The ShapeMOD paper's experiments (listed by ``python -m shapeprog paper --list``, :mod:`shapeprog.paper`).

Each entry names the commands that rebuild its table and the result file they write (:mod:`shapeio.experiments`).
"""
from __future__ import annotations

from shapeio.experiments import Experiment, Step  # noqa: F401  (Step: the entries' commands)

__all__ = ["EXPERIMENTS"]

EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("mod-t1", "not-built", "Table 1: the objective f, |L|, fn, d, b of No Macros, Baseline macros and ShapeMOD",
               why="no command writes its result file yet"),
    Experiment("mod-t2", "not-built", "Table 2: generation with macros (No Macros, Baseline Macros, ShapeMOD)",
               why="no command writes its result file yet"),
    Experiment("mod-t3", "not-built", "Table 3: point cloud to program with and without macros",
               why="no command writes its result file yet"),
    Experiment("mod-t5", "not-built", "Table 5: ablations of the discovery",
               why="no command writes its result file yet"),
    Experiment("mod-f7", "not-built", "Figure 7: FD of perturbed programs with and without macros",
               why="no command writes its result file yet"),
    Experiment("mod-s65", "not-built", "Section 6.5: one library discovered across categories",
               why="no command writes its result file yet"),
)
