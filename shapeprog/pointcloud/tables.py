"""The papers' point-cloud reconstruction tables on our data: ShapeMOD Table 3 and ShapeAssembly Table 7 layouts.

Protocol (:func:`evaluate`): the test split of a cloud cache (the corpus's val split; the models trained on a
carve-out of its train split), each shape given as :data:`INPUT_POINTS` points of its cached 10,000 with
Gaussian noise (sigma :data:`NOISE`, canonical units) and then a random uniform scale and position (seeded per
shape). Every method's result is mapped back through that known transform and compared with the shape's
clean 10,000-point cloud in the canonical frame: chamfer distance (x1000), F-score at 0.03, rooted, stable
(:func:`shapeprog.pointcloud.infer.shape_metrics`). Rows:

* ``model``: :func:`~shapeprog.pointcloud.infer.infer` without fitting (the latent-projection row of Table 7,
  the "No Macros" row of Table 3 when the model is the ShapeAssembly decoder);
* ``opt_program``: the same with ``fit=True`` (Table 7 "Opt Program");
* ``opt_cuboids``: the decoded cuboids fitted freely, without the program (Table 7 "Opt Cuboids",
  :func:`fit_cuboids`);
* ``retrieval``: the nearest training shape by chamfer (:class:`~shapeprog.pointcloud.retrieval.RetrievalIndex`).

With ``search=True`` two more rows measure the latent search (:mod:`shapeprog.pointcloud.search`), which is
ours, not the papers': ``search`` (``infer(..., search=True)``, no fitting) and ``search_opt_program`` (the
same with ``fit=True``). With ``augmented=True`` two more measure retrieval-augmented decoding (also ours):
``augmented`` (``infer(..., search=True, search_schedule=QUICK_SEARCH_SCHEDULE, retrieval=index)``: the
program of a 5-decode search against the shortlisted training programs of the index, the one closest to the
input kept; no fitting) and ``augmented_opt_program`` (the same with ``fit=True``).

:func:`write_tables` writes both layouts with the papers' rows beside ours as Markdown
(``python -m shapeprog pointcloud-tables``).
"""
from __future__ import annotations

import time
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from shapeio import atomic_write

from ..geometry import CORNER_SIGNS
from ..metrics import chamfer
from ..sampling import sample_surface
from .dataset import load_cache, read_split
from .infer import FIT_STEPS, RETRIEVAL_CANDIDATES, infer, load_model, load_pretrained, shape_metrics
from .normalize import _corners_of, normalize
from .retrieval import RetrievalIndex
from .search import QUICK_SEARCH_SCHEDULE, SEARCH_SCHEDULE

__all__ = ["INPUT_POINTS", "KEEP_MARK", "NOISE", "PAPER_TABLE3", "PAPER_TABLE3_MACROS", "PAPER_TABLE7",
           "PAPER_TABLE7_NAMES", "ROWS", "TableResult", "evaluate",
           "fit_cuboids", "write_tables"]

#: Points per input cloud, and the Gaussian noise added to them (canonical units): the issue's test condition.
INPUT_POINTS, NOISE = 2048, 0.005
#: The random uniform scale of an input is ``exp(U(-log SCALE_RANGE, log SCALE_RANGE))``; its shift is
#: ``U(-SHIFT, SHIFT)`` per axis.
SCALE_RANGE, SHIFT = 10.0, 5.0
#: Failed shapes listed by name under the tables (the rest are counted).
MAX_LISTED_ERRORS = 20
ROWS = ("model", "opt_program", "opt_cuboids", "retrieval", "search", "search_opt_program", "augmented",
        "augmented_opt_program")
#: A line of a table file after which the text is kept when :func:`write_tables` rewrites the file: sections that
#: show other commands' result files (the harder test conditions of ``bench/pointcloud_robust.py --conditions``).
KEEP_MARK = "<!-- kept when `python -m shapeprog pointcloud tables` rewrites this file -->"
#: ShapeMOD Table 3, "No Macros" row: CD x1000, F-score, % rooted, % stable (dense PartNet mesh samples).
PAPER_TABLE3 = {"chair": (44.2, 54.8, 93.7, 83.6), "table": (41.1, 64.0, 92.8, 78.2),
                "storage": (56.5, 41.1, 95.0, 87.7)}
#: The same table's ShapeMOD row (the model trained on macro programs).
PAPER_TABLE3_MACROS = {"chair": (41.7, 56.1, 96.9, 88.0), "table": (36.7, 68.7, 95.2, 88.5),
                       "storage": (47.0, 53.0, 97.6, 92.6)}
