"""The ShapeAssembly paper's generation tables for a set of generated programs, and the classifier they use.

:func:`generation_table` measures generated programs of one category with every metric of
:mod:`shapeprog.vae.genmetrics` (the paper's Table 2: % rooted, % stable, % fool, FD; Table 5: leaf parts;
Table 4: generalization, coverage, variety; and % novel programs, by text and by structure) against the
corpus train split, adds a ground-truth row (the corpus val split through the same metrics) and the paper's
figures, and returns a markdown table. :func:`evaluate_generation` gives one row as numbers,
:func:`generation_rows` the rows of several sample sets against one category's references and
:func:`generation_result` rows of one or more categories as a result file's content. :func:`train_category_classifier`
trains the PointNet whose features the Fréchet distance uses (``python -m shapeprog vae train-classifier``).
Definitions and decisions: ``docs/generation_metrics.md``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np
import torch

from shapeio.cache import cached

from .genmetrics import (CHAMFER_POINTS, CLASSIFIER_POINTS, FoolResult, chamfer_clouds, classifier_clouds,
                         classifier_features, coverage, execute_samples, frechet_distance, gaussian_fit,
                         generalization, leaf_parts, novelty, percent_fool, variety)
from ..lang import Program
from .. import corpus
from ..corpus import data_digest
from ..physics import CODE_STABILITY_TOLERANCE, PAPER_STABILITY_TOLERANCE, rootedness, stability_displacement
from .structure import structure_key
from .pointnet import accuracy, fit_classifier, PRETRAINED_SHA256, load_classifier

__all__ = ["PAPER", "PAPER_SHAPEMOD", "PAPERS", "GenerationRow", "paper_rows", "References", "evaluate_generation", "format_table", "generation_result",
           "generation_rows", "generation_table", "table_notes", "train_category_classifier"]

#: The ShapeAssembly paper's figures for its model (Tables 2, 4 and 5) and the ground truth's leaf parts. Its
#: stability figure is under the 10 % rule of its appendix E (our column ``stable_paper``); its structural novelty
#: (§7.1.3) is not in the specification.
PAPER = {
    "chair": {"rooted": 94.5, "stable": 84.7, "fool": 25.06, "fd": 22.34, "leaf_parts": 7.9,
              "generalization": 0.108, "coverage": 0.118, "variety": 0.104, "gt_leaf_parts": 9.7},
    "table": {"rooted": 96.2, "stable": 85.9, "fool": 33.21, "fd": 49.07, "leaf_parts": 7.84,
              "generalization": 0.101, "coverage": 0.108, "variety": 0.102, "gt_leaf_parts": 8.4},
    "storage": {"rooted": 95.3, "stable": 83.7, "fool": 13.50, "fd": 31.72, "leaf_parts": 8.4,
                "generalization": 0.125, "coverage": 0.129, "variety": 0.119, "gt_leaf_parts": 10.8},
}

_COLUMNS = ("rooted", "stable", "stable_paper", "fool", "fd", "leaf_parts", "generalization", "coverage", "variety",
            "novelty", "novelty_structure")
_HEADERS = ("% rooted", f"% stable (code rule, {100 * CODE_STABILITY_TOLERANCE:g} %)",
            f"% stable (paper rule, {100 * PAPER_STABILITY_TOLERANCE:g} %)", "% fool", "FD", "leaf parts",
            "generalization", "coverage", "variety", "% novel (text)", "% novel (structure)")
_DIGITS = {"rooted": 1, "stable": 1, "stable_paper": 1, "fool": 2, "fd": 2, "leaf_parts": 2, "generalization": 3,
           "coverage": 3, "variety": 3, "novelty": 1, "novelty_structure": 1}
#: The ShapeMOD paper's Table 2 (chairs; generation with and without macros): the rows printed under a macro
#: model's table instead of the ShapeAssembly paper's. Its FD is not comparable with either other FD, and its
#: stability rule is not in the specification (placed beside the ShapeAssembly paper's, in the 10 % column).
PAPER_SHAPEMOD = {
    "chair": {"No Macros": {"fool": 21.2, "fd": 17.8, "leaf_parts": 7.6, "rooted": 93.9, "stable": 82.3},
              "ShapeMOD": {"fool": 25.6, "fd": 16.7, "leaf_parts": 8.6, "rooted": 92.7, "stable": 79.5}},
}
#: Which paper's rows a table prints (``format_table(paper=...)``).
PAPERS = ("shapeassembly", "shapemod")

#: Where the paper's row takes its figures from: our column -> the key of :data:`PAPER` (the paper's stability
#: is under its 10 % rule, so it sits in the paper-rule column).
_PAPER_KEYS = {"stable": None, "stable_paper": "stable"}


# --------------------------------------------------------------------------------------------------
# the category classifier


def _corpus(category: str, split: str) -> tuple[list[Program], list[torch.Tensor]]:
    programs = [p for _, p in corpus.load(category, split)]
    corners, errors = execute_samples(programs)
    if errors:
        raise ValueError(f"{category} {split}: {len(errors)} corpus programs failed: {errors[:3]}")
    return programs, corners


def train_category_classifier(
    epochs: int = 10,
    per_class: int = 500,
    points: int = 512,
    finetune_epochs: int = 1,
    finetune_lr: float = 3e-4,
    batch_size: int = 32,
    lr: float = 1e-3,
    seed: int = 0,
    categories: Sequence[str] = ("chair", "table", "storage"),
    log=None,
    **model_kwargs,
) -> tuple:
    """Train the PointNet category classifier on the corpus train split; measure it on the val split.

    Every executed train shape gives one :func:`~shapeprog.vae.genmetrics.classifier_clouds` cloud of 2,500
    points (seed ``seed``); :func:`shapeprog.vae.pointnet.fit_classifier` draws ``per_class`` shapes of each
    category per epoch and a random ``points``-point subset of each cloud per visit (cheap), then
    ``finetune_epochs`` more epochs at learning rate ``finetune_lr`` use all 2,500 points, so that the
    head and its batch norms see the max pool of the clouds the metrics use. The accuracy is measured on
    the val split's clouds (seed ``seed + 1``) with all 2,500 points.

    Returns:
        ``(model, meta)``; ``meta`` records the settings, the val accuracy overall and per category
        (percent), the shape counts and the training seconds.
    """
    t0 = time.perf_counter()
    data = {}
    for split, s in (("train", seed), ("val", seed + 1)):
        clouds, labels = [], []
        for k, cat in enumerate(categories):
            c = classifier_clouds(_corpus(cat, split)[1], seed=s)
            clouds.append(c)
            labels.append(torch.full((c.shape[0],), k, dtype=torch.long))
        data[split] = (torch.cat(clouds), torch.cat(labels))
    if log is not None:
        log(f"clouds ready in {time.perf_counter() - t0:.1f} s: train {len(data['train'][1])}, "
            f"val {len(data['val'][1])}")
    t1 = time.perf_counter()
    model = fit_classifier(*data["train"], k=len(categories), epochs=epochs, batch_size=batch_size, lr=lr,
                           points=points, per_class=per_class, seed=seed, log=log, **model_kwargs)
    if finetune_epochs:
        model = fit_classifier(*data["train"], k=len(categories), epochs=finetune_epochs, batch_size=batch_size,
                               lr=finetune_lr, points=None, per_class=per_class, seed=seed + 1, model=model, log=log)
    train_s = time.perf_counter() - t1
    val_clouds, val_labels = data["val"]
    per_cat = {cat: accuracy(model, val_clouds[val_labels == k], val_labels[val_labels == k])
               for k, cat in enumerate(categories)}
    meta = {
        "categories": list(categories), "epochs": epochs, "per_class": per_class, "points": points,
        "finetune_epochs": finetune_epochs, "finetune_lr": finetune_lr, "cloud_points": CLASSIFIER_POINTS, "batch_size": batch_size, "lr": lr, "seed": seed,
        "train_shapes": int(len(data["train"][1])), "val_shapes": int(len(val_labels)),
        "val_accuracy": accuracy(model, val_clouds, val_labels), "val_accuracy_per_category": per_cat,
        "train_seconds": round(train_s, 1), "torch": str(torch.__version__), "threads": torch.get_num_threads(),
    }
    return model, meta


# --------------------------------------------------------------------------------------------------
# reference sets


@dataclass
class References:
    """The corpus sets a category's generated shapes are measured against, executed and sampled once.

    Attributes:
        category: ``"chair"``, ``"table"`` or ``"storage"``.
        train_programs, val_programs: the corpus splits' programs.
        train_corners, val_corners: their leaf corners ``(L, 8, 3)``.
        train_clouds: :func:`~shapeprog.vae.genmetrics.classifier_clouds` of the train shapes (the real
            shapes of % fool), ``(T, 2500, 3)``.
        train_fit: Gaussian fit ``(mu, cov)`` of the train shapes' classifier features (FD).
        train_chamfer, val_chamfer: :func:`~shapeprog.vae.genmetrics.chamfer_clouds` of both splits.
        seed: the sampling seed (train clouds use ``seed``, val ``seed + 1``).
        train_structures: the train programs' structure keys (:meth:`structures` makes them when None).
    """

    category: str
    train_programs: list
    val_programs: list
    train_corners: list
    val_corners: list
    train_clouds: torch.Tensor
    train_fit: tuple
    train_chamfer: torch.Tensor
    val_chamfer: torch.Tensor
    seed: int = 0
    train_structures: Optional[frozenset] = None

    def structures(self) -> frozenset:
        """The structure keys of the train programs (:func:`~shapeprog.vae.structure.structure_key`), made once."""
        if self.train_structures is None:
            self.train_structures = frozenset(structure_key(p) for p in self.train_programs)
        return self.train_structures

    @classmethod
    def build(cls, category: str, model=None, seed: int = 0, chamfer_points: int = CHAMFER_POINTS,
              log=None, classifier_sha: Optional[str] = None) -> "References":
        """Execute and sample the corpus train and val splits of ``category``; fit the train features (kept in
        the on-disk cache, :func:`train_feature_fit`, when ``classifier_sha`` names the classifier)."""
        t0 = time.perf_counter()
        train_programs, train_corners = _corpus(category, "train")
        val_programs, val_corners = _corpus(category, "val")
        train_clouds = classifier_clouds(train_corners, seed=seed)
        fit = train_feature_fit(category, train_clouds, model, seed, classifier_sha, log)
        refs = cls(category, train_programs, val_programs, train_corners, val_corners, train_clouds, fit,
                   chamfer_clouds(train_corners, chamfer_points, seed=seed),
                   chamfer_clouds(val_corners, chamfer_points, seed=seed + 1), seed)
        if log is not None:
            log(f"{category}: train {len(train_corners)} and val {len(val_corners)} shapes executed, sampled "
                f"and the train features fitted in {time.perf_counter() - t0:.1f} s")
        return refs


# --------------------------------------------------------------------------------------------------
# one row


@dataclass
class GenerationRow:
    """One row of the generation table (percentages 0-100; None where a metric was not computed).

    ``samples`` programs were given, ``valid`` of them parsed and executed to at least one leaf cuboid;
    every metric is over the valid ones. ``stable`` is under the reference code's rule (a base may move 2.5 % of
    its height), ``stable_paper`` under the paper's (10 %), both from one simulation per shape; ``novelty`` is
    the text novelty (numbers to 3 decimals), ``novelty_structure`` the structural one (numbers abstracted,
    :func:`~shapeprog.vae.structure.structural_novelty`). ``fool_detail`` keeps the % fool breakdown, ``errors`` the
    failures, ``seconds`` the time per metric.
    """

    name: str
    samples: int
    valid: int
    rooted: Optional[float] = None
    stable: Optional[float] = None
    stable_paper: Optional[float] = None
    fool: Optional[float] = None
    fd: Optional[float] = None
    leaf_parts: Optional[float] = None
    generalization: Optional[float] = None
    coverage: Optional[float] = None
    variety: Optional[float] = None
    novelty: Optional[float] = None
    novelty_structure: Optional[float] = None
    fool_detail: Optional[FoolResult] = None
    errors: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)


def _physics_job(job) -> tuple[bool, Optional[float]]:
    """``(corners, stability)`` -> rooted, and the base displacement (a fraction of the height; ``inf`` when not
    rooted) when ``stability``."""
    corners, stable = job
    rooted = rootedness(corners)
    if not stable:
        return rooted, None
    return rooted, stability_displacement(corners) if rooted else float("inf")


def _map(executor, fn, jobs) -> list:
    return list(map(fn, jobs)) if executor is None else list(executor.map(fn, jobs, chunksize=8))


def evaluate_generation(
    samples: Sequence,
    references: References,
    name: str = "generated",
    model=None,
    executor=None,
    stability: bool = True,
    fool: bool = True,
    fool_epochs: int = 12,
    fool_average_last: int = 4,
    fool_points: int = 512,
    with_coverage: bool = True,
    candidates: Optional[int] = 16,
    chamfer_points: int = CHAMFER_POINTS,
    seed: int = 0,
    log=None,
) -> GenerationRow:
    """Every generation metric of ``samples`` (programs or texts) against ``references``.

    Args:
        samples: generated programs (``Program`` or text).
        references: the category's corpus sets (:meth:`References.build`).
        name: the row's name.
        model: the PointNet whose features give the FD (default the shipped classifier); it must be the
            one ``references`` was built with.
        executor: a ``concurrent.futures.Executor`` for the per-shape work (physics, chamfer search); None
            runs everything here.
        stability: run the pybullet stability test (about 0.5 s per shape); False leaves it None.
        fool: train the % fool classifier; ``fool_epochs``, ``fool_average_last`` and ``fool_points``
            are its budget (:func:`~shapeprog.vae.genmetrics.percent_fool`).
        with_coverage: measure coverage of the val split (False for the val split itself).
        candidates: exact chamfer candidates per shape (:func:`~shapeprog.vae.genmetrics.nearest_chamfer`).
        chamfer_points: surface points per shape of the chamfer metrics.
        seed: sampling and training seed (samples use ``seed + 2``, their chamfer clouds ``seed + 3``).
        log: a function taking a line of progress text.
    """
    say = log or (lambda s: None)
    samples = list(samples)
    corners, errors = execute_samples(samples)
    valid = [i for i, c in enumerate(corners) if c is not None]
    shapes = [corners[i] for i in valid]
    row = GenerationRow(name, len(corners), len(valid), errors=errors)
    if len(shapes) < 2:
        say(f"{name}: only {len(shapes)} of {len(corners)} programs executed; nothing measured")
        return row

    def timed(key, fn):
        t0 = time.perf_counter()
        out = fn()
        row.seconds[key] = round(time.perf_counter() - t0, 1)
        say(f"{name}: {key} in {row.seconds[key]} s")
        return out

    row.leaf_parts = float(np.mean([leaf_parts(c) for c in shapes]))
    progs = [samples[i] for i in valid]
    row.novelty = timed("novelty", lambda: novelty(progs, references.train_programs))
    known = references.structures()
    row.novelty_structure = 100.0 * float(np.mean([structure_key(p) not in known for p in progs]))
    phys = timed("physics", lambda: _map(executor, _physics_job, [(c.double().numpy(), stability) for c in shapes]))
    row.rooted = 100.0 * float(np.mean([r for r, _ in phys]))
    if stability:
        row.stable = 100.0 * float(np.mean([s <= CODE_STABILITY_TOLERANCE for _, s in phys]))
        row.stable_paper = 100.0 * float(np.mean([s <= PAPER_STABILITY_TOLERANCE for _, s in phys]))
    clouds = classifier_clouds(shapes, seed=seed + 2)
    row.fd = timed("fd", lambda: frechet_distance(classifier_features(clouds, model), references.train_fit))
    if fool:
        row.fool_detail = timed("fool", lambda: percent_fool(clouds, references.train_clouds, epochs=fool_epochs,
                                                             average_last=fool_average_last, points=fool_points,
                                                             seed=seed))
        row.fool = row.fool_detail.percent
    gen = chamfer_clouds(shapes, chamfer_points, seed=seed + 3)
    kw = dict(candidates=candidates, executor=executor)
    row.generalization = timed("generalization", lambda: generalization(gen, references.train_chamfer, **kw))
    if with_coverage:
        row.coverage = timed("coverage", lambda: coverage(references.val_chamfer, gen, **kw))
    row.variety = timed("variety", lambda: variety(gen, **kw))
    return row


# --------------------------------------------------------------------------------------------------
# the table


def _cell(value, digits: int) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def paper_rows(category: str, paper="shapeassembly") -> list[tuple[str, dict]]:
    """The paper rows of a table: ``(name, {column: value or None})`` for each. ``paper``: ``"shapeassembly"``
    (or True; its model and ground-truth rows, :data:`PAPER`), ``"shapemod"`` (the ShapeMOD paper's Table 2 rows,
    :data:`PAPER_SHAPEMOD`, for a model of macro programs), or None / False (none)."""
    if paper is True:
        paper = "shapeassembly"
    if not paper:
        return []
    if paper not in PAPERS:
        raise ValueError(f"unknown paper {paper!r}; expected one of {', '.join(PAPERS)}")
    if paper == "shapemod":
        return [(f"paper: ShapeMOD Table 2, {name}", {c: p.get(_PAPER_KEYS.get(c, c)) for c in _COLUMNS})
                for name, p in PAPER_SHAPEMOD.get(category, {}).items()]
    if category not in PAPER:
        return []
    p = PAPER[category]
    return [("paper: ShapeAssembly", {c: p.get(_PAPER_KEYS.get(c, c)) for c in _COLUMNS}),
            ("paper: ground truth", {c: p["gt_leaf_parts"] if c == "leaf_parts" else None for c in _COLUMNS})]


def format_table(rows: Sequence[GenerationRow], category: str, notes: Sequence[str] = (),
                 paper="shapeassembly") -> str:
    """A markdown table of ``rows`` and the paper's rows for ``category`` (:func:`paper_rows`), then ``notes``."""
    lines = [f"Generation metrics, {category}", "",
             "| | " + " | ".join(_HEADERS) + " |", "|---" * (len(_HEADERS) + 1) + "|"]
    for r in rows:
        label = f"{r.name} ({r.valid} of {r.samples} programs)" if r.valid != r.samples else f"{r.name} ({r.samples})"
        lines.append(f"| {label} | " + " | ".join(_cell(getattr(r, c), _DIGITS[c]) for c in _COLUMNS) + " |")
    for name, values in paper_rows(category, paper):
        lines.append(f"| {name} | " + " | ".join(_cell(values[c], _DIGITS[c]) for c in _COLUMNS) + " |")
    if paper == "shapemod":
        notes = [*notes, "The paper rows are the ShapeMOD paper's Table 2 (chairs only in the specification; its "
                 "stability rule is not specified); its FD used another classifier."]
    if notes:
        lines += [""] + [f"* {n}" for n in notes]
    return "\n".join(lines) + "\n"


