"""The state of a ShapeMOD discovery run (:class:`Discovery`: macros, active set, orderings, history,
as ``state.json``), the sub-programs it works on (:class:`Nodes`) and the objective f over them
(:func:`evaluate`, best programs searched through a caller's ``concurrent.futures.Executor``).
:mod:`shapeprog.macros.discover` runs the rounds.
"""
from __future__ import annotations

import hashlib
import json
import math
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from shapeio.files import parse_json

from ..errors import ParseError
from .grammar import Line
from .lang import BASE, MacroDef
from .library import Library
from .objective import WEIGHTS, beam_search, exact_search, fit_options, templates

__all__ = [
    "Discovery",
    "Nodes",
    "evaluate",
    "nodes_from_subprograms",
]


@dataclass
class Nodes:
    """The collection: per sub-program its key, its orderings' lines and their signatures."""

    keys: list[str]
    lines: list[list[tuple[Line, ...]]]
    sigs: list[list[tuple]]

    def digest(self) -> str:
        h = hashlib.sha256()
        for k, ls in zip(self.keys, self.lines):
            h.update(f"{k}:{len(ls)};".encode())
        return h.hexdigest()[:16]


def nodes_from_subprograms(subs, max_orders: int = 1000) -> Nodes:
    """:class:`Nodes` from :class:`~shapeprog.macros.subprogram.SubProgram` s (their first ``max_orders``
    orderings)."""
    keys, lines, sigs = [], [], []
    for s in subs:
        if not s.orders or not s.cubes:
            continue
        os = s.orders[:max_orders]
        keys.append(s.key)
        lines.append([s.lines(o) for o in os])
        sigs.append([o.signature for o in os])
    return Nodes(keys, lines, sigs)


# ----------------------------------------------------------------------------- evaluation (the hot spot)


def _eval_chunk(lib_text: str, active: tuple[str, ...], items: list[list[tuple[Line, ...]]], cfg: dict,
                per_order: bool):
    """Worker: best programs of some sub-programs. Returns per item (f, called function names) or, with
    ``per_order``, per item the f of every ordering."""
    lib = Library.from_text(lib_text) if lib_text else Library()
    tpls = templates(lib)
    tpls = [t for t in tpls if t.name in BASE or t.name in active]
    nm = len(active)
    out = []
    for orders in items:
        scores = []
        best, best_f = (), math.inf
        for lines in orders:
            opts = fit_options(lines, tpls, cfg["abs_max_error"], cfg["prec"])
            if cfg["search"] == "beam":
                calls, f = beam_search(opts, nm, cfg["abs_beam_size"])
            else:
                calls, f = exact_search(opts, nm)
            scores.append(f)
            if f < best_f:
                best, best_f = calls, f
        out.append(scores if per_order else (best_f, [o.func for o in best]))
    return out


def _map(executor: Executor | None, fn, chunks: list) -> list:
    if executor is None:
        return [fn(*c) for c in chunks]
    futs = [executor.submit(fn, *c) for c in chunks]
    return [f.result() for f in futs]


def evaluate(library: Library, active: Sequence[str], items: Sequence[Sequence[tuple[Line, ...]]], cfg: Mapping,
             executor: Executor | None = None, per_order: bool = False):
    """Best programs of ``items`` (each a list of orderings' lines) under ``library`` restricted to
    ``active`` macros, through ``executor`` in chunks of ``cfg['chunk']``.

    Returns:
        ``(mean f, usage)`` with usage the number of calls per function, or with ``per_order`` the list
        of per-ordering f of every item.
    """
    text = library.to_text()
    ch = max(1, int(cfg["chunk"]))
    chunks = [(text, tuple(active), list(items[i:i + ch]), dict(cfg), per_order) for i in range(0, len(items), ch)]
    res = [r for part in _map(executor, _eval_chunk, chunks) for r in part]
    if per_order:
        return res
    usage: dict[str, int] = {}
    for _, funcs in res:
        for f in funcs:
            usage[f] = usage.get(f, 0) + 1
    return float(np.mean([f for f, _ in res])) if res else 0.0, usage


def _options_chunk(lib_text: str, names: tuple[str, ...], items, cfg: dict):
    """Worker for the milp: per item, per ordering, (n lines, [(func, pos, k, cost + 10 * error)])."""
    lib = Library.from_text(lib_text) if lib_text else Library()
    tpls = [t for t in templates(lib) if t.name in BASE or t.name in names]
    out = []
    for orders in items:
        per = []
        for lines in orders:
            opts = fit_options(lines, tpls, cfg["abs_max_error"], cfg["prec"])
            per.append((len(lines), [(o.func, o.pos, o.k, o.cost + WEIGHTS["err"] * o.error)
                                     for row in opts for o in row]))
        out.append(per)
    return out


