"""The Baseline macros of the ShapeMOD paper (supplement B): frequent command sequences with constant slots.

One ordering per sub-program (its first, which keeps the text's declaration order inside each grounding
level; the reference picks the "most canonical"); every contiguous command sequence of 2 to
:data:`MAX_LENGTH` base lines (after the bbox line) that occurs in more than ``min_share`` of the
sub-programs becomes a macro; in it a slot is a constant when at least ``const_share`` of the occurrences
agree (discrete slots and cuboid ids: the same value; floats: within ``float_tol`` of the mean, which
becomes the constant, rounded to 2 decimals), else a parameter of its own. Sequences whose macro would
not be valid (e.g. a cuboid id that cannot be a parameter) are skipped. Programs are then written with the
best-program search as for ShapeMOD.

Example:
    >>> from shapeprog.macros.grammar import CuboidLine, SqueezeLine, ReflectLine
    >>> lines = [[CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(0.1, 1.0, 0.1, True),
    ...           SqueezeLine(-1, -1, "top", 0.1 * k, 0.5), ReflectLine("X")] for k in range(1, 6)]
    >>> print(baseline_library(lines).to_text(), end="")
    def base_0(x0: float):
        c0 = Cuboid(0.1, 1.0, 0.1, True)
        squeeze(bbox, bbox, top, x0, 0.5)
    <BLANKLINE>
    def base_1(x0: float):
        squeeze(bbox, bbox, top, x0, 0.5)
        reflect(X)
    <BLANKLINE>
    def base_2(x0: float):
        c0 = Cuboid(0.1, 1.0, 0.1, True)
        squeeze(bbox, bbox, top, x0, 0.5)
        reflect(X)
"""
from __future__ import annotations

from collections import Counter
from typing import Sequence

import numpy as np

from .grammar import BBOX, CuboidLine, Line, command
from .lang import BASE, CUBE, FLOAT, Call, Linear, Literal, MacroDef, MacroError, Name, Param, check_def
from .library import Library
from .objective import _observed

__all__ = ["MAX_LENGTH", "baseline_library"]

#: Longest command sequence considered (base lines).
MAX_LENGTH = 8


def _slots(window: Sequence[Line], cube_start: int) -> list:
    """Per base line, (floats, cube refs, categoricals): cube refs as 'bbox', ('r', m) or ('o', id)."""
    out = []
    for ln in window:
        fl, ids, cs = _observed(ln)
        refs = ["bbox" if i == BBOX else ("r", i - cube_start) if i >= cube_start else ("o", i) for i in ids]
        out.append((fl, refs, cs))
    return out


def baseline_library(programs: Sequence[Sequence[Line]], min_share: float = 0.1, const_share: float = 0.9,
                     float_tol: float = 0.05, max_length: int = MAX_LENGTH) -> Library:
    """The baseline macros of ``programs`` (one line sequence per sub-program, bbox first)."""
    seq_count: Counter = Counter()
    occ: dict[tuple, list] = {}
    for lines in programs:
        cmds = [command(x) for x in lines]
        seen = set()
        cube_before = [0] * len(lines)
        c = 0
        for i in range(1, len(lines)):
            cube_before[i] = c
            if type(lines[i]) is CuboidLine:
                c += 1
        for i in range(1, len(lines)):
            for k in range(2, max_length + 1):
                if i + k > len(lines):
                    break
                key = tuple(cmds[i:i + k])
                occ.setdefault(key, []).append(_slots(lines[i:i + k], cube_before[i]))
                seen.add(key)
        seq_count.update(seen)
    n = len(programs)
    macros: list[MacroDef] = []
    lib = Library()
    for key in sorted(seq_count, key=lambda s: (len(s), s)):
        if seq_count[key] <= min_share * n:
            continue
        d = _macro(f"base_{len(macros)}", key, occ[key], const_share, float_tol)
        try:
            check_def(d, lib.infos())
        except MacroError:
            continue
        macros.append(d)
        lib = Library(macros)
    return lib


def _macro(name: str, cmds: tuple, occs: list, const_share: float, tol: float) -> MacroDef:
    params: list[Param] = []
    counts = Counter()
    body = []
    created = 0

    def new(ptype: str) -> str:
        p = {FLOAT: "x", "bool": "b", "face": "k", "axis": "a", CUBE: "t"}[ptype]
        nm = f"{p}{counts[p]}"
        counts[p] += 1
        params.append(Param(nm, ptype))
        return nm

    m = len(occs)
    for j, cmd in enumerate(cmds):
        info = BASE[cmd]
        fi = ci = di = 0
        args = []
        for p in info.params:
            if p.type == FLOAT:
                vals = np.array([o[j][0][fi] for o in occs], dtype=float)
                fi += 1
                mean = float(vals.mean())
                if (np.abs(vals - mean) <= tol).sum() >= const_share * m:
                    args.append(Linear.const(round(mean, 2)))
                else:
                    args.append(Linear.var(new(FLOAT)))
            elif p.type == CUBE:
                vals = [o[j][1][ci] for o in occs]
                ci += 1
                top, cnt = Counter(map(repr, vals)).most_common(1)[0]
                v = next(x for x in vals if repr(x) == top)
                if cnt >= const_share * m and v != "bbox" and v[0] == "r":
                    args.append(Name(f"c{v[1]}"))
                elif cnt >= const_share * m and v == "bbox":
                    args.append(Name("bbox"))
                else:
                    args.append(Name(new(CUBE)))
            else:
                vals = [o[j][2][di] for o in occs]
                di += 1
                top, cnt = Counter(vals).most_common(1)[0]
                if cnt >= const_share * m:
                    args.append(Literal(top))
                else:
                    args.append(Name(new(p.type)))
        rets = (f"c{created}",) if cmd == "Cuboid" else ()
        created += len(rets)
        body.append(Call(cmd, tuple(args), rets))
    return MacroDef(name, tuple(params), tuple(body))