def table_notes(model_meta: dict, sha: Optional[str], fool_epochs: int, fool_average_last: int, fool_points: int,
                chamfer_points: int, candidates: Optional[int], stability: bool) -> list[str]:
    """The notes printed under a generation table: how each column was measured."""
    acc = model_meta.get("val_accuracy")
    acc_text = f", {acc:.1f} % correct on the corpus val split" if isinstance(acc, (int, float)) else ""
    which = (f"this project's PointNet (global feature, 1024-d; weights SHA-256 {sha[:12]}…, trained on the "
             f"corpus train split{acc_text})") if sha else "the classifier the caller passed"
    return [
        f"FD values are comparable only within one classifier: these use {which}; the paper's FD used a "
        "ShapeNet classifier whose weights are not public, so its FD column is not comparable with ours.",
        f"% fool: a binary PointNet trained from scratch for {fool_epochs} epochs (the paper: 300) on generated "
        f"vs training shapes in equal numbers, {fool_points} points per shape, 20 % of each held out; the "
        f"percentage of held-out shapes misclassified, averaged over the last {fool_average_last} epochs "
        "(50 = indistinguishable).",
        f"Chamfer columns: {chamfer_points} surface points per shape, every shape scaled to unit bounding-box "
        "diagonal; the sum of both directions' mean nearest-point distances; nearest shapes by a grid estimate "
        + ("and exact chamfer on every pair." if candidates is None else f"and exact chamfer on its {candidates} best candidates.")
        + " Coverage is over the val split, so the ground-truth row has none.",
        "Rooted follows the reference code (2 % contact rule). Stable: one pybullet simulation per shape with the "
        "code's forces, scored under two rules: a group's base may move 2.5 % of its height (the reference code) "
        "or 10 % (the paper's appendix E, whose force is proportional to mass instead); the paper's % stable is "
        "printed in the 10 % column" + ("." if stability else "; stability was not run."),
        "The paper's generalization, coverage and variety are chamfer distances on another normalisation (its "
        "shapes and point counts; ours: unit bounding-box diagonal, so two samplings of one shape already differ "
        "by about 0.035): compare orderings between rows, not values with the paper's.",
        "% novel (text): programs whose text (numbers to 3 decimals) is no training program's, so a changed number "
        "is novel. % novel (structure): programs whose structure (every continuous number abstracted; names, "
        "faces, axes, aligned flags, translate counts and hierarchy kept) is no training program's, the paper's "
        "§7.1.3 measure; the paper's figures for it are not in the specification.",
        "Ground truth: the corpus val split through the same metrics (FD, % fool, generalization against "
        "the train split). Leaf parts: leaf cuboids per executed program (= the reference's vertices / 8).",
    ]


