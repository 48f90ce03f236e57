"""The editor's controls: one per free parameter of a program, and the edit a control change makes.

:func:`controls` lists the free parameters of a ShapeAssembly :class:`~shapeprog.lang.Program` or of a
macro program (:class:`~shapeprog.macros.lang.MacroProgram`) as :class:`Control` objects (name, kind,
range, current value, where it sits in the printed text, which leaf cuboids it moves). :func:`apply`
sets controls to new values and returns the edited program: it changes the AST, prints it with the
language's printer and parses the text back with the language's parser, so an edit is exactly an edit
of the text (no second interpreter). Errors are :class:`~shapeprog.errors.EditError`, located in the
printed program.

ShapeAssembly controls (names as :func:`shapeprog.execute.parameter_names`, ``block:statement:field``):

========================  ======  =====================================================================
statement field           kind    range
========================  ======  =====================================================================
Cuboid l, h, w            float   [:data:`MIN_DIM`, :data:`MAX_DIM`] (the root bbox included)
Cuboid aligned            bool    (not for bbox lines)
attach x1 .. z2           float   [0, 1]
attach b                  choice  the cuboids declared before the line in the block, not the subject
squeeze b, c              choice  as attach b
squeeze face              choice  :data:`shapeprog.lang.FACES`
squeeze u, v              float   [0, 1]
reflect / translate axis  choice  X, Y, Z
translate n               int     [1, :data:`shapeprog.limits.MAX_TRANSLATE_COPIES`]
translate d               float   [0, 1]
========================  ======  =====================================================================

A float range is widened to hold the current value (a hand-written program may have 1.2 as an attach
coordinate). A sub-program's ``bbox = Cuboid(...)`` dims that equal its ``Program_m`` line's dims in the
parent (every corpus program) have no control of their own: the parent's control sets both, so the two
stay equal (as :func:`shapeprog.fit.fit` does).

Macro program controls are the arguments of its lines (``line:function.parameter``, e.g.
``2:four_legs.s``): numbers are floats (base functions' ranges as above; a macro's float parameter
[min(0, value), max(:data:`MAX_DIM`, value)]), a base translate count an int, booleans, faces and axes
literals, cuboid arguments choices among ``bbox`` and the names bound by earlier lines. A hierarchical
macro program (:class:`~shapeprog.macros.hierarchy.MacroHierarchy`, what ``refactor -o`` writes) has every
block's macro controls, named ``block:line:function.parameter`` (``Program_1:1:nfunc_15.x0``); a
sub-program's bbox dims have none (its parent's cuboid sets its extent).

Example:
    >>> from shapeprog.lang import parse, to_text
    >>> p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
    ...           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> c = {c.name: c for c in controls(p)}
    >>> c["Program_0:2:attach.y2"].kind, c["Program_0:2:attach.y2"].low, c["Program_0:2:attach.y2"].cuboids
    ('float', 0.0, (0,))
    >>> print(to_text(apply(p, {"Program_0:2:attach.y2": 0.25})), end="")
    bbox = Cuboid(1.0, 1.0, 1.0, True)
    cube0 = Cuboid(0.5, 0.2, 0.5, True)
    attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.25, 0.5)
"""
from __future__ import annotations

import dataclasses
import weakref
from typing import Mapping

import torch

from .. import limits
from ..errors import EditError, ExecutionError, ParseError
from ..execute import ExecutionPlan, program_parameters
from ..lang import AXES, FACES, Attach, Block, Cuboid, Program, Reflect, Squeeze, Translate, parse, statement_lines
from ..lang import statement_text, to_text
from ..macros.hierarchy import MacroHierarchy
from ..macros.lang import MacroProgram
from ..macros.library import Library
from .control import (_ARG_FIELDS, _FLOAT_RANGE, BOOL, CHOICE, FLOAT, INT, KINDS, MAX_DIM, MIN_DIM, PAGE_DECIMALS,
                      Control, Value, _arg_columns, _head, _influence, _moved, _range, _Spec, page_value)
from .macro_controls import _hier_apply, _hier_influence, _hier_specs, _macro_apply, _macro_influence, _macro_specs

__all__ = ["BOOL", "CHOICE", "FLOAT", "INT", "KINDS", "MAX_DIM", "MIN_DIM", "PAGE_DECIMALS", "Control", "apply",
           "controls", "page_value"]

