"""The ShapeMOD paper's experiments (listed by ``python -m shapeprog paper --list``, :mod:`shapeprog.paper`).

Each entry names the commands that rebuild its table and the result file they write (:mod:`shapeio.experiments`).
"""
from __future__ import annotations

from shapeio.experiments import Experiment, Step  # noqa: F401  (Step: the entries' commands)

__all__ = ["EXPERIMENTS", "RESULTS"]

#: Where the full runs write their result files (shown in docs/shapemod.md).
RESULTS = "docs/results/shapemod"
CATEGORIES = ("chair", "table", "storage")
#: The point clouds Table 3 reads: the first 50 shapes of each category's train and val splits (the val ones
#: are the test clouds), made once.
CLOUDS = "data/shapemod_clouds"
_CLOUDS = tuple(Step.of(f"pointcloud make-clouds --category {c} --limit 50 --workers 2 --quiet --out {CLOUDS}",
                        result=False, creates=f"{CLOUDS}/{c}_split.json") for c in CATEGORIES)
_CLOUD_ARGS = " ".join(f"--clouds {c}={CLOUDS}" for c in CATEGORIES)

_S65_NOTE = ("ShapeMOD rows: each category's own library discovered at this scale, not the shipped one; "
             "cross-category: one library over the three categories' shapes, the same settings. The paper gives "
             "only its cross-category library's size (12 macros).")


def _macros(words: str, result: bool = True, creates: str | None = None) -> Step:
    """A ``macros`` command (its words after ``macros``), quiet, writing the result file unless ``result`` is False."""
    return Step.of(f"macros {words} --quiet", result, creates)


def _experiment(eid: str, title: str, result: str, full: str, quick: str, before: tuple[Step, ...] = (),
                **kwargs) -> Experiment:
    """A done experiment of one ``macros`` command (``full``; ``quick`` its small variant, both after the
    ``before`` steps) writing ``RESULTS/result``."""
    return Experiment(eid, "done", title, result=f"{RESULTS}/{result}", steps=(*before, _macros(full)),
                      quick=(*before, _macros(quick)), **kwargs)


def _cross_steps(root: str, limit: int, rounds: int, steps: int) -> tuple[Step, ...]:
    """Discover one library over the three categories and one per category (same scale, same shapes), then
    Table 1 of each category with its own library (the ShapeMOD row) and the cross-category one."""
    # Table 1's shapes: compression of the corpus, as the paper
    common = f"--split all --limit {limit} --rounds {rounds} --proposal-steps {steps} --workers 2"
    found = [_macros(f"discover --category {' '.join(CATEGORIES)} {common} --out {root}/cross", False,
                     f"{root}/cross/library.txt")]
    found += [_macros(f"discover --category {c} {common} --out {root}/{c}", False, f"{root}/{c}/library.txt")
              for c in CATEGORIES]
    libs = " ".join(f"--library {c}={root}/{c}/library.txt" for c in CATEGORIES)
    table = _macros(f"tables --category {' '.join(CATEGORIES)} --limit {limit} {libs} "
                    f"--extra cross-category={root}/cross/library.txt --workers 2")
    return (*found, Step((*table.argv, "--note", _S65_NOTE)))


EXPERIMENTS: tuple[Experiment, ...] = (
    _experiment(
        "mod-t1", "Table 1: f per shape (absolute and over the same run's No Macros), |L|, fn, d, b of "
                "No Macros, Baseline macros and ShapeMOD",
        "table1.json",
        f"tables --category {' '.join(CATEGORIES)} --limit 200 --workers 2",
        "tables --category chair --limit 30",
        scale="200 random shapes per category, all their sub-programs (the paper: every shape)"),
    _experiment(
        "mod-t2", "Table 2: generation by the VAEs over No Macros, Baseline Macros and ShapeMOD programs "
                          "(chair), beside ShapeMOD Table 2's rows",
        "table2_generation_chair.json",
        "generation --category chair -n 100 --workers 2",
        "generation --category chair -n 20 --no-stability --fool-epochs 4 --no-ground-truth",
        scale="chair (the specification gives the paper's rows for chair only), 100 samples per model, % fool "
              "classifier 12 epochs (the paper: 1,000 samples, 300 epochs)"),
    _experiment(
        "mod-t3", "Table 3: point cloud to program by the end-to-end models without and with macros",
        "table3_pointcloud.json",
        f"pointcloud {_CLOUD_ARGS} --limit 50 --workers 2",
        f"pointcloud --clouds chair={CLOUDS} --limit 5 --no-stability",
        before=_CLOUDS,
        scale="the first 50 test shapes per category, one decode each (the paper: its whole test split)"),
    _experiment(
        "mod-t5", "Table 5: discovery ablations (no P_matches-dist weighting, no beam, no bad-order filter, "
                "no generalize, no valid-macro criteria) against the full method, f per sub-program",
        "table5_ablation_chair.json",
        "ablation --category chair --limit 100 --rounds 2 --proposal-steps 1000 --workers 2",
        "ablation --category chair --limit 40 --rounds 1 --proposal-steps 100",
        scale="100 random chairs, 2 rounds of 1,000 proposal steps per variant (the paper: all chairs, 5 rounds "
              "of 10,000); the variants' paper figures are not in the spec"),
    _experiment(
        "mod-f7", "Figure 7: FD to the val split of perturbed programs without and with macros, per sigma",
        "fig7_perturbation_chair.json",
        "perturbation --category chair --n 500 --repeats 3 --png docs/figures/shapemod_perturbation.png",
        "perturbation --category chair --n 50 --repeats 1 --sigmas 0 0.05 0.1",
        scale="chair: 500 train shapes, 7 sigmas, 3 noise draws each (the paper: a plot, its sample not in the "
              "spec); table and storage not run"),
    Experiment(
        "mod-s65", "done", "Section 6.5: one library discovered over chair, table and storage programs, applied "
                           "per category beside per-category libraries discovered the same way",
        result=f"{RESULTS}/s65_cross_category.json",
        steps=_cross_steps("runs/shapemod_s65", 100, 2, 1000),
        quick=_cross_steps("runs/shapemod_s65_quick", 15, 1, 50),
        scale="100 random shapes per category, 2 rounds of 1,000 proposal steps for every library (the paper: "
              "all shapes, 5 rounds of 10,000); the paper reports the cross-category library's size only "
              "(12 macros)"),
)
