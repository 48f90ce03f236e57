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
block's macro controls, named ``block:line:function.parameter`` (``Program_1:1:nfunc_14.x0``); a
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
import math
import re
import weakref
from dataclasses import dataclass
from typing import Mapping, Union

from .. import limits
from ..errors import EditError, ExecutionError, ParseError
from ..lang import AXES, FACES, Attach, Block, Cuboid, Program, Reflect, Squeeze, Translate, parse, statement_lines
from ..lang import statement_text, to_text

__all__ = ["BOOL", "CHOICE", "FLOAT", "INT", "KINDS", "MAX_DIM", "MIN_DIM", "PAGE_DECIMALS", "Control", "apply",
           "controls", "page_value"]

FLOAT, INT, BOOL, CHOICE = "float", "int", "bool", "choice"
#: The kinds of control.
KINDS = (FLOAT, INT, BOOL, CHOICE)
#: Smallest cuboid extent a control offers (the executor's valid range, as :func:`shapeprog.fit.fit`).
MIN_DIM = 0.01
#: Largest cuboid extent a control offers (corpus maximum: 2.788); a larger current value widens it.
MAX_DIM = 4.0

Value = Union[float, int, bool, str]


@dataclass(frozen=True)
class Control:
    """One free parameter of a program.

    Attributes:
        name: unique within the program (``Program_1:3:attach.y2``; ``2:four_legs.s`` for macro programs).
        kind: ``'float'``, ``'int'``, ``'bool'`` or ``'choice'``.
        value: the current value.
        low, high: the range of a float or int (None otherwise), both included.
        choices: the values of a choice (empty otherwise).
        label: a short description for people (``'line 5 attach(cube0, bbox) y2'``).
        line, column: 1-based place of the value's token in the printed program.
        lines: 1-based lines whose text the control changes (two for a shared sub-program bbox).
        cuboids: indices (executed leaf order) of the leaf cuboids the control moves: those whose
            corners have a non-zero derivative with respect to it (float and int), or those that the
            same line's floats move or the line creates (bool and choice). Empty when not computed.
    """

    name: str
    kind: str
    value: Value
    low: float | None = None
    high: float | None = None
    choices: tuple = ()
    label: str = ""
    line: int = 1
    column: int = 1
    lines: tuple[int, ...] = ()
    cuboids: tuple[int, ...] = ()

    def check(self, value, file: str = "<edit>") -> Value:
        """``value`` in this control's type, or :class:`EditError` (wrong type, not finite, out of range,
        not a choice)."""
        def bad(reason):
            return EditError(reason, file, self.line, self.column, str(self.value), control=self.name, value=value)

        if self.kind == FLOAT:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad(f"expected a number, got {type(value).__name__} {value!r}")
            v = float(value)
            if not math.isfinite(v) or not self.low <= v <= self.high:
                raise bad(f"value {value!r} is outside [{self.low!r}, {self.high!r}]")
            return v
        if self.kind == INT:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                    isinstance(value, float) and not (math.isfinite(value) and value.is_integer())):
                raise bad(f"expected an integer, got {type(value).__name__} {value!r}")
            v = int(value)
            if not self.low <= v <= self.high:
                raise bad(f"value {value!r} is outside [{int(self.low)}, {int(self.high)}]")
            return v
        if self.kind == BOOL:
            if not isinstance(value, bool):
                raise bad(f"expected True or False, got {type(value).__name__} {value!r}")
            return value
        if not isinstance(value, str) or value not in self.choices:
            raise bad(f"{value!r} is not one of {', '.join(map(str, self.choices))}")
        return value


#: Decimals a float slider's value keeps (a browser's 0.30000000000000004 arrives as 0.3).
PAGE_DECIMALS = 9


