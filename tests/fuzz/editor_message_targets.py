"""Fuzz targets for what the editors' pages send: a sequence of messages handled the way the servers handle
them (:func:`shapeprog.editor.page_value` then :meth:`EditSession.set`, ``set_text``, undo / redo / reset,
export; the same for :mod:`csgnet.editor`), without a browser or a server.

An input is text. The first line picks a program (its index modulo the list) and, after a tab, the session's
name (the stem of exported files). Each further line is one message, at most :data:`MAX_MESSAGES`:

* ``set<TAB>control<TAB>value``: a slider, checkbox or drop-down moved (the value read as ``True``/``False``,
  an int, a float such as ``nan`` or ``1e308``, or else a string);
* ``text<TAB>program``: "Run text" with the program (``\\n`` in it stands for a line break);
* ``undo``, ``redo``, ``reset``, ``export`` (into a fresh temporary folder).

No error may escape a message: a refused one returns False and leaves :attr:`error` set to the editor's own
error type, with the program unchanged. After every message the session must be consistent: the current
program is the history's, its printed text parses back to it, and after the last message undoing to the
first state and redoing as many steps gives back the same program. An export writes new files named after
the session, inside the folder, whose text parses back to the current program.
"""
from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

from csgnet.editor import CSGEditError, CSGEditSession
from csgnet.editor import controls as csg_controls
from csgnet.editor import page_value as csg_page_value
from csgnet.lang import ParseError as CSGParseError
from csgnet.lang import parse as csg_parse
from shapeedit import MAX_HISTORY
from shapeprog import corpus
from shapeprog.editor import EditSession, load_program, page_value
from shapeprog.errors import EditError, ExecutionError, ParseError, ParseWarning

from fuzz.engine import Target

__all__ = ["MAX_MESSAGES", "TARGETS"]

#: Messages read from one input (the rest are ignored), so that one input stays within the target's bound.
MAX_MESSAGES = 12

with warnings.catch_warnings():
    warnings.simplefilter("ignore", ParseWarning)  # the flat example's stray comma
    _SA = [(corpus.read("chair", 173), "chair/173.txt"), (corpus.example_text("ex-0.txt"), "ex-0.txt")]
_CSG = ["c(32,32,28)s(32,32,20)-", "cy(32,32,32,12,24)sp(40,32,32,8)-"]


def _value(text: str):
    if text in ("True", "False"):
        return text == "True"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _read(data: bytes, count: int) -> tuple[int, str, list[list[str]]]:
    lines = data.decode("utf-8", "replace").split("\n")
    head, _, name = lines[0].partition("\t")
    try:
        k = int(head.strip()[:4] or 0)
    except ValueError:
        k = len(head)
    return k % count, name, [ln.split("\t", 2) for ln in lines[1:1 + MAX_MESSAGES]]


def _exported(paths, folder: Path, stem: str, text: str, parses_back) -> None:
    assert paths, "an export wrote nothing"
    for p in paths:
        assert p.parent == folder and p.name.startswith(stem + "_edit") and p.is_file(), (p, stem)
    (txt,) = [p for p in paths if p.suffix == ".txt"]
    assert txt.read_text().rstrip("\n") == text.rstrip("\n"), "the exported text is not the program's"
    parses_back(txt.read_text())