def _sa_specs(program: Program) -> list[_Spec]:
    lines = statement_lines(program)
    blocks = {b.name: bi for bi, b in enumerate(program.blocks)}
    pindex: dict = {}  # (block, statement, field) -> executor parameter index
    for bi, b in enumerate(program.blocks):
        for si, s in enumerate(b.statements):
            for f in {Cuboid: ("l", "h", "w"), Attach: ("x1", "y1", "z1", "x2", "y2", "z2"),
                      Squeeze: ("u", "v"), Reflect: (), Translate: ("d",)}[type(s)]:
                pindex[(bi, si, f)] = len(pindex)
    tied = set()  # child bbox dims set by the parent's Program_m line
    ties: dict = {}
    for bi, b in enumerate(program.blocks):
        for si, s in enumerate(b.statements):
            if isinstance(s, Cuboid) and s.name in blocks and s.name != b.name:
                ci = blocks[s.name]
                box = program.blocks[ci].statements[0]
                for f in ("l", "h", "w"):
                    if getattr(box, f) == getattr(s, f):
                        tied.add((ci, 0, f))
                        ties[(bi, si, f)] = (ci, 0, f)
    indent = 0 if program.flat else 1
    out = []
    for bi, b in enumerate(program.blocks):
        declared: list[str] = []
        for si, s in enumerate(b.statements):
            line = lines[bi][si] + 1
            text = statement_text(s)
            cols = _arg_columns(text)
            head = f"line {line} {_head(s)}"
            for k, f in enumerate(_ARG_FIELDS[type(s)]):
                slot = (bi, si, f)
                if slot in tied:
                    continue
                v = getattr(s, f)
                col = indent + cols[k] + 1
                name = f"{b.name}:{si}:{type(s).__name__.lower()}.{f}"
                common = dict(name=name, value=v, label=f"{head} {f}", line=line, column=col)
                slots = (slot,) + ((ties[slot],) if slot in ties else ())
                extra_lines = tuple(lines[t[0]][t[1]] + 1 for t in slots[1:])
                if f in ("a",) or (isinstance(s, Cuboid) and f == "aligned" and s.name == "bbox"):
                    continue  # the subject is structure; the bbox's aligned flag does nothing
                if f in ("b", "c"):
                    choices = tuple(n for n in declared if n != s.a)
                    if v not in choices:
                        choices += (v,)
                    ctl = Control(kind=CHOICE, choices=choices, lines=(line,), **common)
                elif f == "aligned":
                    ctl = Control(kind=BOOL, lines=(line,), **common)
                elif f == "face":
                    ctl = Control(kind=CHOICE, choices=FACES, lines=(line,), **common)
                elif f == "axis":
                    ctl = Control(kind=CHOICE, choices=AXES, lines=(line,), **common)
                elif f == "n":
                    ctl = Control(kind=INT, low=1, high=limits.MAX_TRANSLATE_COPIES, lines=(line,), **common)
                else:
                    lo, hi = _range(*_FLOAT_RANGE.get(f, (0.0, 1.0)), v)
                    ctl = Control(kind=FLOAT, low=lo, high=hi, lines=(line,) + extra_lines, **common)
                params = tuple(pindex[t] for t in slots if t in pindex)
                out.append(_Spec(ctl, slots, params))
            if isinstance(s, Cuboid):
                declared.append(s.name)
    return out


def _sa_apply(program: Program, specs: list[tuple[_Spec, Value]], file: str) -> Program:
    stmts = [list(b.statements) for b in program.blocks]
    for spec, v in specs:
        for bi, si, f in spec.slots:
            stmts[bi][si] = dataclasses.replace(stmts[bi][si], **{f: v})
    edited = Program(tuple(Block(b.name, tuple(s)) for b, s in zip(program.blocks, stmts)), program.flat)
    text = to_text(edited)
    try:
        return parse(text, file)
    except ParseError as e:
        one = specs[0][0].control if len(specs) == 1 else None
        raise EditError(e.reason, e.file, e.line, e.column, e.token, control=None if one is None else one.name,
                        value=None if one is None else specs[0][1]) from None


