"""Latent search: more decodes per cloud, the one closest to the input kept.

The papers decode one program per cloud, from the code the encoder predicts; that is
:func:`~shapeprog.pointcloud.infer.infer`'s default and the protocol row of the tables. The predicted code
is an estimate, and the decoder's output is not smooth in it (a small change of code can add or drop a
part), so a program decoded from a nearby code often matches the cloud better. :func:`latent_search` looks
for it without gradients (the decoder's structure choices have none): a cross-entropy-style local search
that, at each step of :data:`SEARCH_SCHEDULE`, draws ``samples`` codes around the best code so far with the
step's ``sigma``, decodes them (non-rejecting validity decoding, as :func:`infer`), scales each program onto
the cloud's bounding box (:func:`~shapeprog.pointcloud.normalize.align_program`) and keeps the candidate of
lowest chamfer distance to the (normalised) input cloud. The input is the only thing it looks at: no
ground truth, no training shape.

The returned program's selection chamfer is never above the predicted code's (the predicted code is the
first candidate; ties keep the earlier candidate), and the search is deterministic under its seed.

Cost: 1 + sum of the schedule's samples decodes (97 by default, about 1 s per cloud on one CPU core; see
``docs/benchmarks.md``), so it is an option (``infer(..., search=True)``, ``python -m shapeprog infer
--search``), not the default.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import torch

from ..execute import execute_batch
from ..lang import Program
from ..metrics import chamfer
from ..sampling import sample_surface
from .normalize import _align_executed, _corners_of

__all__ = ["FAST_SEARCH_SCHEDULE", "MAX_SEARCH_DECODES", "MAX_SIGMA", "NAMED_SCHEDULES", "QUICK_SEARCH_SCHEDULE", "SEARCH_POINTS",
           "SEARCH_SCHEDULE",
           "SearchResult", "aligned_corners", "check_schedule", "latent_search", "parse_schedule", "selection_chamfers",
           "selection_target"]

#: ``(samples, sigma)`` per step: ``samples`` codes drawn around the best code so far with standard deviation
#: ``sigma`` (the VAE's prior has unit variance). Chosen on 30 chair test shapes of the cloud cache with the
#: latent-regression chair model (F-score without fitting): 45.6 for the predicted code alone, 60.9 for four
#: steps of 8, 64.4 for four steps of 16, 66.9 for these six steps of 16 (docs/pointcloud.md, "Latent search").
SEARCH_SCHEDULE = ((16, 0.75), (16, 0.5), (16, 0.35), (16, 0.25), (16, 0.18), (16, 0.12))
#: A short schedule (17 decodes; about 4.5 times the plain decode's time, 0.39 s per chair on one core of the
#: 2-core CPU on 2026-11-27, against the issue's 0.2 s budget). Chosen on the validation
#: carve-out of the chair cache (167 clouds, the shipped end-to-end model, F-score without fitting): 57.3 for
#: the predicted code alone, 65.9 for these two steps of 8, 65.7 / 65.6 / 64.4 for the 21-decode schedules
#: 12:0.5,8:0.25 / 10:0.6,10:0.3 / 8:0.75,8:0.4,4:0.2, and 66.4 for 25 decodes (16:0.5,8:0.25)
#: (``bench/pointcloud_search_budget.py --split val``; docs/pointcloud.md, "Latent search").
FAST_SEARCH_SCHEDULE = ((8, 0.5), (8, 0.25))
#: The shortest schedule (5 decodes), for retrieval-augmented decoding within the 0.2 s budget
#: (``infer(..., search=True, search_schedule=QUICK_SEARCH_SCHEDULE, retrieval=index)``). Chosen on the chair
#: cache's validation carve-out with 16 retrieval candidates: F-score 68.9 for the decoded program and the
#: candidates, 69.9 with these 4 more codes, 70.8 with 8 more (4:0.5,4:0.25), whose 90th percentile passes 0.2 CPU s per cloud
#: (docs/pointcloud.md, "Retrieval-augmented decoding").
QUICK_SEARCH_SCHEDULE = ((4, 0.5),)
#: Schedules by name for :func:`parse_schedule` (and so the command line's ``--search-schedule``).
NAMED_SCHEDULES = {"default": SEARCH_SCHEDULE, "fast": FAST_SEARCH_SCHEDULE, "quick": QUICK_SEARCH_SCHEDULE}
#: Points of the input cloud, and surface samples of each candidate, in the selection chamfer.
SEARCH_POINTS = 1024
#: Most decodes one search may ask for (the sum of a schedule's samples).
MAX_SEARCH_DECODES = 4096
#: The largest sigma of a search step: latents are drawn from N(0, I), so steps this wide already reach far
#: outside the prior (the default schedule starts at 0.75).
MAX_SIGMA = 10.0


@dataclass
class SearchResult:
    """What :func:`latent_search` returns.

    Attributes:
        program: the chosen program in the decoder's (corpus) frame, or None when no candidate decoded to a
            shape.
        code: its code ``(H,)``.
        cd: its selection chamfer against the input (canonical units; ``inf`` without a program).
        start_cd: the predicted code's selection chamfer (``inf`` when it decoded to no shape).
        decodes: codes decoded, the predicted one included.
        improved: steps (of the schedule) that found a better candidate.
    """

    program: Optional[Program]
    code: torch.Tensor
    cd: float
    start_cd: float
    decodes: int
    improved: int


def check_schedule(schedule: Sequence) -> tuple:
    """``schedule`` as a tuple of ``(int samples >= 1, float sigma > 0)``.

    Raises:
        ValueError: an empty schedule, a step that is not a pair, a count below 1, a sigma outside
            ``(0, MAX_SIGMA]``, or more than :data:`MAX_SEARCH_DECODES` samples in all.
    """
    steps = []
    for k, step in enumerate(schedule):
        try:
            samples, sigma = step
        except (TypeError, ValueError):
            raise ValueError(f"search step {k}: expected (samples, sigma), got {step!r}") from None
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            raise ValueError(f"search step {k}: samples must be an integer >= 1, got {samples!r}")
        if isinstance(sigma, bool) or not isinstance(sigma, (int, float)) or not 0 < sigma <= MAX_SIGMA:
            raise ValueError(f"search step {k}: sigma must be a number in (0, {MAX_SIGMA:g}] (MAX_SIGMA), "
                             f"got {sigma!r}")
        steps.append((int(samples), float(sigma)))
    if not steps:
        raise ValueError("the search schedule has no step")
    total = sum(s for s, _ in steps)
    if total > MAX_SEARCH_DECODES:
        raise ValueError(f"the search schedule asks for {total} decodes; at most {MAX_SEARCH_DECODES}")
    return tuple(steps)


def parse_schedule(text: str) -> tuple:
    """``"16:0.75,16:0.5"`` -> ``((16, 0.75), (16, 0.5))`` (checked by :func:`check_schedule`); a name of
    :data:`NAMED_SCHEDULES` (``default``, ``fast``, ``quick``) gives that schedule.

    Raises:
        ValueError: a step that is not ``samples:sigma`` or fails :func:`check_schedule`.
    """
    if str(text).strip() in NAMED_SCHEDULES:
        return NAMED_SCHEDULES[str(text).strip()]
    steps = []
    for k, part in enumerate(str(text).split(",")):
        bits = part.strip().split(":")
        if len(bits) != 2:
            raise ValueError(f"search step {k}: expected samples:sigma, got {part.strip()!r}")
        try:
            steps.append((int(bits[0]), float(bits[1])))
        except ValueError:
            raise ValueError(f"search step {k}: expected samples:sigma with numbers, got {part.strip()!r}") from None
    return check_schedule(steps)


def latent_search(model, code: torch.Tensor, cloud: torch.Tensor, schedule: Sequence = SEARCH_SCHEDULE,
                  points: int = SEARCH_POINTS, seed: int = 0) -> SearchResult:
    """The decoded program closest to ``cloud`` among codes searched around ``code`` (module docstring).

    Args:
        model: a :class:`~shapeprog.pointcloud.infer.CloudModel` (its :meth:`decode` is used).
        code: the predicted code ``(H,)``.
        cloud: the normalised input ``(N, 3)`` (canonical frame); at most ``points`` of it are used.
        schedule: ``(samples, sigma)`` steps (:func:`check_schedule`).
        points: points of the cloud and surface samples per candidate in the selection chamfer.
        seed: the draws of codes, of the cloud subset and of the surface samples.
    """
    steps = check_schedule(schedule)
    code = torch.as_tensor(code).detach().float().reshape(-1)
    target = torch.as_tensor(cloud, dtype=torch.float64)
    g = torch.Generator().manual_seed(int(seed))
    target = selection_target(target, points, g)

    def scores(programs) -> list[float]:
        return selection_chamfers(programs, target, points, seed)

    first = model.decode(code[None])[0]
    best_cd = scores([first])[0]
    best_prog = first if math.isfinite(best_cd) else None
    start_cd, best_code, decodes, improved = best_cd, code, 1, 0
    for samples, sigma in steps:
        codes = best_code[None] + sigma * torch.randn(samples, code.numel(), generator=g)
        programs = model.decode(codes)
        found = False
        for z, program, cd in zip(codes, programs, scores(programs)):
            if cd < best_cd:
                best_cd, best_prog, best_code, found = cd, program, z, True
        decodes += samples
        improved += int(found)
    return SearchResult(best_prog, best_code, best_cd, start_cd, decodes, improved)


def selection_target(cloud, points: int, generator: torch.Generator) -> torch.Tensor:
    """``cloud`` ``(N, 3)`` as float64, or ``points`` of its points drawn with ``generator`` when it has more:
    the target of :func:`selection_chamfers` (the latent search draws its codes from the same generator
    afterwards)."""
    target = torch.as_tensor(cloud, dtype=torch.float64)
    if len(target) > points:
        target = target[torch.randperm(len(target), generator=generator)[:points]]
    return target


def selection_chamfers(programs: Sequence[Optional[Program]], target: torch.Tensor, points: int = SEARCH_POINTS,
                       seed: int = 0) -> list[float]:
    """The selection chamfer of each program against ``target`` ``(M, 3)`` (the normalised input, already
    subsampled): the program aligned as :func:`aligned_corners`, ``points`` surface samples (the same seed for
    every candidate: equal footing), chamfer with ``eps = 0``; ``inf`` where :func:`aligned_corners` gives
    None."""
    out = []
    target = torch.as_tensor(target, dtype=torch.float64)
    for corners in aligned_corners(programs):
        if corners is None:
            out.append(math.inf)
            continue
        sg = torch.Generator().manual_seed(int(seed))
        with torch.no_grad():
            pred, _ = sample_surface(corners, points, generator=sg)
        out.append(float(chamfer(pred, target, eps=0.0)))
    return out


def aligned_corners(programs: Sequence[Optional[Program]]) -> list[Optional[torch.Tensor]]:
    """The corners ``(L, 8, 3)`` float64 of each program aligned as :func:`~shapeprog.pointcloud.infer.infer`
    aligns its result (:func:`~shapeprog.pointcloud.normalize.align_program`: scaled to the canonical diagonal,
    its box centred), None for a program that is None, executes to no cuboid or has no extent.

    The programs run together (:func:`~shapeprog.execute.execute_batch`: the same numbers as one by one,
    several times faster), twice: once as decoded, to measure each box, and once scaled."""
    out: list[Optional[torch.Tensor]] = [None] * len(programs)
    live = [i for i, p in enumerate(programs) if p is not None]
    aligned, offsets, rows = [], [], []
    for i, corners in zip(live, _executed([programs[i] for i in live])):
        try:
            canon, off = _align_executed(programs[i], corners)
        except ValueError:
            continue
        aligned.append(canon)
        offsets.append(off)
        rows.append(i)
    for i, corners, off in zip(rows, _executed(aligned), offsets):
        if len(corners):
            out[i] = corners.double() + torch.from_numpy(off)
    return out


def _executed(programs: Sequence[Program]) -> list[torch.Tensor]:
    """Executed corners of each program (``(0, 8, 3)`` where execution fails): one batch, or one by one when
    a program of the batch fails."""
    if not programs:
        return []
    try:
        with torch.no_grad():
            return [shape.corners for shape in execute_batch(list(programs))]
    except ValueError:
        return [_corners_of(p) for p in programs]