#: ShapeAssembly Table 7 (chairs): F1, rooted, stable of the latent projection, "Opt Program" and "Opt Cuboids".
PAPER_TABLE7 = {"model": (31.1, 95.5, 84.4), "opt_program": (75.8, 95.3, 80.2), "opt_cuboids": (77.6, 93.1, 72.9)}
#: The names of the paper's Table 7 rows.
PAPER_TABLE7_NAMES = {"model": "ShapeAssembly paper", "opt_program": "ShapeAssembly paper, Opt Program",
                      "opt_cuboids": "ShapeAssembly paper, Opt Cuboids"}


def fit_cuboids(corners: torch.Tensor, target: torch.Tensor, steps: int = FIT_STEPS, lr: float = 5e-3,
                samples: int = 2048, generator: Optional[torch.Generator] = None) -> torch.Tensor:
    """Fit cuboids freely to a cloud (no program): each cuboid's centre and its three edge lengths move, its
    orientation stays; Adam on the chamfer distance of surface samples.

    Args:
        corners: ``(L, 8, 3)`` float, the starting cuboids (spec corner order).
        target: ``(M, 3)`` float, the cloud in the same frame.
        steps, lr: Adam's steps and learning rate.
        samples: surface samples per step.
        generator: the samples' draws.

    Returns:
        ``(L, 8, 3) float32`` fitted corners.
    """
    c = corners.detach().double()
    signs = CORNER_SIGNS.double()
    center = c.mean(1)
    # half-edge vectors: corner = center + signs @ half (spec order, signs along the cuboid's own axes)
    half = torch.linalg.lstsq(signs.expand(len(c), 8, 3), c - center[:, None]).solution  # (L, 3, 3)
    pos = center.clone().requires_grad_(True)
    log_s = torch.zeros(len(c), 3, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([pos, log_s], lr=lr)
    tgt = torch.as_tensor(target, dtype=torch.float64)

    def build() -> torch.Tensor:
        return pos[:, None] + signs[None] @ (log_s.exp()[..., None] * half)

    for _ in range(int(steps)):
        opt.zero_grad()
        pts, _ = sample_surface(build(), samples, generator=generator)
        chamfer(pts, tgt).backward()
        opt.step()
    with torch.no_grad():
        return build().float()


def _inputs(clean: np.ndarray, shape_id: int, seed: int):
    """The noisy, subsampled, moved and scaled input of a clean canonical cloud: ``(input, k, b)`` with
    ``input = noisy * k + b``."""
    rng = np.random.default_rng([int(seed), int(shape_id)])
    pick = rng.choice(len(clean), size=min(INPUT_POINTS, len(clean)), replace=False)
    noisy = clean[pick] + rng.normal(0.0, NOISE, size=(len(pick), 3))
    k = float(np.exp(rng.uniform(-np.log(SCALE_RANGE), np.log(SCALE_RANGE))))
    b = rng.uniform(-SHIFT, SHIFT, size=3)
    return noisy * k + b, k, b


def _shape_job(job) -> dict:
    """All rows of one shape: ``(weights, category, id, clean (M, 3), retrieved corners or None, steps,
    stability, seed, search, cache root or None)`` -> ``{row: metrics}``; with a cache root the two
    retrieval-augmented rows are measured (the index of its training clouds, built once per process)."""
    weights, category, shape_id, clean, retrieved, steps, stability, seed, search, augmented = job
    torch.set_num_threads(1)
    model = _model(weights, category)
    x, k, b = _inputs(clean, shape_id, seed)
    target = torch.from_numpy(clean)
    back = lambda corners: torch.from_numpy((np.asarray(corners) - b) / k)  # noqa: E731 - input -> canonical
    out = {}
    g = torch.Generator().manual_seed(int(seed))
    empty = lambda: shape_metrics(torch.zeros(0, 8, 3), target)  # noqa: E731 - no shape: F 0, not rooted

    errors = {}  # row -> the message of the error that left it without a result

    def row(name, make):
        """One row's metrics; a ValueError (no shape decoded, a fit that fails) empties this row only."""
        try:
            out[name] = shape_metrics(back(make()), target, seed=seed, stability=stability)
        except ValueError as e:
            out[name] = empty()
            errors[name] = str(e)

    try:
        plain = infer(x, model=model, physics=False, seed=seed, method="decode")  # the papers' single decode
    except ValueError as e:  # no shape decoded: every row that starts from the decoded program fails for this shape
        plain = None
        out.update({r: empty() for r in ("model", "opt_program", "opt_cuboids")})
        errors.update({r: str(e) for r in ("model", "opt_program", "opt_cuboids")})
    if plain is not None:
        out["model"] = shape_metrics(back(plain.corners()), target, seed=seed, stability=stability)
        row("opt_program", lambda: infer(x, model=model, fit=True, fit_steps=steps, physics=False, seed=seed,
                                         method="decode").corners())

        def free_cuboids():
            unit = torch.from_numpy(plain.transform.apply(x))
            free = fit_cuboids(_corners_of(plain.canonical) + torch.from_numpy(plain.canonical_offset).float(), unit,
                               steps=steps, generator=g)
            return plain.transform.invert(free.double().numpy())
        row("opt_cuboids", free_cuboids)
    if search:
        row("search", lambda: infer(x, model=model, physics=False, seed=seed, search=True).corners())
        row("search_opt_program", lambda: infer(x, model=model, fit=True, fit_steps=steps, physics=False, seed=seed,
                                                search=True).corners())
    if augmented is not None:
        index = _index(augmented, category)
        quick = {"search": True, "search_schedule": QUICK_SEARCH_SCHEDULE, "retrieval": index}
        row("augmented", lambda: infer(x, model=model, physics=False, seed=seed, **quick).corners())
        row("augmented_opt_program", lambda: infer(x, model=model, fit=True, fit_steps=steps, physics=False, seed=seed,
                                                   **quick).corners())
    if retrieved is not None:
        corners, t = retrieved
        out["retrieval"] = shape_metrics(back(t.invert(corners)), target, seed=seed, stability=stability)
    if errors:
        out["errors"] = errors
    return out


_MODELS: dict = {}
_INDEXES: dict = {}


def _index(root, category) -> RetrievalIndex:
    key = (str(root), category)
    if key not in _INDEXES:  # one index per worker process
        _INDEXES[key] = RetrievalIndex.from_cache(root, category)
    return _INDEXES[key]


def _model(weights, category):
    key = (str(weights), category)
    if key not in _MODELS:  # one load per worker process
        _MODELS[key] = load_pretrained(category) if weights is None else load_model(weights, category)
    return _MODELS[key]


@dataclass
class TableResult:
    """Per-row means over the shapes measured, and how they were measured."""

    category: str
    shapes: int
    rows: dict = field(default_factory=dict)  # row -> {"cd": x1000 mean, "fscore", "rooted" %, "stable" %}
    errors: dict = field(default_factory=dict)  # row -> [(shape id, the error's message)]: shapes without a result
    seconds: float = 0.0
    settings: dict = field(default_factory=dict)

    @property
    def failed(self) -> dict:
        """Row -> the number of shapes without a result (scored F 0, not rooted)."""
        return {row: len(errs) for row, errs in self.errors.items()}


def _mean(results: list[dict], row: str) -> dict:
    ms = [r[row] for r in results if row in r]
    cds = [m["cd"] for m in ms if m["cd"] is not None]

    def pct(key: str) -> Optional[float]:
        if not ms or ms[0][key] is None:
            return None
        return 100.0 * float(np.mean([bool(m[key]) for m in ms]))

    return {"cd": 1000.0 * float(np.mean(cds)) if cds else None,
            "fscore": float(np.mean([m["fscore"] for m in ms])), "rooted": pct("rooted"), "stable": pct("stable"),
            "n": len(ms)}


def evaluate(root, category: str = "chair", weights=None, limit: Optional[int] = None, steps: int = FIT_STEPS,
             stability: bool = True, retrieval: bool = True, executor: Optional[Executor] = None, seed: int = 0,
             progress=None, search: bool = False, augmented: bool = False) -> TableResult:
    """Measure every row of :data:`ROWS` on the test split of the cache at ``root``.

    Args:
        root: a :func:`~shapeprog.pointcloud.data.make_clouds` folder.
        category: the category.
        weights: a point-cloud weights file (default: the shipped model of ``category``).
        limit: the first N test shapes only (the split file's order); None: all.
        steps: fitting steps of the two optimisation rows.
        stability: run the stability test (about 0.5 s per shape and row).
        retrieval: measure the retrieval row.
        executor: runs the per-shape jobs; None runs them here.
        seed: the inputs' noise, subsets, scales and positions.
        progress: called with ``(done, total)``.
        search: also measure the two latent-search rows (about 1 s and 3 s more per shape).
        augmented: also measure the two retrieval-augmented rows (each worker builds the index once from the
            cache, about 13 CPU s for chairs).
    """
    t0 = time.perf_counter()
    cache = load_cache(root, category)
    ids = read_split(root, category, cache)["test"]
    ids = ids[: int(limit)] if limit is not None else ids
    rows = cache.index(ids)
    clean = cache.normalized(rows).astype(np.float64)
    retrieved = [None] * len(ids)
    if retrieval:
        index = _index(root, category)
        queries, transforms = [], []
        for i, c in zip(ids, clean):
            x, _, _ = _inputs(c, i, seed)
            unit, t = normalize(x)
            queries.append(torch.from_numpy(unit))
            transforms.append(t)
        for j, m in enumerate(index.search(queries)):
            prog, off = m.canonical_program()
            retrieved[j] = ((_corners_of(prog).double() + torch.from_numpy(off)).numpy(), transforms[j])
    aug = str(root) if augmented else None
    jobs = [(None if weights is None else str(weights), category, int(i), c, r, steps, stability, seed, bool(search), aug)
            for i, c, r in zip(ids, clean, retrieved)]
    it = map(_shape_job, jobs) if executor is None else executor.map(_shape_job, jobs)
    results = []
    for n, r in enumerate(it, 1):
        results.append(r)
        if progress is not None:
            progress(n, len(jobs))
    macros = _model(None if weights is None else str(weights), category).layout is not None
    out = TableResult(category, len(ids), seconds=time.perf_counter() - t0,
                      settings={"points": INPUT_POINTS, "noise": NOISE, "steps": steps, "seed": seed,
                                "stability": stability, "weights": str(weights) if weights else "shipped",
                                "search": bool(search), "augmented": bool(augmented), "macros": macros})
    for row in ROWS:
        if any(row in r for r in results):
            out.rows[row] = _mean(results, row)
            out.errors[row] = [(int(i), r["errors"][row]) for i, r in zip(ids, results)
                               if row in r.get("errors", {})]
    return out


def _f(v, digits=1) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}"