def _sa_influence(program: Program, specs: list[_Spec]) -> list[tuple[int, ...]]:
    plan = ExecutionPlan([program], dtype=torch.float64)
    x = program_parameters(program, torch.float64).requires_grad_(True)
    shape = plan.run([x])[0]
    moved = _moved(shape.corners, x)
    lines = statement_lines(program)
    made = shape.line.tolist()
    return _influence(specs, moved, made, lambda spec: lines[spec.slots[0][0]][spec.slots[0][1]],
                      lambda spec: (spec.slots[0][0], spec.slots[0][1]))


def _is_hier(program) -> bool:
    return isinstance(program, MacroHierarchy)


def _is_macro(program) -> bool:
    if isinstance(program, MacroProgram) or _is_hier(program):
        return True
    if not isinstance(program, Program):
        raise TypeError(f"expected a ShapeAssembly Program or a MacroProgram, got {type(program).__name__}")
    return False


_CACHE: dict = {}  # id(program) -> (weak reference, library, specs): a session asks again for the same program
_CACHE_SIZE = 8


def _specs(program, library) -> list[_Spec]:
    hit = _CACHE.get(id(program))
    if hit is not None and hit[0]() is program and hit[1] is library:
        return hit[2]
    specs = _specs_uncached(program, library)
    if len(_CACHE) >= _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[id(program)] = (weakref.ref(program), library, specs)
    return specs


def _specs_uncached(program, library) -> list[_Spec]:
    if _is_macro(program):
        lib = Library() if library is None else library
        return _hier_specs(program, lib) if _is_hier(program) else _macro_specs(program, lib)
    return _sa_specs(program)


def controls(program, library=None, cuboids: bool = True) -> list[Control]:
    """One :class:`Control` per free parameter of ``program``, in text order.

    Args:
        program: a :class:`~shapeprog.lang.Program` or a :class:`~shapeprog.macros.lang.MacroProgram`.
        library: the :class:`~shapeprog.macros.library.Library` a macro program calls (besides its own
            definitions; default: the base functions only). Ignored for ShapeAssembly programs.
        cuboids: also find the leaf cuboids each control moves (one execution and one backward pass per
            leaf); left empty when False or when the program does not execute.

    Returns:
        The controls; names are unique.
    """
    specs = _specs(program, library)
    if not cuboids:
        return [s.control for s in specs]
    try:
        if _is_macro(program):
            lib = Library() if library is None else library
            leaves = (_hier_influence if _is_hier(program) else _macro_influence)(program, lib, specs)
        else:
            leaves = _sa_influence(program, specs)
    except ExecutionError:
        return [s.control for s in specs]
    return [dataclasses.replace(s.control, cuboids=c) for s, c in zip(specs, leaves)]


def apply(program, values: Mapping[str, Value], library=None, file: str = "<edit>"):
    """The program with the controls named in ``values`` set to the given values.

    The edited AST is printed and parsed back (:func:`shapeprog.lang.parse`, or
    :meth:`shapeprog.macros.library.Library.parse` for a macro program), so the result is the program of
    the edited text, checked by the language; ``apply(p, {c.name: c.value for c in controls(p)})`` prints
    to the same text as ``p``.

    Args:
        program: a ShapeAssembly :class:`~shapeprog.lang.Program` or a macro program.
        values: control name -> new value (a float or an int for float controls, an int (or an integral
            float) for int controls, a bool, or one of a choice's strings).
        library: the library a macro program calls (see :func:`controls`).
        file: the file name errors carry.

    Raises:
        EditError: an unknown control name, a value of the wrong type or outside the control's range, or
            an edited program that the language refuses; located at the control's token in the printed
            program (or at the language's error).
    """
    if not isinstance(values, Mapping):
        raise TypeError(f"`values` must be a mapping of control names to values, got {type(values).__name__}")
    specs = {s.control.name: s for s in _specs(program, library)}
    chosen = []
    for name, v in values.items():
        spec = specs.get(name)
        if spec is None:
            near = ", ".join(sorted(specs)[:3])
            raise EditError(f"no such control (the program's controls are named like {near})", file, 1, 1, "",
                            control=str(name), value=v)
        chosen.append((spec, spec.control.check(v, file)))
    if not chosen:
        return program
    if _is_macro(program):
        lib = Library() if library is None else library
        return (_hier_apply if _is_hier(program) else _macro_apply)(program, lib, chosen, file)
    return _sa_apply(program, chosen, file)