#: The draws per VAE sample of the generation tables (``vae evaluate -n``) before a sample is decoded without
#: rejection.
EVALUATE_TRIES = 10
#: Bumped when the classifier clouds or features change: cached feature fits of other versions are not read.
FEATURE_CACHE_VERSION = 1


def train_feature_fit(category: str, train_clouds, model, seed: int, classifier_sha: Optional[str] = None,
                      log=None) -> tuple:
    """The Gaussian fit ``(mu, cov)`` of the classifier features of a category's training clouds (FD's reference),
    kept in the on-disk cache (:mod:`shapeio.cache`) keyed by the category, the classifier's SHA-256, the corpus
    archive's digest, the seed, the cloud size and :data:`FEATURE_CACHE_VERSION`; not cached without a digest."""
    def compute():
        if log is not None:
            log(f"{category}: classifier features of {len(train_clouds)} training shapes (cached after this run)")
        mu, cov = gaussian_fit(classifier_features(train_clouds, model))
        return {"mu": mu, "cov": cov}

    if classifier_sha is None:
        got = compute()
    else:
        key = {"category": category, "classifier": classifier_sha, "corpus": data_digest(), "seed": int(seed),
               "points": int(train_clouds.shape[1]), "shapes": int(train_clouds.shape[0]),
               "version": FEATURE_CACHE_VERSION}
        got = cached("train-feature-fit", key, compute)
    return np.asarray(got["mu"]), np.asarray(got["cov"])