def _against_retrieval(r: dict, row: str, claim: str) -> list:
    """A sentence on whether ``row`` beats the retrieval row on F-score (``claim`` has a ``{}`` for the verb);
    nothing without a retrieval row."""
    if "retrieval" not in r:
        return []
    verdict = "beats" if r[row]["fscore"] > r["retrieval"]["fscore"] else "does not beat"
    return [claim.format(verdict) + f" on F-score without fitting ({_f(r[row]['fscore'])} against "
            f"{_f(r['retrieval']['fscore'])}).", ""]


def write_tables(result: TableResult, out, command: str = "") -> Path:
    """Write both layouts as Markdown to ``out`` (atomically); ``command`` is recorded under them. When ``out``
    exists, its text from the line :data:`KEEP_MARK` on is kept at the end."""
    r, cat = result.rows, result.category
    names = {"model": "Ours: PointNet++ -> latent -> VAE decoder (no fitting)",
             "opt_program": "Ours + Opt Program (fit the program's numbers)",
             "opt_cuboids": "Ours + Opt Cuboids (fit free cuboids)", "retrieval": "Nearest training shape (retrieval)",
             "search": "Ours + latent search (not the papers' protocol; no fitting)",
             "search_opt_program": "Ours + latent search + Opt Program",
             "augmented": "Ours + quick search + retrieval-augmented decoding (not the papers' protocol; no fitting)",
             "augmented_opt_program": "Ours + quick search + retrieval-augmented decoding + Opt Program"}
    lines = [f"# Point cloud -> program reconstruction, {cat} ({result.shapes} test shapes)", "",
             f"Test split: the corpus val split (`{cat}`), the first {result.shapes} shapes of the cache's split file. "
             f"Inputs: {INPUT_POINTS} points of each shape's cuboid-surface cloud, Gaussian noise sigma {NOISE}, then a "
             f"random scale (x1/{SCALE_RANGE:g} to x{SCALE_RANGE:g}) and position; results are mapped back and compared "
             "with the clean 10,000-point cloud in the canonical frame (bounding-box diagonal 2). The papers sampled "
             "dense PartNet meshes, which are not available here: their rows are beside ours, not comparable "
             "number for number.", "",
             "## ShapeMOD Table 3 layout", "", "| Method | CD x1000 (lower better) | F-score @0.03 | % rooted | % stable |",
             "|---|---|---|---|---|"]
    macros = bool(result.settings.get("macros"))
    if macros:  # the model writes macro programs: every "Ours" row is of the ShapeMOD kind
        names = {k: v.replace("Ours", "Ours, ShapeMOD macros", 1) for k, v in names.items()}
    p3 = PAPER_TABLE3.get(cat)
    if p3:
        lines.append(f"| ShapeMOD paper, No Macros | {p3[0]} | {p3[1]} | {p3[2]} | {p3[3]} |")
    p3m = PAPER_TABLE3_MACROS.get(cat)
    if p3m and macros:
        lines.append(f"| ShapeMOD paper, ShapeMOD (macros) | {p3m[0]} | {p3m[1]} | {p3m[2]} | {p3m[3]} |")
    for row in ("model", "opt_program", "retrieval", "search", "search_opt_program", "augmented",
                "augmented_opt_program"):
        if row in r:
            m = r[row]
            lines.append(f"| {names[row]} | {_f(m['cd'])} | {_f(m['fscore'])} | {_f(m['rooted'])} | {_f(m['stable'])} |")
    if macros:
        lines += ["", "The model decodes macro programs calling the category's ShapeMOD library; the metrics read "
                  "their expansions. Compare with the same command on the base-language model for the No Macros "
                  "row.", ""]
    else:
        lines += ["", "The model decodes ShapeAssembly programs (No Macros); a model trained on macro programs "
                  "(`--weights` of one) gives the ShapeMOD row.", ""]
    if cat == "chair":
        lines += ["## ShapeAssembly Table 7 layout (chairs)", "", "| Method | F1 | % rooted | % stable |", "|---|---|---|---|"]
        lines += [f"| {PAPER_TABLE7_NAMES[k]} | {f} | {ro} | {st} |" for k, (f, ro, st) in PAPER_TABLE7.items()]
        for row in ROWS:
            if row in r:
                m = r[row]
                lines.append(f"| {names[row]} | {_f(m['fscore'])} | {_f(m['rooted'])} | {_f(m['stable'])} |")
        lines += ["", "Our F1 is the F-score at 0.03 (canonical units, bounding-box diagonal 2) against the clean cloud; "
                  "the paper's Table 7 used its adaptive F-score threshold against PartNet mesh samples. Our stable "
                  "column follows the reference code's 2.5 % rule; the paper's appendix describes 10 %.", ""]
    if "retrieval" in r and "model" in r and r["model"]["fscore"] < r["retrieval"]["fscore"]:
        lines += [f"**The learned model loses to retrieval** on F-score ({_f(r['model']['fscore'])} against "
                  f"{_f(r['retrieval']['fscore'])}) without fitting.", ""]
    if "search" in r:
        decodes = 1 + sum(n for n, _ in SEARCH_SCHEDULE)
        lines += [f"Latent search (`infer(..., search=True)`, `shapeprog.pointcloud.search`): {decodes} decodes of codes "
                  "drawn around the predicted one, the program of lowest chamfer to the *input* cloud kept (no ground "
                  "truth, no training shape). It is ours, not the papers' protocol: compare the papers with the rows "
                  "above it.", ""]
        lines += _against_retrieval(r, "search", "With latent search the model {} retrieval")
    if "augmented" in r:
        quick = 1 + sum(n for n, _ in QUICK_SEARCH_SCHEDULE)
        lines += [f"Retrieval-augmented decoding (`infer(..., search=True, search_schedule=QUICK_SEARCH_SCHEDULE, "
                  f"retrieval=index)`; CLI `--retrieval --search-schedule quick`): the program of a {quick}-decode latent "
                  f"search and the {RETRIEVAL_CANDIDATES} training programs that the retrieval index's coarse stage "
                  "puts nearest to the input compete, and the one of lowest chamfer to the *input* cloud is kept (no "
                  "ground truth; the index holds the corpus train split only). It is ours, not the papers' protocol.", ""]
        lines += _against_retrieval(r, "augmented", "Retrieval-augmented decoding {} retrieval alone")
    failed = {k: v for k, v in result.failed.items() if v}
    lines += [f"Shapes without a result (scored F 0, not rooted): {failed or 'none'}. "
              f"Settings: {result.settings}. Wall time {result.seconds:.0f} s.", ""]
    named = [(row, e) for row, errs in result.errors.items() for e in errs]
    if named:
        lines += ["Why (row: shape: error):", ""]
        lines += [f"* {row}: {cat}/{i}: {msg}" for row, (i, msg) in named[:MAX_LISTED_ERRORS]]
        if len(named) > MAX_LISTED_ERRORS:
            lines.append(f"* and {len(named) - MAX_LISTED_ERRORS} more")
        lines.append("")
    if command:
        lines += ["Command:", "", f"    {command}", ""]
    kept = ""
    if Path(out).is_file():  # what follows KEEP_MARK in the file being replaced stays
        old = Path(out).read_text(encoding="utf-8")
        kept = "\n" + old[old.index(KEEP_MARK):] if KEEP_MARK in old else ""
    return atomic_write(out, "\n".join(lines) + kept, mkdir=True)
