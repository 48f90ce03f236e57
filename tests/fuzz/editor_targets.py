"""Fuzz targets for the program editors' edits: control assignments fed to :func:`shapeprog.editor.apply`
(then executed) and :func:`csgnet.editor.apply` (then rendered).

An input is text: the first line picks a program (its index modulo the list), each further line is
``name<TAB>value`` with the value read as ``True``/``False``, a number or else a string, the way a page
or a script hands values over. Only the editors' own errors (and, after a ShapeAssembly edit, an
execution error) may escape.
"""
from __future__ import annotations

import warnings

from csgnet.editor import CSGEditError
from csgnet.editor import apply as csg_apply
from csgnet.editor import controls as csg_controls
from csgnet.lang import parse as csg_parse
from shapeprog import corpus
from shapeprog.editor import apply, controls
from shapeprog.errors import EditError, ExecutionError, ParseWarning
from shapeprog.execute import execute
from shapeprog.lang import parse

from fuzz.engine import Target

__all__ = ["TARGETS"]

with warnings.catch_warnings():
    warnings.simplefilter("ignore", ParseWarning)  # the flat example's stray comma
    _SA = [parse(corpus.read("chair", 173)), parse(corpus.read("table", 33075)),
           parse(corpus.example_text("ex-0.txt"))]
_CSG = [csg_parse("c(32,32,28)s(32,32,20)-"), csg_parse("cy(32,32,32,12,24)sp(40,32,32,8)-", 3)]


def _value(text: str):
    if text in ("True", "False"):
        return text == "True"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _read(data: bytes, programs):
    lines = data.decode("utf-8", "replace").split("\n")
    try:
        k = int(lines[0].strip()[:4] or 0)
    except ValueError:
        k = len(lines[0])
    values = {}
    for ln in lines[1:]:
        name, _, v = ln.partition("\t")
        values[name] = _value(v)
    return programs[k % len(programs)], values


def _seeds(programs, control_list) -> list[bytes]:
    out = []
    for k, p in enumerate(programs):
        cs = control_list(p)
        for start in range(0, len(cs), max(1, len(cs) // 6)):
            body = "".join(f"\n{c.name}\t{c.value}" for c in cs[start:start + 3])
            out.append(f"{k}{body}".encode())
    return out


def _run_sa(data: bytes):
    program, values = _read(data, _SA)
    edited = apply(program, values)
    return execute(edited).corners.flatten().tolist()


def _run_csg(data: bytes):
    program, values = _read(data, _CSG)
    edited = csg_apply(program, values)
    return [float(len(edited.tokens))]


TARGETS = [
    Target("editor/shapeassembly-values", _seeds(_SA, lambda p: controls(p, cuboids=False)), _run_sa,
           (EditError, ExecutionError), 2.0),
    Target("editor/csg-values", _seeds(_CSG, csg_controls), _run_csg, (CSGEditError,), 1.0),
]


# -- hierarchical macro programs (what `refactor -o` writes) and their controls
from shapeprog.errors import ParseError  # noqa: E402
from shapeprog.macros import hierarchy, load_library, refactor  # noqa: E402
from shapeprog.macros.execute import execute_hierarchy  # noqa: E402

_LIB = load_library("chair")
_HTEXT = [refactor(parse(corpus.read("chair", i)), _LIB, category="chair", shape_id=i).text for i in (173, 42220)]
_H = [hierarchy.parse(t, "m.txt", _LIB) for t in _HTEXT]


def _run_htext(data: bytes):
    from shapeprog.limits import decode

    h = hierarchy.parse(decode(data, "m.txt"), "m.txt")
    assert hierarchy.parse(hierarchy.to_text(h), "m.txt") == h, "the printed program does not parse back"
    return execute_hierarchy(h).corners.flatten().tolist()


def _run_hvalues(data: bytes):
    program, values = _read(data, _H)
    return execute_hierarchy(apply(program, values, _LIB), _LIB).corners.flatten().tolist()


TARGETS += [
    Target("macros/hierarchy-text", [t.encode() for t in _HTEXT], _run_htext, (ParseError, ExecutionError), 2.0),
    Target("editor/macro-hierarchy-values", _seeds(_H, lambda p: controls(p, _LIB, cuboids=False)), _run_hvalues,
           (EditError, ExecutionError), 2.0),
]
