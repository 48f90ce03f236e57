"""The ShapeAssembly paper's experiments (listed by ``python -m shapeprog paper --list``, :mod:`shapeprog.paper`).

Each entry names the commands that rebuild its table and the result file they write (:mod:`shapeio.experiments`).
"""
from __future__ import annotations

from shapeio.experiments import Experiment, Step  # noqa: F401  (Step: the entries' commands)

__all__ = ["EXPERIMENTS"]

EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("sa-t2", "not-built", "Table 2: generation (rooted, stable, fool, FD) of 1,000 samples per category, and its decoding ablations",
               why="no command writes its result file yet"),
    Experiment("sa-t3", "not-built", "Table 3: editability (lines per program, share of macro lines)",
               why="no command writes its result file yet"),
    Experiment("sa-t4", "not-built", "Table 4: generalization, coverage and variety of samples",
               why="no command writes its result file yet"),
    Experiment("sa-t5", "not-built", "Table 5: leaf parts per sample",
               why="no command writes its result file yet"),
    Experiment("sa-t6", "not-built", "Table 6: interpolation smoothness (geometric and program steps)",
               why="no command writes its result file yet"),
    Experiment("sa-t7", "not-built", "Table 7: point cloud to program on the chair val split (latent projection, optimised program, cuboids)",
               why="no command writes its result file yet"),
    Experiment("sa-novelty", "not-built", "Section 7.1.3: structural novelty of samples against the training split",
               why="no command writes its result file yet"),
)
