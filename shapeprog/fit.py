"""Fit a program's continuous parameters to a point cloud (the reference's ``example_fit``).

:func:`fit` runs Adam on ``chamfer(surface samples of execute(program, params), target cloud)
+ reg * ||params - params0||^2`` over every continuous number of the program, through the one
differentiable executor; the structure is fixed. It returns a :class:`FitResult`.

See docs/shapeassembly.md ("Fitting") for the differences from the reference script.

Example:
    >>> import torch, shapeprog
    >>> from shapeprog.sampling import sample_surface
    >>> p = shapeprog.parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.5, 0.5, True)\\n"
    ...                     "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> g = torch.Generator().manual_seed(0)
    >>> target = shapeprog.execute(p).corners * torch.tensor([1.2, 1.0, 1.0])
    >>> pts, _ = sample_surface(target, 2048, generator=g)
    >>> r = shapeprog.fit(p, pts, steps=60, lr=0.01, generator=g)
    >>> r.losses[-1] < r.losses[0]
    True
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import torch

from .errors import ExecutionError
from .execute import ExecutionPlan, parameter_names, program_parameters
from .lang import Cuboid, Program, replace_numbers, to_text
from .metrics import chamfer
from .sampling import sample_surface

__all__ = ["MAX_DECIMALS", "MAX_LR", "MAX_REG", "MAX_STEPS", "FitResult", "fit"]

#: The largest Adam learning rate :func:`fit` takes (the numbers are lengths of a shape of size about 1; the
#: default is 1e-3).
MAX_LR = 1.0
#: The largest weight of the pull towards the starting numbers.
MAX_REG = 1e6
#: The most Adam steps of one :func:`fit` (the default is 400).
MAX_STEPS = 1_000_000
#: The most decimals of the written numbers (float64 holds about 16 significant digits).
MAX_DECIMALS = 12


@dataclass
class FitResult:
    """Outcome of :func:`fit`.

    Attributes:
        program: the fitted program (numbers rounded to ``decimals``).
        text: ``to_text(program)``, formatted like the corpus.
        params: (P,) float tensor, the fitted numbers before rounding (text order).
        losses: the loss (chamfer + penalty) at every step.
        chamfer: the chamfer term at every step.
        seconds: wall time of the optimisation.
        stopped: None when every step ran; else why the fit stopped early: a step took the numbers where
            the program no longer executes to finite cuboids (an :class:`~shapeprog.errors.ExecutionError`,
            e.g. an attachment that degenerates), so that step was undone and the result is the numbers
            before it.
    """

    program: Program
    text: str
    params: torch.Tensor
    losses: list[float] = field(default_factory=list)
    chamfer: list[float] = field(default_factory=list)
    seconds: float = 0.0
    stopped: str | None = None


def _sharing(program: Program, names: list[str]) -> torch.Tensor:
    """Index map full -> free parameter: child bbox dims share their Program_m line's dims.
    ``names``: :func:`parameter_names` of ``program``."""
    pos = {n: i for i, n in enumerate(names)}
    owner = list(range(len(names)))
    for b in program.blocks:
        for si, s in enumerate(b.statements):
            if isinstance(s, Cuboid) and s.name.startswith("Program_"):
                for f in ("l", "h", "w"):
                    owner[pos[f"{s.name}:0:cuboid.{f}"]] = pos[f"{b.name}:{si}:cuboid.{f}"]
    return torch.tensor(owner)


def _bounds(names: list[str], dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper bound of every parameter (``names``: :func:`parameter_names`)."""
    lo, hi = [], []
    for n in names:
        if ":cuboid." in n:
            lo.append(0.01)
            hi.append(float("inf"))
        else:
            lo.append(0.0)
            hi.append(1.0)
    return torch.tensor(lo, dtype=dtype, device=device), torch.tensor(hi, dtype=dtype, device=device)