def _drive(session, messages, refused: tuple, control, to_control, program_of, parses_back) -> None:
    """Feed ``messages`` to ``session`` as the page's handlers do (``control(session, name)`` finds a control,
    ``to_control(control, value)`` is the editor's ``page_value``); check the session after each."""
    for parts in messages:
        verb = parts[0].strip()
        before = session.program
        if verb == "set" and len(parts) == 3:
            name, value = parts[1], _value(parts[2])
            done = session.set({name: to_control(control(session, name), value)})
        elif verb == "text" and len(parts) >= 2:
            done = session.set_text("\t".join(parts[1:]).replace("\\n", "\n"))
        elif verb in ("undo", "redo", "reset"):
            error = session.error
            done = getattr(session, verb)()
            if not done:  # nothing to move: nothing changes
                assert session.program is before and session.error is error
        elif verb == "export":
            with tempfile.TemporaryDirectory() as folder:
                _exported(session.export(folder), Path(folder), session.name, session.text, parses_back)
            continue
        else:
            continue
        if verb in ("set", "text"):
            assert done == (session.error is None), (done, session.error)
            if not done:
                assert isinstance(session.error, refused), repr(session.error)
                assert session.program is before, "a refused message changed the program"
        assert session.program is program_of(session.history.current), "the program is not the history's"
        parses_back(session.text)
    history = session.history
    assert 1 <= len(history) <= MAX_HISTORY
    last, undone = session.program, 0
    while session.undo():
        undone += 1
    assert session.program is program_of(history.initial)
    assert all(session.redo() for _ in range(undone)) and session.program is last, \
        "undoing to the first state and redoing as many steps did not come back to the last program"


def _sa_control(session, name):
    return next((c for c in session.controls(cuboids=False) if c.name == name), None)


def _run_sa(data: bytes):
    k, name, messages = _read(data, len(_SA))
    text, file = _SA[k]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ParseWarning)
        session = EditSession(text, file, name=name or None)

        def parses_back(t):
            assert load_program(t, file) == session.program, "the printed program does not parse back"

        _drive(session, messages, (EditError, ParseError, ExecutionError), _sa_control, page_value,
               lambda st: st.program, parses_back)
    return session.shape.corners.flatten().tolist()


def _csg_control(session, name):
    return next((c for c in session.controls() if c.name == name), None)


def _run_csg(data: bytes):
    k, name, messages = _read(data, len(_CSG))
    session = CSGEditSession(_CSG[k], name=name)

    def parses_back(t):
        assert csg_parse(t, session.dim) == session.program, "the printed program does not parse back"

    _drive(session, messages, (CSGEditError, CSGParseError), _csg_control, csg_page_value, lambda st: st[0],
           parses_back)
    return [float(session.canvas.sum())]


def _seeds_sa() -> list[bytes]:
    out = []
    for k, (text, file) in enumerate(_SA):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ParseWarning)
            cs = EditSession(text, file).controls(cuboids=False)
        picks = cs[:: max(1, len(cs) // 4)][:4]
        sets = "".join(f"\nset\t{c.name}\t{c.value}" for c in picks)
        out.append(f"{k}\tedited{sets}\nundo\nredo\nreset\nexport".encode())
        if picks:
            c = picks[-1]
            out.append(f"{k}\t../odd name\nset\t{c.name}\tnan\nset\t{c.name}\t{c.value}\nundo\nundo\nredo".encode())
    small = "bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n" \
            "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)"
    out.append(f"0\nset\tProgram_0:1:cuboid.h\t0.30000000000000004\ntext\t{small}\nundo\nredo\nexport".encode())
    return out


def _seeds_csg() -> list[bytes]:
    out = []
    for k, text in enumerate(_CSG):
        cs = csg_controls(csg_parse(text, 3 if "cy(" in text else 2))
        sets = "".join(f"\nset\t{c.name}\t{c.value}" for c in cs[::3])
        choice = next(c for c in cs if c.name.endswith(".kind"))
        out.append(f"{k}\tring{sets}\nset\t{choice.name}\t{choice.choices[-1]}\nundo\nredo\nreset\nexport".encode())
        out.append(f"{k}\t\nset\t{cs[1].name}\t12.6\nset\t{cs[1].name}\tinf\ntext\t{text}\nundo\nexport".encode())
    return out


TARGETS = [
    Target("editor/shapeassembly-messages", _seeds_sa(), _run_sa, (), 3.0),
    Target("editor/csg-messages", _seeds_csg(), _run_csg, (), 2.0),
]