def page_value(control: "Control | None", value):
    """A value as a page's widget sent it, made what :meth:`Control.check` takes: a float slider's number rounded
    to :data:`PAGE_DECIMALS` decimals, an int slider's to the nearest integer. Anything else (another type, a
    non-finite number, a control the page does not know) is passed on unchanged, for the check to refuse with
    its located :class:`EditError`.

    Example:
        >>> c = Control("Program_0:1:cuboid.h", FLOAT, 0.5, low=0.01, high=4.0)
        >>> page_value(c, 0.30000000000000004), page_value(c, float("nan")) != page_value(c, float("nan"))
        (0.3, True)
    """
    if control is None or isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return value
    if control.kind == FLOAT:
        return round(float(value), PAGE_DECIMALS)
    if control.kind == INT:
        return int(round(value))
    return value


@dataclass(frozen=True)
class _Spec:
    """A control and the places it writes: ``slots`` of (block index, statement index, field) for
    ShapeAssembly, (line index, argument index) for macro programs; ``params`` its indices in the
    executor's parameter vector."""

    control: Control
    slots: tuple
    params: tuple[int, ...] = ()


# ----------------------------------------------------------------------------- text positions

_ARG_FIELDS = {
    Cuboid: ("l", "h", "w", "aligned"),
    Attach: ("a", "b", "x1", "y1", "z1", "x2", "y2", "z2"),
    Squeeze: ("a", "b", "c", "face", "u", "v"),
    Reflect: ("a", "axis"),
    Translate: ("a", "axis", "n", "d"),
}
_FLOAT_RANGE = {"l": (MIN_DIM, MAX_DIM), "h": (MIN_DIM, MAX_DIM), "w": (MIN_DIM, MAX_DIM)}


def _arg_columns(text: str) -> list[int]:
    """0-based offsets of the arguments of ``f(a, b, ...)`` in ``text`` (the printer's ', ' separators)."""
    start = text.index("(") + 1
    out = [start]
    for m in re.finditer(r", ", text[start:]):
        out.append(start + m.end())
    return out


def _range(lo: float, hi: float, v: float) -> tuple[float, float]:
    return (min(lo, v), max(hi, v))


def _head(s) -> str:
    if isinstance(s, Cuboid):
        return f"{s.name} = Cuboid"
    if isinstance(s, Attach):
        return f"attach({s.a}, {s.b})"
    if isinstance(s, Squeeze):
        return f"squeeze({s.a}, {s.b}, {s.c})"
    return f"{type(s).__name__.lower()}({s.a})"


# ----------------------------------------------------------------------------- ShapeAssembly


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
    import torch

    from ..execute import ExecutionPlan, program_parameters

    plan = ExecutionPlan([program], dtype=torch.float64)
    x = program_parameters(program, torch.float64).requires_grad_(True)
    shape = plan.run([x])[0]
    moved = _moved(shape.corners, x)
    lines = statement_lines(program)
    made = shape.line.tolist()
    return _influence(specs, moved, made, lambda spec: lines[spec.slots[0][0]][spec.slots[0][1]],
                      lambda spec: (spec.slots[0][0], spec.slots[0][1]))


#: Derivatives below this share of a leaf's largest one count as zero when finding the cuboids a control moves.
_GRAD_TOL = 1e-6


