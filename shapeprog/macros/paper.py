"""The ShapeMOD paper's experiments (listed by ``python -m shapeprog paper --list``, :mod:`shapeprog.paper`).

Each entry names the commands that rebuild its table and the result file they write (:mod:`shapeio.experiments`).
"""
from __future__ import annotations

from shapeio.experiments import Experiment, Step  # noqa: F401  (Step: the entries' commands)

__all__ = ["EXPERIMENTS", "RESULTS"]

#: Where the full runs write their result files (shown in docs/shapemod.md).
RESULTS = "docs/results/shapemod"
CATEGORIES = ("chair", "table", "storage")

EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment(
        "mod-t1", "done", "Table 1: f per shape (absolute and over the same run's No Macros), |L|, fn, d, b of "
                          "No Macros, Baseline macros and ShapeMOD",
        result=f"{RESULTS}/table1.json",
        steps=(Step(("macros", "tables", "--category", *CATEGORIES, "--limit", "200", "--workers", "2", "--quiet",
                     "--overwrite", "--json", "{out}")),),
        quick=(Step(("macros", "tables", "--category", "chair", "--limit", "30", "--quiet", "--overwrite",
                     "--json", "{out}")),),
        scale="200 random shapes per category, all their sub-programs (the paper: every shape)"),
    Experiment("mod-t2", "not-built", "Table 2: generation with macros (No Macros, Baseline Macros, ShapeMOD)",
               why="no command writes its result file yet"),
    Experiment("mod-t3", "not-built", "Table 3: point cloud to program with and without macros",
               why="no command writes its result file yet"),
    Experiment(
        "mod-t5", "done", "Table 5: discovery ablations (no P_matches-dist weighting, no beam, no bad-order filter, "
                          "no generalize, no valid-macro criteria) against the full method, f per sub-program",
        result=f"{RESULTS}/table5_ablation_chair.json",
        steps=(Step(("macros", "ablation", "--category", "chair", "--limit", "100", "--rounds", "2",
                     "--proposal-steps", "1000", "--workers", "2", "--quiet", "--overwrite", "--json", "{out}")),),
        quick=(Step(("macros", "ablation", "--category", "chair", "--limit", "40", "--rounds", "1",
                     "--proposal-steps", "100", "--quiet", "--overwrite", "--json", "{out}")),),
        scale="100 random chairs, 2 rounds of 1,000 proposal steps per variant (the paper: all chairs, 5 rounds "
              "of 10,000); the variants' paper figures are not in the spec"),
    Experiment(
        "mod-f7", "done", "Figure 7: FD to the val split of perturbed programs without and with macros, per sigma",
        result=f"{RESULTS}/fig7_perturbation_chair.json",
        steps=(Step(("macros", "perturbation", "--category", "chair", "--n", "500", "--repeats", "3", "--png",
                     "docs/figures/shapemod_perturbation.png", "--quiet", "--overwrite", "--json", "{out}")),),
        quick=(Step(("macros", "perturbation", "--category", "chair", "--n", "50", "--repeats", "1", "--sigmas",
                     "0", "0.05", "0.1", "--quiet", "--overwrite", "--json", "{out}")),),
        scale="chair: 500 train shapes, 7 sigmas, 3 noise draws each (the paper: a plot, its sample not in the "
              "spec); table and storage not run"),
    Experiment("mod-s65", "not-built", "Section 6.5: one library discovered across categories",
               why="no command writes its result file yet"),
)
