"""Point cloud -> ShapeAssembly program: :func:`infer` (the robust method and the papers' single decode) and the
polish by fitting. The models and their weights files are in :mod:`shapeprog.pointcloud.model`, how candidates and
up axes are scored in :mod:`shapeprog.pointcloud.selection`; both are re-exported here.

:func:`infer` takes a cloud ``(N, 3)`` (NumPy or torch) in any position and scale, maps it into the canonical
frame the training clouds are in (:func:`~shapeprog.pointcloud.normalize.normalize`), encodes
:data:`ENCODER_POINTS` of its points with the PointNet++ encoder, decodes the code with the VAE decoder
(non-rejecting validity decoding, :func:`shapeprog.vae.decode.decode_latent`; several codes at once with
:func:`~shapeprog.vae.decode.decode_programs`), scales the program uniformly
so that its executed cuboids span the cloud's bounding box (the decoder works in the corpus frame, whose
shapes the normalisation scales by 0.85-1.1), and maps the result back into the input's position, its lengths in
the power of ten (:func:`text_unit`) that keeps them in the corpus's range, so that the program text parses
and executes at any input scale.
With ``fit=True`` the program's continuous numbers are then fitted to the cloud by chamfer through the
differentiable executor (:func:`shapeprog.fit.fit`), keeping the structure. With ``retrieval=`` (a
:class:`~shapeprog.pointcloud.retrieval.RetrievalIndex`; ours, not the papers') the decoded program competes
with the training programs nearest to the cloud, and the one closest to the input is kept.

This module does not import Lightning.

Example:
    >>> import numpy as np
    >>> from shapeprog.pointcloud.data import corpus_cloud
    >>> cloud = corpus_cloud("chair", 173, n_points=3000) * 7.0 + np.array([1.0, 2.0, 3.0])
    >>> r = infer(cloud, "chair", physics=False)                                       # doctest: +SKIP
    >>> r.text.startswith("Assembly Program_0 {"), r.metrics["fscore"] > 0              # doctest: +SKIP
    (True, True)
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import torch

from ..errors import PointCloudError
from ..fit import fit as fit_program
from ..lang import Program, to_text
from ..metrics import chamfer, fscore
from ..sampling import sample_surface
from .data import TRAIN_POINTS
from .normalize import CANONICAL_DIAGONAL, Transform, _corners_of, align_program, normalize, scale_program
from .retrieval import RetrievalIndex
from .search import (SEARCH_POINTS, SEARCH_SCHEDULE, aligned_corners, check_schedule, latent_search, parse_schedule,
                     selection_chamfers, selection_target)
from ..physics import rootedness, stability as stable_fn
from .selection import (FSCORE_THRESHOLD, SELECT_POINTS, UP_CANDIDATES, UP_RATIO, UpAxisWarning, orientation_scores,
                        selection_scores, warn_up_axis)
from .model import (PRETRAINED, CloudModel, cloud_corners, decode_codes, load_encoder, load_model,
                    load_pretrained)

__all__ = ["DEFAULT_METHOD", "ENCODER_POINTS", "FIT_STEPS", "FSCORE_THRESHOLD", "MAX_DIAGONAL", "METHODS", "MIN_DIAGONAL",
           "MIN_POINTS", "POLISH_STEPS", "PRETRAINED", "RETRIEVAL_CANDIDATES", "ROBUST_CANDIDATES", "ROBUST_SUBSETS",
           "SELECT_POINTS", "UP_CANDIDATES", "UP_RATIO", "CloudModel", "Inference", "UpAxisWarning", "align_program", "cloud_corners", "decode_codes",
           "default_index", "infer", "load_encoder", "load_model", "load_pretrained", "orientation_scores", "selection_scores",
           "shape_metrics", "text_unit"]

#: Fewest points :func:`infer` takes.
MIN_POINTS = 16
#: Smallest and largest bounding-box diagonal of a cloud :func:`infer` takes (input units): well inside float32's
#: range (1.2e-38 to 3.4e38), in which clouds are read and shapes executed.
MIN_DIAGONAL, MAX_DIAGONAL = 1e-32, 1e32
#: Points of the (normalised) input the encoder sees (the training clouds' count); fewer are drawn with repeats.
ENCODER_POINTS = TRAIN_POINTS
#: Adam steps of the polish (``fit=True``).
FIT_STEPS = 150
#: Training programs that compete with the decoded one under ``infer(..., retrieval=index)``. Chosen on the
#: validation carve-out of the chair cache (167 chairs against an index of the other 3,172 training chairs, the
#: shipped end-to-end model, no fitting): F-score 57.3 for the decoded program alone, 68.2 / 68.9 / 69.1 with
#: 8 / 16 / 32 candidates at 0.081 / 0.092 / 0.112 CPU s per cloud (median, one core); 16 takes nearly all of
#: the gain for little time, 32 and 64 add 0.2 (docs/pointcloud.md, "Retrieval-augmented decoding").
RETRIEVAL_CANDIDATES = 16
#: Surface samples of the result for the metrics.
METRIC_POINTS = 10_000
#: What :func:`infer` does: ``"robust"`` (candidates from several encoder subsets and the retrieval index, the one
#: closest to the input kept, then a short polish) or ``"decode"`` (the papers' single decode of one subset's code,
#: the protocol of the tables; ``search=`` and ``retrieval=`` extend it).
METHODS = ("robust", "decode")
#: The method of a call that names none (and asks for neither ``search`` nor ``retrieval``).
DEFAULT_METHOD = "robust"
#: Encoder subsets of ``ENCODER_POINTS`` points each, drawn and decoded by the robust method (one batch).
ROBUST_SUBSETS = 4
#: Training programs nearest to the cloud (the index's coarse stage) that compete in the robust method.
ROBUST_CANDIDATES = 16
#: Fitting steps of the robust method's final polish (kept only when it improves the selection score), and the
#: surface samples and input points of each step.
POLISH_STEPS, POLISH_SAMPLES = 10, 1024
def text_unit(diagonal: float) -> float:
    """The unit of the program text :func:`infer` writes for a cloud of bounding-box ``diagonal`` (input units):
    the power of ten nearest to ``diagonal / CANONICAL_DIAGONAL`` (1 for diagonals 0.63 to 6.3, 1000 for a chair
    in millimetres). The text's lengths times the unit are input lengths, so its numbers stay in the corpus's
    range (far below :data:`shapeprog.limits.MAX_ABS_NUMBER`) with the corpus's 3 decimals of precision.

    Example:
        >>> text_unit(1.8), text_unit(1774.6), text_unit(0.0018), text_unit(2.5e30)
        (1.0, 1000.0, 0.001, 1e+30)
    """
    return float(f"1e{round(math.log10(diagonal / CANONICAL_DIAGONAL))}")


def shape_metrics(corners: torch.Tensor, target: torch.Tensor, points: int = METRIC_POINTS, seed: int = 0,
                  physics: bool = True, stability: bool = True) -> dict:
    """Chamfer distance (unsquared, both directions, eps 0), F-score at :data:`FSCORE_THRESHOLD`, rooted and
    stable of cuboids ``(L, 8, 3)`` against a cloud ``(M, 3)`` in the same frame (canonical units).

    ``cd`` is None and ``fscore`` 0 when there is no cuboid; ``rooted`` / ``stable`` are None when not run.
    """
    out = {"cd": None, "fscore": 0.0, "rooted": None, "stable": None}
    if len(corners) == 0:
        if physics:
            out["rooted"] = out["stable"] = False
        return out
    g = torch.Generator().manual_seed(int(seed))
    with torch.no_grad():
        pred, _ = sample_surface(corners.double(), points, generator=g)
    tgt = torch.as_tensor(target, dtype=torch.float64)
    out["cd"] = float(chamfer(pred, tgt, eps=0.0))
    out["fscore"] = float(fscore(pred, tgt, FSCORE_THRESHOLD))
    if physics:
        c = corners.detach().double().numpy()
        out["rooted"] = bool(rootedness(c))
        out["stable"] = bool(out["rooted"] and stable_fn(c)) if stability else None
    return out


@dataclass
class Inference:
    """What :func:`infer` returns.

    Attributes:
        program: the program at the input's scale with lengths in :attr:`unit` (executes y-up, centred near the
            origin).
        text: ``to_text(program)`` (3 decimals, the corpus's format); it parses and executes at any input scale.
        offset, rotation: ``(3,)`` and ``(3, 3) float64``: the executed points ``p`` of :attr:`text` lie on the
            input at ``(p * unit) @ rotation + offset`` (:meth:`place`); the rotation is the identity for a y-up
            input.
        canonical: the program in the canonical frame (AABB diagonal 2) and ``canonical_offset (3,)``: its
            executed points + that offset lie on the normalised cloud.
        transform: the input -> canonical :class:`Transform` of the cloud.
        metrics: ``cd`` (chamfer, canonical units), ``fscore`` (0-100 at 0.03 canonical units), ``rooted``,
            ``stable`` of the result against the (normalised) input cloud.
        before: the same metrics before fitting (``fit=True``), else None.
        seconds: wall time of ``decode`` (encode + decode + align; ``search`` in its place with ``search=True``),
            ``retrieval`` (with ``retrieval=``; not counted in ``decode`` / ``search``), ``fit`` and ``metrics``.
        search: with ``search=True``: ``start_cd`` and ``cd`` (the selection chamfer of the predicted code's
            program and of the one kept), ``decodes`` and ``improved`` (steps that found a better program);
            else None.
        macro_text: for a model that writes macro programs (ShapeMOD), the decoded macro program's text, in
            the decoder's frame, before the alignment and any fitting (:attr:`program` is its expansion, aligned
            and fitted); None for a base-language model, and None when a retrieved program was kept.
        retrieval: with ``retrieval=``: ``candidates`` (training programs scored), ``decoded_cd`` (the
            decoded program's selection chamfer, None when it decoded to no shape), ``cd`` (the kept
            program's) and ``chosen`` (the kept training program's corpus name, ``"chair/173"``, or None when
            the decoded program was kept); else None.
        fit_stopped: with ``fit=True``, None when every fitting step ran; else why the fitting stopped early
            (:attr:`shapeprog.fit.FitResult.stopped`: a step would have broken the program's execution, so the
            numbers before it are kept).
        unit: the input length of one unit of :attr:`text`, a power of ten (:func:`text_unit`; 1 for an input
            whose bounding-box diagonal is 0.63 to 6.3).
        robust: with the robust method: ``decoded`` (candidates decoded from the subsets' codes, and the search's),
            ``retrieved`` (training programs), ``scores`` (each candidate's ``[fscore, cd]`` against the selection
            points, decoded ones first), ``chosen`` (the kept training program's corpus name, or None for a decoded
            one), ``score`` (the kept candidate's) and ``polished`` (the score after the polish when it was kept,
            else None); else None.
        up_scores: ``{up: chamfer distance}`` of :func:`orientation_scores` when the up axis was checked or chosen
            (``up="auto"``); else None. :attr:`transform` names the up axis used.
    """

    program: Program
    text: str
    offset: np.ndarray
    rotation: np.ndarray
    canonical: Program
    canonical_offset: np.ndarray
    transform: Transform
    metrics: dict
    before: Optional[dict] = None
    seconds: dict = field(default_factory=dict)
    search: Optional[dict] = None
    macro_text: Optional[str] = None
    retrieval: Optional[dict] = None
    fit_stopped: Optional[str] = None
    unit: float = 1.0
    robust: Optional[dict] = None
    up_scores: Optional[dict] = None

    def place(self, points):
        """Points of the executed :attr:`program` ``(..., 3)`` -> the input's frame."""
        return (np.asarray(points, dtype=np.float64) * self.unit) @ self.rotation + self.offset

    def corners(self) -> np.ndarray:
        """The result's leaf cuboids in the input's frame, ``(L, 8, 3) float64``."""
        return self.place(_corners_of(self.program).double().numpy())


