"""Post hoc inference with a discovered library, and the shipped libraries.

:func:`infer` finds a program for one shape (its primitives, or one line of a ``PN_*.txt`` file) that
uses the library's abstractions: the naive program is refactored with the library
(:func:`shapeprog.coder.refactor.refactor`), again on the result while the cost drops (up to ``passes``
calls), as the discovery's wake does round after round for its own shapes.
:func:`load_library` reads a library shipped in ``shapeprog/data/coder_libraries/<category>.txt``.

Example:
    >>> from shapeprog.coder.lang import Library, parse_abstraction
    >>> lib = Library().add(parse_abstraction(
    ...     "Pair(w: Float, h: Float, x: Float, y: Float, z: Float) = SymRef(Move(Cuboid(w,h,w),x,y,z),AX)"))
    >>> r = infer([(0.06, 0.6, 0.06, -0.31, -0.5, -0.3, 0, 0, 0), (0.06, 0.6, 0.06, 0.31, -0.5, -0.3, 0, 0, 0)], lib)
    >>> r.text, r.expanded, r.cost, r.error
    ('Pair(0.06,0.6,-0.31,-0.5,-0.3)', 'SymRef(Move(Cuboid(0.06,0.6,0.06),-0.31,-0.5,-0.3),AX)', 11.0, 0.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from shapeio.files import resolve_shipped

from ..limits import decode
from . import data
from .wake import evaluate, network_best, network_payload
from .execute import order
from .lang import LANG_3D, Library, Num, expand, substitute, to_text
from .objective import naive_program
from .refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT, VALUES, RefactorError, refactor
from .search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS, WAKE_STEP_BUDGET
from .recnet import load_checkpoint

__all__ = ["PASSES", "Inferred", "check_search_budget", "infer", "load_library", "load_network", "shipped_libraries", "shipped_networks"]

_DIR = ("data", "coder_libraries")
PASSES = 3
"""Refactor calls of :func:`infer` at most (each on the previous call's program)."""


@dataclass(frozen=True)
class Inferred:
    """A shape's inferred program.

    Attributes:
        text: the program with abstraction calls.
        expanded: the same in the base language.
        cost: its contribution to F (token cost + 10 · error).
        error: the mean matched distance of its primitives to the shape's.
        stop: why the e-graph stopped (see :class:`~shapeprog.coder.refactor.Refactored`).
    """

    text: str
    expanded: str
    cost: float
    error: float
    stop: str


def _prims(shape) -> tuple:
    if isinstance(shape, str):
        return data.parse_record(shape.strip(), "<shape>", 1).prims
    prims = tuple(tuple(float(v) for v in p) for p in shape)
    if not prims:
        raise ValueError("the shape has no primitives")
    width = len(prims[0])
    if width not in (4, 9) or any(len(p) != width for p in prims):
        raise ValueError(f"a shape is a list of 9-tuples (3D) or 4-tuples (2D); got widths {sorted({len(p) for p in prims})}")
    return order(tuple(round(v, 2) + 0.0 for v in p) for p in prims)


def infer(shape, library: Library, *, passes: int = PASSES, iterations: int = MAX_ITERATIONS,
          max_nodes: int = MAX_ENODES, time_limit: float = TIME_LIMIT, network=None, seed: int = 0,
          search_seconds: float = WAKE_SECONDS, search_batches: int = WAKE_BATCHES,
          search_step_budget: int = WAKE_STEP_BUDGET, values: str = VALUES) -> Inferred:
    """The program of one shape under ``library``.

    Args:
        shape: one line of the ``PN_<category>.txt`` format (``<id>_0_<index>:<program>``), or a list of
            primitives (9-tuples ``(W, H, D, X, Y, Z, RX, RY, RZ)``; 4-tuples with a 2D library).
        library: e.g. :func:`load_library`.
        passes: refactor calls at most, each on the previous one's program (each call is limited by
            ``iterations`` and ``max_nodes``; ``time_limit`` is a safety cap in seconds, not a budget:
            :data:`~shapeprog.coder.refactor.TIME_LIMIT`); stops at the first that does not lower the cost.
        network: a recognition network for ``library`` (:func:`load_network`, a ``(model, vocab)`` pair, or
            a payload of :func:`shapeprog.coder.wake.network_payload`): the refactored program is then a
            candidate of the network wake's search for the shape (the paper's post hoc inference), and the
            cheaper program is kept. seed: seeds that search.
        search_batches, search_step_budget: the network search's budget per step, a count of batches of
            :data:`~shapeprog.coder.search.WAKE_BATCH` samples (:func:`~shapeprog.coder.search.step_batches`:
            the wake's defaults stand for the paper's 1 s per step on an idle CPU). A larger budget is ours, not
            the paper's post hoc inference. search_seconds: a safety cap per step, not the budget
            (:data:`~shapeprog.coder.search.WAKE_SECONDS`).
        values: the e-graph's value schedule (:func:`~shapeprog.coder.refactor.refactor`).

    Raises:
        ParseError: a malformed line. ValueError: primitives of the wrong width, or more than the
        domain's :attr:`~shapeprog.coder.lang.Lang.max_prims`. RefactorError: an e-graph failure.
    """
    prims = _prims(shape)
    lang = library.lang
    if len(prims[0]) != len(lang.prim_fields):
        raise ValueError(f"the library is {lang.name} but the primitives have {len(prims[0])} fields")
    if len(prims) > lang.max_prims:
        raise ValueError(f"the shape has {len(prims)} primitives; at most {lang.max_prims} are allowed")
    if isinstance(passes, bool) or not isinstance(passes, int) or passes < 1:
        raise ValueError(f"passes must be an int >= 1, got {passes!r}")
    check_search_budget(search_seconds, search_batches, search_step_budget)
    naive, env = naive_program(prims)
    naive = substitute(naive, {k: Num(v) for k, v in env.items()})
    best = (naive, evaluate(naive, library, prims))
    if best[1] is None:  # pragma: no cover - the naive program always re-covers its primitives
        raise RefactorError("the naive program does not re-cover the shape")
    stop = "iterations"
    for _ in range(passes):
        r = refactor(best[0], library, iterations=iterations, max_nodes=max_nodes, time_limit=time_limit,
                     values=values)
        stop = r.stop
        got = evaluate(r.expr, library, prims)
        if got is None or got[0] >= best[1][0] - 1e-9:
            break
        best = (r.expr, got)
    if network is not None:
        payload = network if len(network) == 4 else network_payload(*network)
        limits = {"iterations": iterations, "max_nodes": max_nodes, "time_limit": time_limit, "values": values}
        search = {"batch": WAKE_BATCH, "batches": int(search_batches), "step_budget": int(search_step_budget),
                  "seconds": float(search_seconds)}
        expr, cost, err, _ = network_best(best[0], library, prims, payload, limits, search=search, seed=seed)
        if cost is not None and cost < best[1][0] - 1e-9:
            best = (expr, (cost, err))
    e, (cost, err) = best
    return Inferred(to_text(e), to_text(expand(e, library)), cost, err, stop)


def check_search_budget(seconds, batches, step_budget=WAKE_STEP_BUDGET) -> None:
    """Refuse a network-search budget that is not ``seconds > 0`` (finite), ``batches >= 1`` and
    ``step_budget >= 1`` (ints)."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds) or seconds <= 0:
        raise ValueError(f"search_seconds must be a positive finite number, got {seconds!r}")
    if isinstance(batches, bool) or not isinstance(batches, int) or batches < 1:
        raise ValueError(f"search_batches must be an int >= 1, got {batches!r}")
    if isinstance(step_budget, bool) or not isinstance(step_budget, int) or step_budget < 1:
        raise ValueError(f"search_step_budget must be an int >= 1, got {step_budget!r}")


def shipped_networks() -> tuple:
    """The categories with a shipped recognition network (``<category>_recnet.pt``)."""
    folder = resources.files("shapeprog").joinpath(*_DIR)
    if not folder.is_dir():
        return ()
    return tuple(sorted(p.name[:-len("_recnet.pt")] for p in folder.iterdir() if p.name.endswith("_recnet.pt")))


def load_network(category: str) -> tuple:
    """``(model, vocab)``: the recognition network shipped with ``category``'s library (the one its final
    wake used), on the CPU in eval mode; for :func:`infer`'s ``network``.

    Raises:
        ValueError: no network is shipped for ``category``.
    """
    if category not in shipped_networks():
        raise ValueError(f"no shipped recognition network for {category!r}; shipped: "
                         f"{', '.join(shipped_networks()) or 'none'}")
    with resources.as_file(resources.files("shapeprog").joinpath(*_DIR, f"{category}_recnet.pt")) as path:
        model, vocab, _ = load_checkpoint(path, load_library(category))
    return model.eval(), vocab


def shipped_libraries() -> tuple:
    """The categories with a shipped library."""
    folder = resources.files("shapeprog").joinpath(*_DIR)
    if not folder.is_dir():
        return ()
    return tuple(sorted(p.name[:-4] for p in folder.iterdir() if p.name[:-4] in data.CATEGORIES
                        and p.name.endswith(".txt")))


def load_library(name: str) -> Library:
    """A ShapeCoder library: the library file ``name`` when one exists at that path, else the shipped library
    of category ``name`` (``shapeprog/data/coder_libraries/<category>.txt``, one abstraction per line; see
    docs/shapecoder.md for how it was discovered); the rule of :func:`shapeio.files.resolve_shipped`: an
    existing file wins.

    Raises:
        NotShippedError: neither a file nor a shipped category (a ``ValueError``; the message names both and
            lists the shipped categories).
        ParseError: a malformed library file (file, line, column).
    """
    folder = resources.files("shapeprog").joinpath(*_DIR)
    shipped = {c: Path(str(folder.joinpath(f"{c}.txt"))) for c in shipped_libraries()}
    path = resolve_shipped(name, shipped, "ShapeCoder library")
    label = path.name if shipped.get(name) == path else str(path)
    return Library.from_text(decode(path.read_bytes(), label), LANG_3D, file=label)