def fit(
    program: Program,
    points: torch.Tensor,
    steps: int = 400,
    lr: float = 1e-3,
    reg: float = 1e-3,
    decimals: int = 3,
    samples: int = 2048,
    target_samples: int | None = 4096,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
) -> FitResult:
    """Optimise the continuous parameters of ``program`` so that its surface matches ``points``.

    Args:
        program: the program to fit (its structure is kept).
        points: (N, 3) float target cloud (same frame as the executed program: y up, centred).
        steps: Adam steps.
        lr: Adam learning rate.
        reg: weight of the L2 penalty on moving away from the starting parameters.
        decimals: precision of the written program (the corpus uses 3).
        samples: surface samples drawn from the program at every step.
        target_samples: random subset of the target used at every step (None: all points).
        generator: torch.Generator for the sampling (reproducible fits).
        dtype: execution dtype.

    Returns:
        A :class:`FitResult`. A step whose numbers no longer execute to finite cuboids is undone and the fit
        stops there with the last numbers that executed (:attr:`FitResult.stopped` says where and why).

    Raises:
        ValueError: bad ``points``, ``steps``, ``lr``, ``reg`` or ``decimals`` (outside ``[0, MAX_STEPS]``,
            ``(0, MAX_LR]``, ``[0, MAX_REG]``, ``[0, MAX_DECIMALS]``).
        ExecutionError: ``program`` itself does not execute to finite cuboids.
    """
    if not isinstance(points, torch.Tensor):
        points = torch.as_tensor(points)
    if points.dim() != 2 or points.shape[1] != 3 or points.shape[0] < 1:
        raise ValueError(f"`points` must have shape (N, 3), got {tuple(points.shape)}")
    if isinstance(steps, bool) or not isinstance(steps, int) or not 0 <= steps <= MAX_STEPS:
        raise ValueError(f"`steps` must be an integer from 0 to {MAX_STEPS} (MAX_STEPS), got {steps!r}")
    if isinstance(lr, bool) or not isinstance(lr, (int, float)) or not 0 < lr <= MAX_LR:
        raise ValueError(f"`lr` must be a number in (0, {MAX_LR:g}] (MAX_LR), got {lr!r}")
    if isinstance(reg, bool) or not isinstance(reg, (int, float)) or not 0 <= reg <= MAX_REG:
        raise ValueError(f"`reg` must be a number in [0, {MAX_REG:g}] (MAX_REG), got {reg!r}")
    if isinstance(decimals, bool) or not isinstance(decimals, int) or not 0 <= decimals <= MAX_DECIMALS:
        raise ValueError(f"`decimals` must be an integer from 0 to {MAX_DECIMALS} (MAX_DECIMALS), got {decimals!r}")
    device = points.device
    target = points.to(dtype)
    full0 = program_parameters(program, dtype, device)
    names = parameter_names(program)
    owner = _sharing(program, names).to(device)
    free_idx = torch.unique(owner)
    remap = torch.full((full0.shape[0],), -1, dtype=torch.int64, device=device)
    remap[free_idx] = torch.arange(free_idx.numel(), device=device)
    gather = remap[owner]
    z0 = full0[free_idx].clone()
    z = z0.clone().requires_grad_(True)
    lo, hi = _bounds(names, dtype, device)
    lo, hi = lo[free_idx], hi[free_idx]
    opt = torch.optim.Adam([z], lr=lr)
    plan = ExecutionPlan([program], dtype, device)  # compiled once, run every step
    res = FitResult(program, "", full0)
    t0 = time.perf_counter()
    previous = z.detach().clone()
    for step in range(steps + 1):  # run k executes the numbers after k updates; the last run only checks them
        opt.zero_grad()
        try:
            shape = plan.run([z[gather]])[0]
        except ExecutionError as e:
            if step == 0:
                raise  # the starting program itself
            with torch.no_grad():
                z.copy_(previous)  # undo the update that left the executable numbers
            res.stopped = f"step {step} of {steps} undone and the fit stopped: {e}"
            break
        if step == steps:
            break
        previous = z.detach().clone()
        pts, _ = sample_surface(shape.corners, samples, generator=generator)
        tgt = target
        if target_samples is not None and target.shape[0] > target_samples:
            sel = torch.randperm(target.shape[0], generator=generator, device=device)[:target_samples]
            tgt = target[sel]
        cd = chamfer(pts, tgt)
        loss = cd + reg * (z - z0).square().sum()
        loss.backward()
        opt.step()
        with torch.no_grad():
            z.copy_(torch.maximum(torch.minimum(z, hi), lo))
        res.losses.append(float(loss.detach()))
        res.chamfer.append(float(cd.detach()))
    res.seconds = time.perf_counter() - t0
    final = z.detach()[gather]
    fitted = replace_numbers(program, [round(v, decimals) for v in final.tolist()])
    res.program, res.params = fitted, final
    res.text = to_text(fitted, decimals=decimals)
    return res