#: Bumped when a generation metric changes: cached ground-truth rows of other versions are not read.
GROUND_TRUTH_CACHE_VERSION = 2


def ground_truth_row(refs: References, classifier_sha: Optional[str], **kw) -> GenerationRow:
    """The ground-truth row (the corpus val split through :func:`evaluate_generation`, no coverage), kept in the
    on-disk cache (:mod:`shapeio.cache`) keyed by the category, the classifier's SHA-256, the corpus archive's
    digest, the metric settings in ``kw`` and :data:`GROUND_TRUTH_CACHE_VERSION`; computed (with a progress line
    through ``kw['log']``) when not there. Not cached for a classifier without a known digest."""
    def compute() -> GenerationRow:
        say = kw.get("log") or (lambda s: None)
        say(f"{refs.category}: measuring the ground-truth row ({len(refs.val_programs)} shapes; cached after this "
            "run)")
        return evaluate_generation(refs.val_programs, refs, name="ground truth: corpus val", with_coverage=False, **kw)

    if classifier_sha is None:
        return compute()
    key = {"category": refs.category, "classifier": classifier_sha, "corpus": data_digest(), "seed": refs.seed,
           "version": GROUND_TRUTH_CACHE_VERSION,
           "settings": {k: v for k, v in kw.items() if k not in ("model", "executor", "log")}}
    got = cached("ground-truth-row", key, lambda: {"row": np.array(json.dumps(dataclasses.asdict(compute())))})
    data = json.loads(str(got["row"]))
    detail = data.pop("fool_detail")
    data["errors"] = [tuple(e) if isinstance(e, list) else e for e in data["errors"]]
    return GenerationRow(**data, fool_detail=None if detail is None else FoolResult(**detail))