# ----------------------------------------------------------------------------- state


@dataclass
class Discovery:
    """The state of a discovery run.

    Attributes:
        macros: every accepted macro in definition order (``nfunc_<k>``).
        active: the names of the macros in L.
        current: per node, the indices of its current orderings.
        history: per finished round, a dict of figures (f before/after, |L|, candidates, seconds...).
        counter: the next macro number.
    """

    macros: list[MacroDef]
    active: list[str]
    current: list[list[int]]
    history: list[dict] = field(default_factory=list)
    counter: int = 0

    def full_library(self) -> Library:
        return Library(self.macros)

    def library(self) -> Library:
        """L as a library: the active macros, where each one that calls a removed macro is inlined to base
        calls (so the library holds exactly |L| - 5 macros)."""
        full = self.full_library()
        active = set(self.active)
        out = []
        for m in self.macros:
            if m.name not in active:
                continue
            if any(c.func not in BASE and c.func not in active for c in m.body):
                m = full.expand_macro(m.name)
            out.append(m)
        return Library(out)

    def digest(self) -> str:
        """A digest of the macros, active set and history (what a continued run starts from)."""
        key = json.dumps([Library(self.macros).to_text(), self.active, self.history], sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    def to_json(self, nodes_digest: str, cfg: Mapping, seed: int, start: str | None = None) -> str:
        return json.dumps({"format": "shapemod-discovery/1", "nodes": nodes_digest, "seed": seed, "config": dict(cfg),
                           "start": start,
                           "library": Library(self.macros).to_text(), "active": self.active, "current": self.current,
                           "history": self.history, "counter": self.counter}, indent=1)

    @classmethod
    def from_library(cls, library: Library, nodes: "Nodes", prior: Sequence[float] = (),
                     source: str = "library") -> "Discovery":
        """A state that continues discovery from ``library`` (a shipped or earlier library): its macros, all
        active; every ordering of every node (:func:`discover` runs filterBadOrders with the library before
        its first round, as the end of a round does, since a library file does not record the orderings);
        one history entry per ``prior`` round (its f per sub-program, from the library's header), so the
        rounds that follow are numbered, and seeded, after them. New macros are numbered after the
        largest ``nfunc_<k>`` of the library."""
        nums = [int(m.name[6:]) for m in library.macros if m.name.startswith("nfunc_") and m.name[6:].isdigit()]
        history = [{"round": k + 1, "f_after": float(f), "from": source} for k, f in enumerate(prior)]
        return cls(list(library.macros), [m.name for m in library.macros],
                   [list(range(len(ls))) for ls in nodes.lines], history, max(nums, default=-1) + 1)

    @classmethod
    def from_json(cls, text: str, file: str = "state.json") -> tuple["Discovery", dict]:
        d = parse_json(text, file, ParseError.in_file(file))
        if not isinstance(d, dict) or d.get("format") != "shapemod-discovery/1":
            raise ParseError("not a shapemod discovery state", file, 1, 1, "")
        try:
            fields = [("library", isinstance(d["library"], str)),
                      ("active", isinstance(d["active"], list) and all(isinstance(a, str) for a in d["active"])),
                      ("current", isinstance(d["current"], list) and all(
                          isinstance(c, list) and all(type(o) is int and o >= 0 for o in c) for c in d["current"])),
                      ("history", isinstance(d["history"], list) and all(isinstance(h, dict) for h in d["history"])),
                      ("counter", type(d["counter"]) is int and d["counter"] >= 0),
                      ("config", isinstance(d["config"], dict)), ("nodes", isinstance(d["nodes"], str))]
            bad = [k for k, ok in fields if not ok]
            if bad:
                raise TypeError(f"field {bad[0]!r} does not hold what a discovery state writes there")
            lib = Library.from_text(d["library"], file) if d["library"] else Library()
            state = cls(list(lib.macros), [str(a) for a in d["active"]], [[int(o) for o in c] for c in d["current"]],
                        list(d["history"]), int(d["counter"]))
            for k in ("nodes", "seed", "config"):
                d[k]
        except (KeyError, TypeError, ValueError) as e:
            if isinstance(e, ParseError):
                raise
            raise ParseError(f"a damaged discovery state ({type(e).__name__}: {e})", file, 1, 1, "") from None
        unknown = [a for a in state.active if a not in lib]
        if unknown:
            raise ParseError(f"active macro {unknown[0]!r} is not defined", file, 1, 1, unknown[0])
        return state, d
