"""The VAE over macro programs (ShapeMOD Appendix C): layout, trees, masked losses, overfit, sampling."""
import pytest
import torch

from shapeprog.errors import ParseError
from shapeprog.macros import Library, load_library
from shapeprog.macros.execute import execute_hierarchy
from shapeprog.macros.hierarchy import parse as parse_hierarchy, to_text
from shapeprog.macros.refactored import load_refactored
from shapeprog.vae.layout import NUM_SLOTS, LineLayout, macro_program_to_tree, tree_to_macro_program
from shapeprog.vae.losses import macro_line_losses, macro_program_loss
from shapeprog.vae.macro_decode import decode_macro, encode_macro, sample_macro
from shapeprog.vae.macro_model import MacroVAE

LIB_TEXT = """def legs(s: float, t: float, b: bool, a: axis):
    c = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, top, t, 0.5)
    reflect(a)
    d = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, top, t, 1.0 - t)

def hang(x: float, y: float, z: float, t0: cube, f: face, t1: cube):
    c = Cuboid(x, y, z, True)
    squeeze(t0, t1, f, 0.5, 0.5)
"""


def _leaves(shape):
    c = shape.corners.reshape(shape.corners.shape[0], -1)
    return torch.tensor(sorted(map(tuple, c.tolist())))


@pytest.fixture(scope="module")
def chairs():
    progs, _ = load_refactored("chair", ids=range(170, 420))
    return load_library("chair"), progs


def test_layout_sizes_of_a_hand_built_library():
    lay = LineLayout(Library.from_text(LIB_TEXT))
    assert lay.commands == ("start", "stop", "Cuboid", "attach", "squeeze", "reflect", "translate", "legs", "hang")
    # floats: attach has 6; cubes: squeeze and hang have 2; faces: squeeze, hang 1; axes 1; bools: legs 1
    assert lay.counts == {"float": 6, "cube": 2, "face": 1, "axis": 1, "bool": 1}
    assert lay.width == 9 + 6 + 2 * NUM_SLOTS + 6 + 3 + 1
    assert lay.max_created == 2
    assert lay.used("legs") == {"float": (True, True, False, False, False, False), "cube": (False, False),
                                "face": (False,), "axis": (True,), "bool": (True,)}
    assert lay.used("hang")["cube"] == (True, True) and lay.used("hang")["float"][:4] == (True, True, True, False)
    assert lay.slices["float"].start == 9 and lay.slices["bool"].stop == lay.width
    base = LineLayout(Library())
    assert base.counts == {"float": 6, "cube": 2, "face": 1, "axis": 1, "bool": 1} and base.max_created == 1


def test_round_trip_on_shipped_refactored_chairs(chairs):
    lib, progs = chairs
    lay = LineLayout(lib)
    assert len(progs) >= 20
    for sid, h in progs.items():
        tree = macro_program_to_tree(h, lay, file=f"chair/{sid}.txt")
        assert sum(1 for _ in tree.nodes()) == len(h.programs)
        back = tree_to_macro_program(tree, lay)
        a, b = execute_hierarchy(h, lib), execute_hierarchy(back, lib)
        assert a.corners.shape == b.corners.shape
        assert torch.allclose(_leaves(a), _leaves(b), atol=1e-4)


def test_created_cuboids_index_children():
    lib = Library.from_text(LIB_TEXT)
    lay = LineLayout(lib)
    text = ("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nProgram_1, cube1 = legs(0.1, 0.2, True, X)\n\n"
            "# Program_1\nbbox = Cuboid(0.1, 1.0, 0.1, True)\nc = Cuboid(0.05, 1.0, 0.05, True)\n"
            "squeeze(bbox, bbox, top, 0.5, 0.5)\n\n")
    h = parse_hierarchy(text, library=lib)
    tree = macro_program_to_tree(h, lay)
    assert len(tree.children) == 3 and tree.children[0] is None and tree.children[2] is None
    assert tree.children[1] is not None and tree.creators(lay) == [(0, 0), (1, 0), (1, 1)]
    back = tree_to_macro_program(tree, lay, decimals=3)
    assert to_text(back).replace("cube0 = Cuboid", "c = Cuboid") == text


def test_a_call_outside_the_library_is_a_located_error():
    lib = Library.from_text(LIB_TEXT)
    h = parse_hierarchy("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nc, d = legs(0.1, 0.2, True, X)\n\n",
                        library=lib)
    with pytest.raises(ParseError) as e:
        macro_program_to_tree(h, LineLayout(Library()), file="x.txt")
    assert e.value.file == "x.txt" and e.value.line == 3 and "legs" in e.value.reason


