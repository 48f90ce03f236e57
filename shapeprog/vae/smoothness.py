"""Interpolation smoothness (ShapeAssembly Table 6): how much a program and its shape change from one step to
the next along straight lines between random latents.

:func:`interpolation_smoothness` draws ``sequences`` pairs of latents from N(0, I), decodes ``steps`` programs
along each line (:func:`shapeprog.vae.interpolate`, both ends included, non-rejecting) and measures every pair of
consecutive steps:

* geometric step: the chamfer distance between the two executed shapes, each scaled to unit bounding-box
  diagonal and sampled with the *same* seed (:func:`shapeprog.vae.genmetrics.chamfer_clouds`), so that two equal
  shapes score exactly 0 and the sampling noise of two draws (about 0.035 at 1,024 points) does not swamp the
  step;
* program step: the token edit distance between the two program texts (numbers to 3 decimals;
  :func:`shapeprog.vae.structure.edit_distance` over :func:`~shapeprog.vae.structure.program_tokens`), where
  every changed number is one edit; and the same between their structures (every number abstracted,
  :func:`~shapeprog.vae.structure.structure_key`), which counts only changed lines, names, faces and counts.

Lower is smoother. The same figures between each line's two ends say how far a line travels.
"""
from __future__ import annotations

import time
from typing import Optional

import numpy as np
import torch

from ..metrics import chamfer
from .decode import interpolate
from .genmetrics import CHAMFER_POINTS, chamfer_clouds, execute_samples
from .structure import edit_distance, program_tokens, structure_key

__all__ = ["MAX_SEQUENCES", "MAX_STEPS", "interpolation_smoothness", "step_distances"]

#: Limits of one measurement (the paper: 100 sequences of 100 steps).
MAX_SEQUENCES, MAX_STEPS = 10_000, 1_000


def step_distances(programs, points: int = CHAMFER_POINTS, seed: int = 0) -> tuple[list, list, list]:
    """The geometric, program and structure distances of consecutive ``programs`` (a sequence), and of its two
    ends last.

    Returns:
        ``(geometric, program, structure)``: ``len(programs)`` values each, the first ``len - 1`` between
        consecutive programs and the last between the first and the last one; a geometric value is None where
        either shape did not execute to a cuboid.
    """
    corners, _ = execute_samples(programs)
    clouds = [None if c is None else chamfer_clouds([c], points, seed=seed)[0] for c in corners]
    tokens = [program_tokens(p) for p in programs]
    shapes = [program_tokens(structure_key(p)) for p in programs]
    pairs = [(i, i + 1) for i in range(len(programs) - 1)] + [(0, len(programs) - 1)]
    geometric, program, structure = [], [], []
    for i, j in pairs:
        a, b = clouds[i], clouds[j]
        geometric.append(None if a is None or b is None else float(chamfer(a, b, eps=0.0)))
        program.append(0 if tokens[i] == tokens[j] else edit_distance(tokens[i], tokens[j]))
        structure.append(0 if shapes[i] == shapes[j] else edit_distance(shapes[i], shapes[j]))
    return geometric, program, structure


def interpolation_smoothness(vae, sequences: int = 100, steps: int = 100, seed: int = 0,
                             points: int = CHAMFER_POINTS, log=None) -> dict:
    """Mean geometric and program steps along ``sequences`` lines of ``steps`` decodes between random latents.

    Args:
        vae: a ShapeAssembly :class:`~shapeprog.vae.VAE`.
        sequences: lines (1 to :data:`MAX_SEQUENCES`).
        steps: decodes per line, both ends included (2 to :data:`MAX_STEPS`).
        seed: the latents' generator (pairs drawn in order) and the surface samples' seed.
        points: surface points per shape.
        log: a function taking a line of progress text.

    Returns:
        ``{"sequences", "steps", "pairs": consecutive pairs measured geometrically, "geometric": mean chamfer per
        step, "program": mean token edits per step, "structure": mean token edits of the structures per step,
        "unchanged": % of steps whose structure did not change, "geometric_ends", "program_ends",
        "structure_ends": the same distances between each line's two ends, "tokens": mean tokens per program,
        "seconds"}``.
    """
    if not (isinstance(sequences, int) and 1 <= sequences <= MAX_SEQUENCES):
        raise ValueError(f"sequences must be an integer in [1, {MAX_SEQUENCES}], got {sequences!r}")
    if not (isinstance(steps, int) and 2 <= steps <= MAX_STEPS):
        raise ValueError(f"steps must be an integer in [2, {MAX_STEPS}], got {steps!r}")
    t0 = time.perf_counter()
    gen = torch.Generator().manual_seed(int(seed))
    hidden = vae.decoder.hidden_dim
    geo, prog, struct, geo_ends, prog_ends, struct_ends, tokens = [], [], [], [], [], [], []
    for s in range(sequences):
        za, zb = torch.randn(2, hidden, generator=gen)
        programs = [r.program for r in interpolate(vae, za, zb, steps)]
        g, p, st = step_distances(programs, points, seed)
        geo += [v for v in g[:-1] if v is not None]
        prog += p[:-1]
        struct += st[:-1]
        struct_ends.append(st[-1])
        if g[-1] is not None:
            geo_ends.append(g[-1])
        prog_ends.append(p[-1])
        tokens += [len(program_tokens(x)) for x in (programs[0], programs[-1])]
        if log is not None and (s + 1) % 10 == 0:
            log(f"{s + 1}/{sequences} sequences ({time.perf_counter() - t0:.0f} s)")

    def mean(values) -> Optional[float]:
        return float(np.mean(values)) if values else None

    return {"sequences": sequences, "steps": steps, "pairs": len(geo), "geometric": mean(geo),
            "program": mean(prog), "structure": mean(struct),
            "unchanged": 100.0 * float(np.mean([v == 0 for v in struct])),
            "geometric_ends": mean(geo_ends), "program_ends": mean(prog_ends), "structure_ends": mean(struct_ends),
            "tokens": mean(tokens),
            "seconds": round(time.perf_counter() - t0, 1)}