def generation_rows(
    sample_sets: Sequence[tuple[str, Sequence]],
    category: str,
    ground_truth: bool = True,
    model=None,
    references: Optional[References] = None,
    executor=None,
    stability: bool = True,
    fool: bool = True,
    fool_epochs: int = 12,
    fool_average_last: int = 4,
    fool_points: int = 512,
    candidates: Optional[int] = 16,
    chamfer_points: int = CHAMFER_POINTS,
    seed: int = 0,
    log=None,
) -> tuple[list[GenerationRow], list[str]]:
    """One :class:`GenerationRow` per ``(name, programs)`` of ``sample_sets`` against the category's references
    (built once), then the ground-truth row when ``ground_truth``; and the notes under the table. Arguments as
    :func:`evaluate_generation`."""
    if category not in PAPER:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(PAPER)}")
    meta, sha = {}, None
    if model is None:
        model, _, meta = load_classifier()  # checks the file against PRETRAINED_SHA256
        sha = PRETRAINED_SHA256
    refs = references or References.build(category, model, seed, chamfer_points, log, classifier_sha=sha)
    kw = dict(model=model, executor=executor, stability=stability, fool=fool, fool_epochs=fool_epochs,
              fool_average_last=fool_average_last, fool_points=fool_points, candidates=candidates,
              chamfer_points=chamfer_points, seed=seed, log=log)
    rows = [evaluate_generation(list(samples), refs, name=name, **kw) for name, samples in sample_sets]
    if ground_truth:
        rows.append(ground_truth_row(refs, sha, **kw))
    notes = table_notes(meta, sha, fool_epochs, fool_average_last, fool_points, chamfer_points, candidates, stability)
    return rows, notes


