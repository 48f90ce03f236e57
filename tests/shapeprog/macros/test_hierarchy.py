"""Hierarchical macro programs (the text ``refactor -o`` writes): text round trip, block structure errors,
execution through the ShapeAssembly executor."""
import pytest
import torch

from shapeprog import corpus, parse
from shapeprog.errors import ParseError
from shapeprog.execute import execute
from shapeprog.macros import Library, load_library, refactor
from shapeprog.macros import hierarchy as H
from shapeprog.macros.execute import compile_hierarchy, execute_hierarchy, hierarchy_parameters

LIB = load_library("chair")
SMALL = ("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nProgram_1 = Cuboid(0.5, 0.5, 0.5, True)\n"
         "attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n\n# Program_1\nbbox = Cuboid(0.5, 0.5, 0.5, True)\n"
         "c = Cuboid(0.1, 0.5, 0.1, True)\nsqueeze(bbox, bbox, top, 0.1, 0.1)\nreflect(X)\n"
         "d = Cuboid(0.1, 0.5, 0.1, True)\nsqueeze(bbox, bbox, top, 0.1, 0.9)\n\n")


@pytest.fixture(scope="module")
def r173():
    return refactor(parse(corpus.read("chair", 173)), LIB, category="chair", shape_id=173)


def test_refactor_text_round_trips_with_and_without_the_library(r173):
    h = H.parse(r173.text, "m.txt", LIB)
    assert H.to_text(h) == r173.text
    assert H.parse(r173.text, "m.txt") == h  # every block carries its definitions
    assert h.names == ("Program_0", "Program_1") and h.keys[1] == "chair/173/Program_1"
    # the cuboid the sub-program fills is named after it, as in the corpus format
    assert "Program_1" in h.programs[0].lines[1].rets


def test_parsing_expands_each_block_once(r173, monkeypatch):
    from shapeprog.macros.library import Library as Lib

    calls = []
    real = Lib.expand
    monkeypatch.setattr(Lib, "expand", lambda self, program: calls.append(program) or real(self, program))
    for lib in (LIB, None):
        calls.clear()
        h = H.parse(r173.text, "m.txt", lib)
        assert len(calls) == len(h.programs) == 2  # the check of each block, reused by the limits check


def test_hierarchy_executes_as_its_shapeassembly_program():
    h = H.parse(SMALL)
    c = compile_hierarchy(h)
    a = execute_hierarchy(h)
    assert a.corners.shape[0] == 3  # a cuboid declared after a reflect keeps its own slot
    assert torch.allclose(execute(c.program).corners, a.corners, atol=1e-6)
    x = hierarchy_parameters(h, torch.float64).requires_grad_(True)
    b = execute_hierarchy(h, params=x, dtype=torch.float64)
    assert torch.allclose(b.corners.float(), a.corners, atol=1e-6)
    b.corners[:, :, 0].sum().backward()
    assert x.grad.abs().sum() > 0
    # the gradients of every corner against central finite differences (float64)
    y = hierarchy_parameters(h, torch.float64).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: execute_hierarchy(h, params=p, dtype=torch.float64).corners, (y,),
                                    eps=1e-6, atol=1e-5)
    # the legs scale into the parent's cuboid: doubling it doubles their width
    big = H.parse(SMALL.replace("Program_1 = Cuboid(0.5,", "Program_1 = Cuboid(1.0,"))
    assert execute_hierarchy(big).dims[0, 0] == pytest.approx(2 * float(a.dims[0, 0]))


@pytest.mark.parametrize("text, where, reason", [
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\n# Program_0\n", (1, 1), "text before the first block header"),
    (SMALL.replace("# Program_0", "# Program_2"), (1, 1), "the first block must be Program_0"),
    (SMALL.replace("Program_1 = Cuboid", "other = Cuboid"), (6, 1), "no earlier block binds a cuboid named Program_1"),
    (SMALL + SMALL.split("\n\n")[1] + "\n\n", (14, 1), "block Program_1 appears twice"),
    (SMALL.replace("c = Cuboid", "Program_0 = Cuboid"), (6, 1), "cuboid Program_0 has no block after this one"),
    (SMALL.replace("Program_1 = Cuboid", "Program_3 = Cuboid"), (1, 1), "cuboid Program_3 has no block after"),
    (SMALL.replace("squeeze(bbox, bbox, top, 0.1, 0.9)", "squeeze(bbox, bbox, up, 0.1, 0.9)"), (12, 21), "face"),
])
def test_structure_errors_are_located_in_the_whole_text(text, where, reason):
    with pytest.raises(ParseError) as e:
        H.parse(text, "h.txt")
    assert (e.value.file, e.value.line, e.value.column) == ("h.txt", *where)
    assert reason in e.value.reason


def test_a_definition_clashing_with_the_library_is_refused(r173):
    name = r173.blocks[0].program.defs[0].name
    text = r173.text.replace(f"def {name}(x0: float", f"def {name}(y0: float", 1)
    text = text.replace("Cuboid(bb_x, x0,", "Cuboid(bb_x, y0,", 1)
    with pytest.raises(ParseError, match="defines differently"):
        H.parse(text, "m.txt", LIB)
    alone = H.parse(text, "m.txt")  # alone it is a valid program, with its own definition
    assert alone.keys == H.parse(r173.text, "m.txt").keys
    assert any(d.name == name and d.params[0].name == "y0" for d in alone.programs[0].defs)


def _nested_copies(levels: int) -> str:
    """Program_k holds Program_{k+1} and 256 translated copies of it: 257**levels leaf cuboids."""
    out = []
    for k in range(levels + 1):
        body = "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"
        if k < levels:
            body += (f"Program_{k + 1} = Cuboid(0.5, 0.5, 0.5, True)\nattach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
                     "translate(X, 256, 0.9)\n")
        else:
            body += "c = Cuboid(0.1, 0.5, 0.1, True)\nattach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
        out.append(f"# Program_{k}\n{body}")
    return "\n".join(out)


def test_the_shapeassembly_limits_hold_for_the_program_a_hierarchy_expands_to():
    one = H.parse(_nested_copies(1), "h.txt")
    assert execute_hierarchy(one).corners.shape[0] == 257
    with pytest.raises(ParseError) as e:  # 257**2 leaves: refused before anything executes
        H.parse(_nested_copies(2), "h.txt")
    assert (e.value.file, e.value.line, e.value.token) == ("h.txt", 1, "# Program_0")
    assert "MAX_CUBOIDS" in e.value.reason