def _moved(corners, x):
    """(L, P) derivatives of each leaf's randomly weighted corner sum with respect to each parameter, and
    (L,) the size below which a leaf's derivative counts as zero."""
    import torch

    L, P = corners.shape[0], x.shape[0]
    grads = torch.zeros(L, P, dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    for leaf in range(L if P else 0):
        w = torch.rand(8, 3, generator=g, dtype=corners.dtype) + 0.5  # no cancellation between corners
        (grad,) = torch.autograd.grad((corners[leaf] * w).sum(), x, retain_graph=True, allow_unused=True)
        if grad is not None:
            grads[leaf] = grad.detach().to(torch.float64)
    # a path that cancels exactly (a squeeze overriding a declared extent) leaves rounding noise
    tol = _GRAD_TOL * grads.abs().amax(1).clamp_min(1e-6) if P else torch.zeros(L, dtype=torch.float64)
    return grads, tol


def _influence(specs, moved, made, line_of, key_of) -> list[tuple[int, ...]]:
    """Leaves per control: a number's by its derivative (the sum over the numbers it sets); a discrete
    one's are its line's numbers' leaves and the leaves its line created."""
    grads, tol = moved

    def leaves_of(params) -> set[int]:
        d = grads[:, list(params)].sum(1)
        return set(_nonzero(d.abs() > tol))

    by_line: dict = {}
    for spec in specs:
        if spec.params:
            by_line.setdefault(key_of(spec), set()).update(leaves_of(spec.params))
    out = []
    for spec in specs:
        if spec.params and spec.control.kind == FLOAT:
            leaves = leaves_of(spec.params)
        else:
            ln = line_of(spec)
            leaves = by_line.get(key_of(spec), set()) | {k for k, m in enumerate(made) if m == ln}
        out.append(tuple(sorted(leaves)))
    return out


def _nonzero(mask) -> list[int]:
    return mask.nonzero().flatten().tolist()


# ----------------------------------------------------------------------------- macro programs


def _macro_specs(program, library) -> list[_Spec]:
    from ..macros.lang import BOOL as T_BOOL, CUBE, FLOAT as T_FLOAT, Linear, Literal, Name, def_text

    lib = library.with_program(program)
    offset = sum(def_text(d).count("\n") + 1 for d in program.defs)  # each definition, then a blank line
    names = ["bbox"]
    out = []
    k = 0  # free parameter index
    for i, call in enumerate(program.lines):
        line = offset + i + 1
        text = f"{', '.join(call.rets)} = " if call.rets else ""
        cols = _arg_columns(f"{text}{call.func}({', '.join(str(a) for a in call.args)})")
        fn = lib[call.func]
        head = f"line {line} {text}{call.func}"
        for j, (a, p) in enumerate(zip(call.args, fn.params)):
            common = dict(name=f"{i}:{call.func}.{p.name}", label=f"{head} {p.name}", line=line, column=cols[j] + 1,
                          lines=(line,))
            if isinstance(a, Linear):
                v = a.value
                if fn.is_base and call.func == "translate" and p.name == "n":
                    ctl = Control(kind=INT, value=int(v) if float(v).is_integer() else v, low=1,
                                  high=limits.MAX_TRANSLATE_COPIES, **common)
                else:
                    if fn.is_base:
                        lo, hi = _FLOAT_RANGE.get(p.name, (0.0, 1.0))
                    else:
                        lo, hi = 0.0, MAX_DIM
                    lo, hi = _range(lo, hi, v)
                    ctl = Control(kind=FLOAT, value=v, low=lo, high=hi, **common)
                out.append(_Spec(ctl, ((i, j),), (k,)))
                k += 1
            elif p.type == CUBE and isinstance(a, Name):
                choices = tuple(names) if a.name in names else tuple(names) + (a.name,)
                out.append(_Spec(Control(kind=CHOICE, value=a.name, choices=choices, **common), ((i, j),)))
            elif isinstance(a, Literal):
                if p.type == T_BOOL:
                    if i == 0:
                        continue  # the bbox's aligned flag does nothing
                    out.append(_Spec(Control(kind=BOOL, value=a.value, **common), ((i, j),)))
                elif p.type != T_FLOAT:
                    choices = FACES if a.value in FACES else AXES
                    out.append(_Spec(Control(kind=CHOICE, value=a.value, choices=choices, **common), ((i, j),)))
        if i > 0:
            names += list(call.rets)
    return out


def _macro_edit(program, specs: list[tuple[_Spec, Value]], block=None):
    """The macro program with the values written at the specs' slots (``(line, arg)``, or
    ``(block, line, arg)`` when ``block`` is given: only that block's slots)."""
    from ..macros.lang import Call, Linear, MacroProgram, Name, Literal

    lines = [list(c.args) for c in program.lines]
    for spec, v in specs:
        for slot in spec.slots:
            if block is not None:
                if slot[0] != block:
                    continue
                slot = slot[1:]
            i, j = slot
            a = lines[i][j]
            if isinstance(a, Linear):
                lines[i][j] = Linear.const(float(v))
            elif isinstance(a, Name):
                lines[i][j] = Name(v)
            else:
                lines[i][j] = Literal(v)
    return MacroProgram(program.defs, tuple(Call(c.func, tuple(a), c.rets) for c, a in zip(program.lines, lines)))


def _refused(e: ParseError, specs) -> EditError:
    one = specs[0][0].control if len(specs) == 1 else None
    return EditError(e.reason, e.file, e.line, e.column, e.token, control=None if one is None else one.name,
                     value=None if one is None else specs[0][1])


def _macro_apply(program, library, specs: list[tuple[_Spec, Value]], file: str):
    from ..macros.lang import to_text as macro_text

    try:
        return library.parse(macro_text(_macro_edit(program, specs)), file)
    except ParseError as e:
        raise _refused(e, specs) from None


def _macro_influence(program, library, specs: list[_Spec]) -> list[tuple[int, ...]]:
    import torch

    from ..macros.execute import MacroPlan, program_parameters

    plan = MacroPlan([program], library, dtype=torch.float64)
    x = program_parameters(program, torch.float64).requires_grad_(True)
    shape = plan.run([x])[0]
    moved = _moved(shape.corners, x)
    source = plan.compiled[0].expansion.source
    made = [source[k] for k in shape.line.tolist()]
    return _influence(specs, moved, made, lambda spec: spec.slots[0][0], lambda spec: spec.slots[0][0])


# ----------------------------------------------------------------------------- hierarchical macro programs


def _hier_specs(h, library) -> list[_Spec]:
    """Every block's macro controls, named ``block:line:function.parameter``; a sub-program's bbox dims
    have none (the parent's cuboid sets its extent: the executor scales the sub-program into it)."""
    from ..macros.hierarchy import block_line_offsets
    from ..macros.lang import parameters

    offsets = block_line_offsets(h)
    out = []
    k0 = 0
    for bi, (name, p) in enumerate(zip(h.names, h.programs)):
        for spec in _macro_specs(p, library):
            c = spec.control
            (i, j), = spec.slots
            if bi > 0 and i == 0:
                continue
            ctl = dataclasses.replace(c, name=f"{name}:{c.name}", label=f"{name} {c.label}", line=c.line + offsets[bi],
                                      lines=tuple(x + offsets[bi] for x in c.lines))
            out.append(_Spec(ctl, ((bi, i, j),), tuple(k0 + x for x in spec.params)))
        k0 += len(parameters(p))
    return out


def _hier_apply(h, library, specs: list[tuple[_Spec, Value]], file: str):
    from ..macros import hierarchy

    edited = h.replace(_macro_edit(p, specs, bi) for bi, p in enumerate(h.programs))
    try:
        return hierarchy.parse(hierarchy.to_text(edited), file, library)
    except ParseError as e:
        raise _refused(e, specs) from None


def _hier_influence(h, library, specs: list[_Spec]) -> list[tuple[int, ...]]:
    import torch

    from ..execute import ExecutionPlan
    from ..macros.execute import compile_hierarchy, hierarchy_parameters

    c = compile_hierarchy(h, library)
    x = hierarchy_parameters(h, torch.float64).requires_grad_(True)
    shape = ExecutionPlan([c.program], dtype=torch.float64).run([c.numbers(x)])[0]
    moved = _moved(shape.corners, x)
    lines = statement_lines(c.program)
    where = {lines[bi][si]: (bi, b.expansion.source[k])
             for bi, (b, order) in enumerate(zip(c.blocks, c.orders)) for si, k in enumerate(order)}
    made = [where[ln] for ln in shape.line.tolist()]
    key = lambda spec: spec.slots[0][:2]  # noqa: E731
    return _influence(specs, moved, made, key, key)


# ----------------------------------------------------------------------------- public API


def _is_hier(program) -> bool:
    from ..macros.hierarchy import MacroHierarchy  # standard library only: cheap

    return isinstance(program, MacroHierarchy)


def _is_macro(program) -> bool:
    from ..macros.lang import MacroProgram  # standard library only: cheap

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
        from ..macros.library import Library

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
            from ..macros.library import Library

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
        from ..macros.library import Library

        lib = Library() if library is None else library
        return (_hier_apply if _is_hier(program) else _macro_apply)(program, lib, chosen, file)
    return _sa_apply(program, chosen, file)
