"""Controls of macro programs (ShapeMOD :class:`~shapeprog.macros.lang.MacroProgram`) and of hierarchical
refactored programs: their specs, how a set of values is applied (by editing the text and parsing it back), and
which leaf cuboids each control moves. :func:`shapeprog.editor.controls.controls` and ``apply`` dispatch here."""
from __future__ import annotations

import dataclasses

import torch

from .. import limits
from ..errors import EditError, ParseError
from ..execute import ExecutionPlan
from ..lang import AXES, FACES, statement_lines
from ..macros import hierarchy
from ..macros.execute import MacroPlan, compile_hierarchy, hierarchy_parameters, program_parameters
from ..macros.lang import BOOL as T_BOOL, CUBE, FLOAT as T_FLOAT, Call, Linear, Literal, MacroProgram, Name, def_text
from ..macros.lang import parameters, to_text as macro_text
from .control import (_FLOAT_RANGE, BOOL, CHOICE, FLOAT, INT, MAX_DIM, Control, Value, _arg_columns, _influence,
                      _moved, _range, _Spec)

def _macro_specs(program, library) -> list[_Spec]:
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
    try:
        return library.parse(macro_text(_macro_edit(program, specs)), file)
    except ParseError as e:
        raise _refused(e, specs) from None


def _macro_influence(program, library, specs: list[_Spec]) -> list[tuple[int, ...]]:
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
    offsets = hierarchy.block_line_offsets(h)
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
    edited = h.replace(_macro_edit(p, specs, bi) for bi, p in enumerate(h.programs))
    try:
        return hierarchy.parse(hierarchy.to_text(edited), file, library)
    except ParseError as e:
        raise _refused(e, specs) from None


def _hier_influence(h, library, specs: list[_Spec]) -> list[tuple[int, ...]]:
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