def _as_cloud(points) -> np.ndarray:
    if isinstance(points, torch.Tensor):
        points = points.detach().cpu().numpy()
    try:
        raw = np.asarray(points)
    except (TypeError, ValueError):
        raw = None
    if raw is None or raw.dtype.kind not in "iuf":  # no strings, objects, booleans or complex numbers
        kind = type(points).__name__ if raw is None else f"{type(points).__name__} of dtype {raw.dtype}"
        raise PointCloudError(f"points must be an (N, 3) array of real numbers, got {kind}", "points")
    x = raw.astype(np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise PointCloudError(f"points must have shape (N, 3), got {x.shape}", "points")
    if len(x) < MIN_POINTS:
        raise PointCloudError(f"the cloud has {len(x)} points; at least {MIN_POINTS} are needed", "points")
    if not np.isfinite(x).all():
        bad = int(np.argwhere(~np.isfinite(x).all(1))[0, 0])
        raise PointCloudError(f"point {bad} has a NaN or infinite coordinate", "points")
    with np.errstate(over="ignore"):
        diagonal = float(np.linalg.norm(x.max(0) - x.min(0)))
    if diagonal > 0 and not MIN_DIAGONAL <= diagonal <= MAX_DIAGONAL:
        raise PointCloudError(f"the cloud's bounding-box diagonal {diagonal:.3g} is outside [{MIN_DIAGONAL:g}, "
                              f"{MAX_DIAGONAL:g}] (MIN_DIAGONAL, MAX_DIAGONAL)", "points")
    return x


def infer(points, category: str = "chair", fit: bool = False, model: Optional[CloudModel] = None, up: str = "y",
          fit_steps: int = FIT_STEPS, fit_lr: float = 5e-3, physics: bool = True, stability: bool = False,
          seed: int = 0, search: bool = False, search_schedule=None, retrieval=None,
          retrieval_candidates: Optional[int] = None, method: Optional[str] = None,
          subsets: int = ROBUST_SUBSETS, polish_steps: int = POLISH_STEPS, select: str = "fscore",
          check_up: bool = True) -> Inference:
    """A ShapeAssembly program for a point cloud.

    Args:
        points: ``(N, 3)`` float, NumPy array or torch tensor, ``N >= MIN_POINTS``, any position and scale.
        category: the shipped model to use (``model`` overrides it).
        fit: polish the decoded program's continuous numbers against the cloud (the structure is kept).
        model: a :class:`CloudModel` (default: :func:`load_pretrained` of ``category``).
        up: the input's up axis (:data:`shapeprog.pointcloud.normalize.UP_AXES`), or ``"auto"``: the axis of
            :data:`UP_CANDIDATES` whose orientation matches the category's training shapes best
            (:func:`orientation_scores`).
        fit_steps, fit_lr: Adam steps and learning rate of the polish.
        physics: compute ``rooted`` of the result; ``stability``: also ``stable``, the physics stability
            test (off by default: about 0.5 s, longer than the rest of the call).
        seed: the draws of the encoder's subset, the fitting's samples and the metrics' samples.
        search: decode more codes around the predicted one and keep the program closest to the cloud
            (:func:`shapeprog.pointcloud.search.latent_search`, about 1 s), before any fitting; the
            papers' protocol is ``search=False``.
        search_schedule: the search's ``(samples, sigma)`` steps, or a name of
            :data:`~shapeprog.pointcloud.search.NAMED_SCHEDULES` (``"default"``, ``"fast"``, ``"quick"``) or a
            ``"samples:sigma,..."`` string as the CLI's ``--search-schedule`` (default
            :data:`~shapeprog.pointcloud.search.SEARCH_SCHEDULE`); only with ``search=True``.
        retrieval: a :class:`~shapeprog.pointcloud.retrieval.RetrievalIndex` of the category's training
            shapes: the ``retrieval_candidates`` training programs nearest to the cloud by the index's coarse
            stage compete with the decoded (or searched) program, and the one of lowest selection chamfer to
            the input is kept (:func:`~shapeprog.pointcloud.search.selection_chamfers`; the decoded program wins
            ties). Ours, not the papers'; default None (no retrieval).
        retrieval_candidates: training programs scored with ``retrieval`` (at least 1; default
            :data:`RETRIEVAL_CANDIDATES`, or :data:`ROBUST_CANDIDATES` with the robust method).
        method: ``"robust"`` or ``"decode"`` (:data:`METHODS`). None: ``"decode"`` when ``search`` or
            ``retrieval`` is given, else :data:`DEFAULT_METHOD`. The robust method encodes ``subsets`` random
            subsets of the cloud, decodes their codes, lets them compete with the ``retrieval_candidates`` (default
            :data:`ROBUST_CANDIDATES`) training programs nearest to the cloud (``retrieval``, default
            :func:`default_index` of the model's category; 0: none) by :func:`selection_scores` against
            :data:`SELECT_POINTS` points of the input (``select``: ``"fscore"``, chamfer breaking ties, or
            ``"chamfer"``), and polishes the kept program with ``polish_steps`` fitting steps, kept only when
            they improve its score (``search=True`` adds the latent search around the best decoded code).
            ``.robust`` records the candidates' scores and what was kept.
        subsets, polish_steps, select: the robust method's settings (above).
        check_up: with the robust method and a given ``up``, score the other orientations of
            :data:`UP_CANDIDATES` too (:func:`orientation_scores`) and warn (:class:`UpAxisWarning`, one line
            naming ``up=`` and the CLI's ``--up``) when one matches the training shapes by more than
            the factor :data:`UP_RATIO` nearer in chamfer distance than the kept program is to the cloud;
            ``.up_scores`` records the chamfer distances.

    Returns:
        An :class:`Inference`.

    Raises:
        PointCloudError: not ``(N, 3)``, fewer than :data:`MIN_POINTS` points, a NaN or infinite coordinate,
            all points at one place; or the model decodes no shape (no cuboid) for this cloud (nor does the
            search find one).
        ValueError: a bad ``search_schedule``, or one given without ``search=True``.
    """
    if search_schedule is not None and not search:
        raise ValueError("search_schedule is given but search is False: pass search=True to use it")
    if method is None:
        method = "decode" if (search or retrieval is not None) else DEFAULT_METHOD
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {method!r}")
    x = _as_cloud(points)
    model = load_pretrained(category) if model is None else model
    up_scores = None
    if up == "auto":
        index = retrieval if retrieval is not None else default_index(model.category)
        up_scores = orientation_scores(x, index, seed)
        up = min(UP_CANDIDATES, key=lambda u: (up_scores[u], UP_CANDIDATES.index(u)))
    try:
        unit, t = normalize(x, up=up)
    except ValueError as e:
        raise PointCloudError(str(e), "points") from None
    if method == "robust":
        k = ROBUST_CANDIDATES if retrieval_candidates is None else retrieval_candidates
        r = _robust(x, unit, t, model, fit, fit_steps, fit_lr, physics, stability, seed, search, search_schedule,
                    retrieval, k, subsets, polish_steps, select)
        if up_scores is None and check_up:
            up_scores = warn_up_axis(x, (r.robust["polished"] or r.robust["score"])[1], up, retrieval if retrieval is not None else default_index(model.category),
                                  seed)
        r.up_scores = up_scores
        return r
    retrieval_candidates = RETRIEVAL_CANDIDATES if retrieval_candidates is None else retrieval_candidates
    if retrieval is not None:
        _check_retrieval(retrieval, retrieval_candidates, model)
    rng = np.random.default_rng(int(seed))
    pick = rng.choice(len(unit), size=ENCODER_POINTS, replace=len(unit) < ENCODER_POINTS)
    cloud = torch.from_numpy(unit[np.sort(pick)].astype(np.float32))
    t0 = time.perf_counter()
    code = model.codes(cloud[None])[0]
    searched = None
    if search:

        if search_schedule is None:
            schedule = SEARCH_SCHEDULE
        elif isinstance(search_schedule, str):
            schedule = parse_schedule(search_schedule)
        else:
            schedule = check_schedule(search_schedule)
        r = latent_search(model, code, torch.from_numpy(unit), schedule, seed=seed)
        program = r.program
        searched = {"start_cd": None if np.isinf(r.start_cd) else r.start_cd, "cd": None if np.isinf(r.cd) else r.cd,
                    "decodes": r.decodes, "improved": r.improved}
        code = r.code
    macro = None
    if model.layout is not None and (not search or program is not None):
        # the kept code's macro program: decoded once here (the search keeps programs, not macro texts)
        macro = model.decode_macros(code[None])[0]
        program = None if macro is None else macro.program
    elif not search:
        program = model.decode(code[None])[0]
    macro_text = None if macro is None else macro.text
    retrieved = None
    if retrieval is not None:
        t3 = time.perf_counter()
        known = None if searched is None else (math.inf if searched["cd"] is None else searched["cd"])
        program, chosen, retrieved = _retrieve(retrieval, retrieval_candidates, program, cloud, unit, seed, known)
        if chosen:
            macro_text = None
        seconds_retrieval = time.perf_counter() - t3
    if program is None or len(_corners_of(program)) == 0:
        hint = "" if search else "; the latent search (search=True, CLI --search) looks for one near the predicted code"
        raise PointCloudError(f"the {model.category} model decoded no shape for this cloud{hint}", "points")
    canon, off = align_program(program)
    seconds = {"search" if search else "decode": time.perf_counter() - t0}
    if retrieval is not None:
        seconds["search" if search else "decode"] -= seconds_retrieval
        seconds["retrieval"] = seconds_retrieval
    target = torch.from_numpy(unit)
    before = fit_stopped = None
    if fit:
        t1 = time.perf_counter()
        g = torch.Generator().manual_seed(int(seed))
        before = shape_metrics(_corners_of(canon) + torch.from_numpy(off).float(), target, seed=seed,
                               physics=physics, stability=stability)
        r = fit_program(canon, target.float() - torch.from_numpy(off).float(), steps=fit_steps, lr=fit_lr,
                        generator=g)
        canon, fit_stopped = r.program, r.stopped
        seconds["fit"] = time.perf_counter() - t1
    return _finish(canon, off, t, target, seed, physics, stability, seconds, before=before, search=searched,
                   macro_text=macro_text, retrieval=retrieved, fit_stopped=fit_stopped, up_scores=up_scores)


def _finish(canon: Program, off: np.ndarray, t: Transform, target: torch.Tensor, seed: int, physics: bool,
            stability: bool, seconds: dict, **fields) -> Inference:
    """The :class:`Inference` of the kept program ``canon`` (canonical frame, executed points + ``off`` on the
    normalised cloud ``target``): its metrics, and the program mapped back to the input's scale and frame."""
    t2 = time.perf_counter()
    metrics = shape_metrics(_corners_of(canon) + torch.from_numpy(off).float(), target, seed=seed,
                            physics=physics, stability=stability)
    seconds["metrics"] = time.perf_counter() - t2
    length = text_unit(CANONICAL_DIAGONAL / t.scale)  # the text's unit
    program_in = scale_program(canon, 1.0 / (t.scale * length))
    rotation = t.rotation
    # canonical p -> input: (p / scale) @ rotation + center; the text's points are p_text = p_canon_exec / (scale * unit)
    offset = np.asarray(t.center) + (off / t.scale) @ rotation
    return Inference(program_in, to_text(program_in, decimals=3), offset, rotation, canon, off, t, metrics,
                     seconds=seconds, unit=length, **fields)


@functools.lru_cache(maxsize=3)
def default_index(category: str):
    """The retrieval index of the robust method for ``category``: the corpus train split's programs, sampled once
    and kept in the on-disk cache (:meth:`~shapeprog.pointcloud.retrieval.RetrievalIndex.from_corpus`; the first
    call per machine takes about a minute for chairs, later processes read it in about half a second), one per
    process."""
    return RetrievalIndex.from_corpus(category)


def _robust(x, unit, t, model, fit, fit_steps, fit_lr, physics, stability, seed, search, search_schedule, index, k,
            subsets, polish_steps, select) -> Inference:
    """:func:`infer`'s robust method (see there)."""
    if isinstance(subsets, bool) or not isinstance(subsets, int) or subsets < 1:
        raise ValueError(f"subsets must be an integer >= 1, got {subsets!r}")
    if isinstance(polish_steps, bool) or not isinstance(polish_steps, int) or polish_steps < 0:
        raise ValueError(f"polish_steps must be an integer >= 0, got {polish_steps!r}")
    if select not in ("fscore", "chamfer"):
        raise ValueError(f"select must be 'fscore' or 'chamfer', got {select!r}")
    t0 = time.perf_counter()
    if k != 0:  # 0: no training program competes
        index = default_index(model.category) if index is None else index
        _check_retrieval(index, k, model)
    rng = np.random.default_rng(int(seed))
    replace = len(unit) < ENCODER_POINTS
    picks = [np.sort(rng.choice(len(unit), size=ENCODER_POINTS, replace=replace)) for _ in range(subsets)]
    clouds = torch.from_numpy(np.stack([unit[p] for p in picks]).astype(np.float32))
    codes = model.codes(clouds)
    g = torch.Generator().manual_seed(int(seed))
    target = torch.from_numpy(unit)
    if len(unit) > SELECT_POINTS:
        target = target[torch.randperm(len(unit), generator=g)[:SELECT_POINTS]]

    def sampled(programs):
        out = []
        for corners in aligned_corners(programs):
            if corners is None:
                out.append(None)
                continue
            with torch.no_grad():
                out.append(sample_surface(corners, SELECT_POINTS, generator=torch.Generator().manual_seed(int(seed)))[0])
        return out

    key = (lambda s: (-s[0], s[1])) if select == "fscore" else (lambda s: (s[1], -s[0]))
    programs = model.decode(codes)
    all_codes = list(codes)
    scores = selection_scores(sampled(programs), target)
    if search:
        schedule = SEARCH_SCHEDULE if search_schedule is None else (
            parse_schedule(search_schedule) if isinstance(search_schedule, str) else check_schedule(search_schedule))
        best = min(range(len(scores)), key=lambda i: (key(scores[i]), i))
        centre = codes[best]
        for samples, sigma in schedule:
            drawn = centre[None] + sigma * torch.randn(samples, centre.numel(), generator=g)
            found = model.decode(drawn)
            got = selection_scores(sampled(found), target)
            programs += found
            scores += got
            all_codes += list(drawn)
            best = min(range(len(scores)), key=lambda i: (key(scores[i]), i))
            centre = all_codes[best] if best < len(all_codes) else centre
    decoded = len(programs)
    matches = index.shortlist(target, k) if k else []
    scores += selection_scores([index.reference_cloud(m.id)[:SELECT_POINTS] for m in matches], target)
    best = min(range(len(scores)), key=lambda i: (key(scores[i]), i))  # decoded programs first: they win ties
    if not math.isfinite(scores[best][1]):
        raise PointCloudError(f"the {model.category} model decoded no shape for this cloud and no training program "
                              "was found", "points")
    macro_text = None
    if best < decoded:
        program, chosen = programs[best], None
        if model.layout is not None:
            macro = model.decode_macros(all_codes[best][None])[0]
            macro_text = None if macro is None else macro.text
    else:
        program, chosen = matches[best - decoded].program(), matches[best - decoded].name
    canon, off = align_program(program)
    record = {"decoded": decoded, "retrieved": len(matches), "scores": scores, "chosen": chosen,
              "score": scores[best], "polished": None}
    seconds = {"select": time.perf_counter() - t0}
    tf = torch.from_numpy(off).float()
    if polish_steps > 0:
        t1 = time.perf_counter()
        r = fit_program(canon, target.float() - tf, steps=polish_steps, lr=fit_lr, samples=POLISH_SAMPLES,
                        target_samples=POLISH_SAMPLES, generator=torch.Generator().manual_seed(int(seed)))
        corners = _corners_of(r.program)
        polished = [0.0, math.inf]
        if len(corners):
            with torch.no_grad():
                pts = sample_surface(corners.double() + torch.from_numpy(off), SELECT_POINTS,
                                     generator=torch.Generator().manual_seed(int(seed)))[0]
            polished = selection_scores([pts], target)[0]
        if key(polished) < key(scores[best]):  # in the same frame (+ off) as the candidates were scored
            canon, record["polished"] = r.program, polished
        seconds["polish"] = time.perf_counter() - t1
    full = torch.from_numpy(unit)
    before = fit_stopped = None
    if fit:
        t1 = time.perf_counter()
        before = shape_metrics(_corners_of(canon) + tf, full, seed=seed, physics=physics, stability=stability)
        r = fit_program(canon, full.float() - tf, steps=fit_steps, lr=fit_lr,
                        generator=torch.Generator().manual_seed(int(seed)))
        canon, fit_stopped = r.program, r.stopped
        seconds["fit"] = time.perf_counter() - t1
    return _finish(canon, off, t, full, seed, physics, stability, seconds, before=before, macro_text=macro_text,
                   fit_stopped=fit_stopped, robust=record)


def _check_retrieval(index, k, model) -> None:
    """Refuse a bad candidate count, an index of another category than ``model``'s, or one whose clouds have
    fewer points than the selection chamfer uses (a training shape would then be scored with fewer points
    than the decoded program, which biases the choice against it)."""

    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"retrieval_candidates must be an integer >= 1, got {k!r}")
    if index.category != model.category:
        raise ValueError(f"the retrieval index holds {index.category} shapes but the model is the "
                         f"{model.category} model")
    if index.clouds.shape[1] < SEARCH_POINTS:
        raise ValueError(f"the retrieval index's clouds have {index.clouds.shape[1]} points; retrieval-augmented "
                         f"decoding scores with {SEARCH_POINTS} (build the index with at least that many)")