def generation_table(
    samples: Sequence,
    category: str,
    ground_truth: bool = True,
    name: str = "generated",
    **kw,
) -> str:
    """The paper's generation tables for ``samples`` of ``category``, as markdown.

    Rows: the samples, the ground truth (the corpus val split, when ``ground_truth``), and the paper's
    ShapeAssembly and ground-truth figures. Columns: % rooted, % stable under the code's and the paper's rule
    (Table 2), % fool, FD (Table 2), leaf parts (Table 5), generalization, coverage, variety (Table 4), % novel
    programs by text and by structure. The notes under the table say how each was measured. Other arguments as
    :func:`generation_rows`; ``samples`` may be empty (``[]``) with ``ground_truth=True`` for the ground-truth
    row alone.
    """
    samples = list(samples)
    rows, notes = generation_rows([(name, samples)] if samples else [], category, ground_truth, **kw)
    return format_table(rows, category, notes)


def generation_result(tables: Sequence[tuple[str, Sequence[GenerationRow]]], notes: Sequence[str] = (),
                      command: Optional[str] = None, paper="shapeassembly") -> dict:
    """The rows of one or more categories (``(category, rows)`` pairs) as a result file's content
    (:func:`shapeio.results.make_result`): one row per table row, then the paper's rows of each category
    (:func:`paper_rows`), a column per metric, the samples and valid counts."""
    from shapeio.results import column, make_result  # lazy: the result format is needed only when written

    cols = [column("category", "category"), column("row", "row"), column("samples", "programs"),
            column("valid", "valid")]
    cols += [column(c, h, _DIGITS[c]) for c, h in zip(_COLUMNS, _HEADERS)]
    out = []
    for category, rows in tables:
        for r in rows:
            out.append({"category": category, "row": r.name, "samples": r.samples, "valid": r.valid,
                        **{c: getattr(r, c) for c in _COLUMNS}})
        for name, values in paper_rows(category, paper):
            out.append({"category": category, "row": name, "samples": None, "valid": None, **values})
    return make_result("Generation metrics (ShapeAssembly Tables 2, 4, 5)", cols, out, notes, command)
