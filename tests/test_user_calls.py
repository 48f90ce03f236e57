"""The obvious Python calls: a program or its text is accepted, anything else is a TypeError naming the call to
make first; a refactored program expands to its whole base program; the ShapeCoder objective refuses what it
cannot score; reprs are one short line."""
import pytest
import torch

import shapeprog
from shapeprog import coder, corpus, macros

CHAIR = corpus.read("chair", 173)


def test_execute_takes_program_or_text():
    p = shapeprog.parse(CHAIR)
    a, b = shapeprog.execute(CHAIR), shapeprog.execute(p)
    assert torch.equal(a.corners, b.corners) and len(a) == 6
    assert [len(s) for s in shapeprog.execute_batch([CHAIR, p])] == [6, 6]
    assert shapeprog.to_text(CHAIR) == shapeprog.to_text(p) == CHAIR
    from shapeprog.execute import parameter_names, program_parameters
    assert torch.equal(program_parameters(CHAIR), program_parameters(p))
    assert parameter_names(CHAIR) == parameter_names(p)


@pytest.mark.parametrize("bad, hint", [(3, r"shapeprog\.parse\(text\)"), (b"bbox", r"decode"),
                                       (None, r"shapeprog\.parse\(text\)")])
def test_execute_refuses_other_values(bad, hint):
    with pytest.raises(TypeError, match=r"^shapeprog\.execute takes a shapeprog Program or its text, got .*" + hint):
        shapeprog.execute(bad)
    with pytest.raises(TypeError, match="takes a list of programs"):
        shapeprog.execute_batch(CHAIR)


@pytest.fixture(scope="module")
def refactored():
    lib = macros.load_library("chair")
    return lib, macros.refactor(CHAIR, lib)


def test_refactor_takes_text_and_expand_returns_the_whole_program(refactored):
    lib, r = refactored
    assert r.text == macros.refactor(shapeprog.parse(CHAIR), lib).text
    base = macros.expand(r, lib)
    p = shapeprog.parse(CHAIR)
    assert isinstance(base, shapeprog.lang.Program) and not base.flat
    assert [b.name for b in base.blocks] == [b.name for b in p.blocks]
    got, want = shapeprog.execute(base), shapeprog.execute(p)
    assert len(got) == len(want) == 6
    # the macro program's numbers are its best fit: within its refactoring error of the input
    assert float((got.corners - want.corners).abs().max()) < 0.05
    # the hierarchy (as an object or as the text refactor writes) executes to the same cuboids
    assert torch.equal(macros.execute(r, lib).corners, got.corners)
    assert torch.equal(macros.execute(r.text, lib).corners, got.corners)
    assert shapeprog.to_text(macros.expand(r.text, lib)) == shapeprog.to_text(base)
    # one block's text (its definitions repeat the library's) is a macro program
    assert macros.program_stats(r.blocks[0].text, lib) == r.blocks[0].stats
    assert macros.to_text(shapeprog.macros.library.as_macro_program(r.blocks[1].text, lib)) == r.blocks[1].text


def test_macro_calls_refuse_other_values(refactored):
    lib, r = refactored
    with pytest.raises(TypeError, match=r"^shapeprog\.macros\.refactor takes .* got Refactored .*macros\.expand"):
        macros.refactor(r, lib)
    with pytest.raises(TypeError, match=r"^shapeprog\.macros\.refactor takes a shapeprog\.macros\.Library"):
        macros.refactor(CHAIR, "chair")
    with pytest.raises(TypeError, match=r"^shapeprog\.macros\.execute takes a MacroProgram or its text, got Program: "
                                        r".*shapeprog\.macros\.refactor"):
        macros.execute(shapeprog.parse(CHAIR), lib)
    with pytest.raises(TypeError, match=r"^shapeprog\.macros\.expand takes a MacroProgram or its text, got Program"):
        macros.expand(shapeprog.parse(CHAIR), lib)
    with pytest.raises(TypeError, match=r"^shapeprog\.execute takes .* got Refactored: .*macros\.expand"):
        shapeprog.execute(r)


def test_coder_calls_take_program_or_text():
    text = "Union(Move(Cuboid(0.5,0.1,0.5),0,-0.2,0),SymRef(Move(Cuboid(0.1,0.4,0.1),-0.3,0,0),AX))"
    e = coder.parse(text)
    assert coder.execute(text) == coder.execute(e)
    assert coder.run(text).primitives() == coder.run(e).primitives()
    assert coder.expand(text, coder.Library()) == e
    assert coder.objective([text]) == coder.objective([e]) == coder.program_cost(e)
    from shapeprog.coder.objective import token_counts
    assert token_counts(text) == token_counts(e)
    with pytest.raises(TypeError, match=r"^shapeprog\.coder\.execute takes a ShapeCoder program .* got int"):
        coder.execute(3)


def test_objective_refuses_what_it_cannot_score():
    lib = coder.load_library("chair")
    r = coder.Inferred(text="Cuboid(0.1,0.2,0.3)", expanded="Cuboid(0.1,0.2,0.3)", cost=3.0, error=0.0,
                       stop="saturated")
    with pytest.raises(TypeError, match=r"got Inferred: an inference result, not a program: .*"
                                        r"coder\.parse\(result\.text, library\)"):
        coder.objective([r, r], lib)
    with pytest.raises(TypeError, match="takes a list of programs, got one Inferred"):
        coder.objective(r, lib)
    with pytest.raises(TypeError, match="takes a list of programs, got one str"):
        coder.objective("Cuboid(0.1,0.2,0.3)", lib)
    with pytest.raises(coder.ProgramError):  # a Float expression is no program
        coder.objective([coder.parse("Add(a,1.0)", expect=coder.Type.FLOAT)], lib)
    # what it can score: the program's cost plus the library's omega
    e = coder.parse(r.text, lib)
    omega = sum(coder.omega(ab, lib) for ab in lib.abstractions)
    assert coder.objective([e], lib) == pytest.approx(7.0 + omega)  # 1 function, 3 free floats


def test_reprs_are_one_short_line(refactored):
    lib, r = refactored
    shown = {
        "coder library": repr(coder.load_library("chair")),
        "macro library": repr(lib),
        "program": repr(shapeprog.parse(CHAIR)),
        "macro program": repr(r.program),
        "coder program": repr(coder.naive_program(coder.data.load("chair")[0].prims)[0]),
    }
    for what, text in shown.items():
        assert "\n" not in text and len(text) <= 160, (what, text)
    assert shown["coder library"] == ("<shapeprog.coder.Library (3d): 21 abstractions: A8, A9, A12, A13, A14, A16, "
                                      "A17, A18, ... (13 more)>")
    assert shown["macro library"].startswith("Library(12 macros: nfunc_3, ") and shown["macro library"].endswith(
        "... (4 more))")
    assert shown["program"] == ("<Program (corpus format): 2 blocks, 14 statements, 5 cuboids besides the bboxes; "
                                "print with shapeprog.to_text>")
    assert shown["coder program"].startswith("<Union(Move(Cuboid(S_0_0_,") and len(shown["coder program"]) == 82