def _retrieve(index, k, program: Optional[Program], cloud: torch.Tensor, unit: np.ndarray, seed: int,
              program_cd: Optional[float] = None):
    """``(program kept, True when it is a training program, the record)``: ``program`` against the ``k``
    shortlisted training programs of ``index`` (coarse stage on ``cloud``, the encoder's subset), by
    selection chamfer against :data:`~shapeprog.pointcloud.search.SEARCH_POINTS` points of ``unit``: the
    decoded program's as the latent search scores (aligned, that many surface samples; ``program_cd`` when
    the search has scored it already), a training program's from the first that many points of its reference
    cloud in the index (samples of the same cuboid surfaces in the same frame, so no program is executed until
    one is kept)."""

    matches = index.shortlist(cloud.double(), k)
    target = selection_target(unit, SEARCH_POINTS, torch.Generator().manual_seed(int(seed)))
    cds = [program_cd] if program_cd is not None else selection_chamfers([program], target, SEARCH_POINTS, seed)
    for m in matches:
        ref = index.reference_cloud(m.id)[:SEARCH_POINTS].double()
        cds.append(float(chamfer(ref, target, eps=0.0)))
    best = min(range(len(cds)), key=lambda i: (cds[i], i))  # the decoded program (0) wins ties
    record = {"candidates": len(matches), "decoded_cd": None if math.isinf(cds[0]) else cds[0],
              "cd": None if math.isinf(cds[best]) else cds[best],
              "chosen": None if best == 0 else matches[best - 1].name}
    return (program, False, record) if best == 0 else (matches[best - 1].program(), True, record)
