"""The ShapeMOD paper's Table 3: point cloud to program by a model trained end to end, without macros (the
ShapeAssembly decoder) and with a ShapeMOD library (the macro decoder), on the same test clouds.

Each model decodes every test cloud of a ``make-clouds`` cache once (the protocol of
:func:`shapeprog.pointcloud.tables.evaluate`: noisy 2,048-point inputs in random scale and position, mapped
back and compared with the clean cloud): CD x1000, F-score at 0.03, % rooted, % stable of its ``model`` row
(no fitting: the paper's Table 3 measures the network's output). The evaluation's fitting rows are run with
:data:`FIT_STEPS_UNUSED` steps and not reported. The paper's rows (all categories in the specification) come
from :data:`shapeprog.pointcloud.tables.PAPER_TABLE3` and ``PAPER_TABLE3_MACROS``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Mapping, Sequence

__all__ = ["FIT_STEPS_UNUSED", "pointcloud_rows", "shipped_weights", "table3_result"]

#: Fitting steps given to the evaluation's optimisation rows, which Table 3 does not report.
FIT_STEPS_UNUSED = 1
_W = Path(__file__).resolve().parents[1] / "weights"


def shipped_weights(category: str) -> dict[str, str]:
    """The shipped end-to-end point-cloud models of ``category``: No Macros and ShapeMOD."""
    return {"No Macros": str(_W / f"pointcloud_e2e_{category}.pt"),
            "ShapeMOD": str(_W / f"pointcloud_e2e_{category}_macros.pt")}


def pointcloud_rows(clouds: Mapping[str, str], limit: int | None = None, seed: int = 0, stability: bool = True,
                    weights: Mapping[str, Mapping[str, str]] | None = None, executor=None,
                    log: Callable[[str], None] | None = None) -> list[dict]:
    """One row per category (``clouds``: category -> its ``make-clouds`` folder) and model: ``category``,
    ``method``, ``cd`` (x1000), ``fscore`` (%), ``rooted``, ``stable`` (%), ``shapes``, ``failed``, then the
    paper's two rows of the category."""
    from ..pointcloud.tables import PAPER_TABLE3, PAPER_TABLE3_MACROS, evaluate  # lazy: torch models on use

    rows = []
    for cat, root in clouds.items():
        for method, path in (weights or {}).get(cat, shipped_weights(cat)).items():
            r = evaluate(root, cat, weights=path, limit=limit, steps=FIT_STEPS_UNUSED, stability=stability,
                         retrieval=False, executor=executor, seed=seed)
            m = r.rows["model"]
            rows.append({"category": cat, "method": method, "cd": m["cd"], "fscore": m["fscore"],
                         "rooted": m["rooted"], "stable": m["stable"], "shapes": r.shapes,
                         "failed": r.failed.get("model", 0)})
            if log:
                log(f"{cat} {method}: CD {m['cd']:.1f}, F {m['fscore']:.1f} ({r.seconds:.0f} s)")
        for method, paper in (("No Macros", PAPER_TABLE3.get(cat)), ("ShapeMOD", PAPER_TABLE3_MACROS.get(cat))):
            if paper is not None:
                rows.append({"category": cat, "method": f"paper: {method}", "cd": paper[0], "fscore": paper[1],
                             "rooted": paper[2], "stable": paper[3], "shapes": None, "failed": None})
    return rows


def _discovery_note(categories: Sequence[str]) -> str:
    """Which split each category's shipped library was discovered on (its header), and what that means here."""
    from .api import library_split

    by_split: dict[str, list[str]] = {}
    for c in categories:
        by_split.setdefault(library_split(c) or "unrecorded", []).append(c)
    parts = []
    for split, cats in sorted(by_split.items(), key=lambda kv: kv[0] != "train"):
        names = (", ".join(cats[:-1]) + " and " if len(cats) > 1 else "") + cats[-1]
        names += " library was" if len(cats) == 1 else " libraries were"
        if split == "train":
            parts.append(f"the {names} discovered on the train split, without these test shapes")
        elif split == "unrecorded":
            parts.append(f"the {names} discovered on a split that the header does not record")
        else:
            parts.append(f"the {names} discovered on split {split}, so these test shapes took part in discovery")
    return "; ".join(parts) + " (shapeprog/macros/libs/README.md)"


def table3_result(rows: Sequence[dict], command: str, limit: int | None, seed: int) -> dict:
    """``rows`` (:func:`pointcloud_rows`) as a result file's content (:mod:`shapeio.results`)."""
    from shapeio.results import column, make_result  # lazy: loaded when a result is written

    cols = [column("category", "category"), column("method", "method"), column("cd", "CD x1000", 1),
            column("fscore", "F-score (%)", 1), column("rooted", "% rooted", 1), column("stable", "% stable", 1),
            column("shapes", "test shapes"), column("failed", "no shape decoded")]
    scale = "every test shape" if limit is None else f"the first {limit} test shapes"
    notes = [f"Per category, {scale} of the make-clouds cache (the corpus val split), seed {seed}: noisy "
             "2,048-point inputs in random scale and position; one decode per cloud, no fitting; F-score at 0.03.",
             "The shipped models, trained for about the same number of steps with and without macros "
             f"(docs/benchmarks.md); {_discovery_note(sorted({r['category'] for r in rows}))}. Our stability test "
             "uses 2.5 % of the height, the paper's 10 %; the paper's rows are on its own data split and training, so "
             "only the ordering of the two models compares."]
    return make_result("ShapeMOD Table 3: point cloud to program, without and with macros", cols, rows, notes,
                       command)