def test_unused_slots_give_zero_loss_and_zero_gradient():
    lib = Library.from_text(LIB_TEXT)
    lay = LineLayout(lib)
    h = parse_hierarchy("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nc, d = legs(0.1, 0.2, True, X)\n\n",
                        library=lib)
    target = macro_program_to_tree(h, lay).target_seq(lay)
    torch.manual_seed(0)
    pred = torch.randn(target.shape, requires_grad=True)
    terms = macro_line_losses(pred, target, lay)
    assert terms["cube"].item() == 0.0 and terms["face"].item() == 0.0  # legs has no cube or face parameter
    sum(terms.values()).backward()
    g = pred.grad
    fl = lay.slices["float"]
    # bbox row: l, h, w used; legs row: s, t; the stop row: no parameter at all
    assert (g[0, fl][:3] != 0).all() and (g[0, fl][3:] == 0).all()
    assert (g[1, fl][:2] != 0).all() and (g[1, fl][2:] == 0).all()
    assert (g[2, lay.slices["cmd"].stop:] == 0).all()
    assert (g[:, lay.slices["cube"]] == 0).all() and (g[:, lay.slices["face"]] == 0).all()
    assert (g[0, lay.slices["bool"]] == 0).all() and (g[1, lay.slices["bool"]] != 0).all()
    # the float term is the L1 of the used floats exactly
    want = (pred[0, fl][:3] - target[0, fl][:3]).abs().sum() + (pred[1, fl][:2] - target[1, fl][:2]).abs().sum()
    assert terms["float"].item() == pytest.approx(want.item(), rel=1e-6)
    # changing an unused slot's prediction changes nothing
    pred2 = pred.detach().clone()
    pred2[1, fl.start + 4] += 100.0
    pred2[1, lay.slices["cube"]] += 5.0
    assert all(torch.equal(v, terms[k].detach()) for k, v in macro_line_losses(pred2, target, lay).items())


@pytest.fixture(scope="module")
def overfit(chairs):
    lib, progs = chairs
    lay = LineLayout(lib)
    small = [h for h in progs.values() if len(h.programs) == 2 and sum(len(p.lines) for p in h.programs) <= 5][:3]
    trees = [macro_program_to_tree(h, lay) for h in small]
    torch.manual_seed(0)
    vae = MacroVAE(lay, hidden_dim=64)
    opt = torch.optim.Adam(vae.parameters(), lr=3e-3)
    losses = []
    for _ in range(150):
        opt.zero_grad()
        total = sum(macro_program_loss(vae(t, sample=False), t, lay, kl=False)[0] for t in trees)
        total.backward()
        opt.step()
        losses.append(total.item())
    return vae, small, losses


def test_a_tiny_overfit_reconstructs_its_training_programs(overfit):
    vae, small, losses = overfit
    assert len(small) == 3
    assert losses[-1] < 0.05 * losses[0]
    lib = vae.library
    for h in small:
        d = decode_macro(vae, encode_macro(vae, h))
        assert d.skipped == 0
        assert [[c.func for c in p.lines] for p in d.hierarchy.programs] == [[c.func for c in p.lines] for p in h.programs]
        a, b = execute_hierarchy(h, lib), d.shape
        assert a.corners.shape == b.corners.shape
        assert (_leaves(a) - _leaves(b)).abs().max().item() < 0.05


def test_samples_are_macro_programs_that_execute(overfit):
    vae = overfit[0]
    out = sample_macro(vae, 6, seed=3)
    assert len(out) == 6
    for d in out:
        back = parse_hierarchy(d.text, library=vae.library)
        shape = execute_hierarchy(back, vae.library)
        assert shape.corners.shape[0] >= 1 and torch.isfinite(shape.corners).all()
        assert torch.allclose(_leaves(shape), _leaves(d.shape), atol=1e-5)
    again = sample_macro(vae, 6, seed=3)
    assert [d.text for d in again] == [d.text for d in out]


def test_float_ranges_follow_the_base_slots_a_parameter_fills_alone():
    import math

    from shapeprog.vae.macro_decode import MIN_DIM, float_ranges
    lib = Library.from_text(LIB_TEXT + "\ndef odd(x: float):\n    c = Cuboid(0.5 * x, 0.2, 0.2, True)\n"
                            "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n")
    assert float_ranges(lib, "legs") == ((MIN_DIM, math.inf), (0.0, 1.0))  # s a dim; t a squeeze u (1 - t skipped)
    assert float_ranges(lib, "hang") == ((MIN_DIM, math.inf),) * 3
    assert float_ranges(lib, "odd") == ((-math.inf, math.inf),)  # only in an expression: not clamped
    assert float_ranges(lib, "attach") == ((0.0, 1.0),) * 6 and float_ranges(lib, "reflect") == ()
