"""The ShapeCoder paper's experiments (listed by ``python -m shapeprog paper --list``, :mod:`shapeprog.paper`).

Each entry names the commands that rebuild its table and the result file they write (:mod:`shapeio.experiments`).
"""
from __future__ import annotations

from shapeio.experiments import Experiment, Step  # noqa: F401  (Step: the entries' commands)

__all__ = ["EXPERIMENTS"]

EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("coder-t2", "not-built", "Table 2: F, |L|, structural and parametric terms of the discovered libraries",
               why="no command writes its result file yet"),
    Experiment("coder-t3", "not-built", "Table 3: post hoc inference with a discovered library on training and held-out shapes",
               why="no command writes its result file yet"),
    Experiment("coder-t4-left", "not-built", "Table 4 left: ablations of the discovery",
               why="no command writes its result file yet"),
    Experiment("coder-t4-right", "not-built", "Table 4 right: FD of perturbed programs with and without abstractions",
               why="no command writes its result file yet"),
    Experiment("coder-s75", "not-built", "Section 7.5: abstractions from noisy primitive input",
               why="no command writes its result file yet"),
    Experiment("coder-s76", "not-built", "Section 7.6: a generative model over programs with abstractions",
               why="no command writes its result file yet"),
)
