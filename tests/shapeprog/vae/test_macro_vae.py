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


# ------------------------------------------------------------------------------------------ batched pass

TWO_LEVELS = ("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nProgram_1, cube1 = legs(0.1, 0.2, True, X)\n"
              "Program_2 = hang(0.4, 0.1, 0.4, bbox, top, cube1)\n\n"
              "# Program_1\nbbox = Cuboid(0.1, 1.0, 0.1, True)\nc, d = legs(0.02, 0.3, False, Z)\n\n"
              "# Program_2\nbbox = Cuboid(0.4, 0.1, 0.4, True)\nc = Cuboid(0.2, 0.1, 0.2, True)\n"
              "squeeze(bbox, bbox, top, 0.5, 0.5)\n\n")


def _per_tree_losses(vae, trees, eps=None, codes=None, kl=True):
    from shapeprog.vae.model import VAEOutput
    out = []
    for b, t in enumerate(trees):
        if codes is not None:
            z = mu = codes[b]
            logvar = torch.zeros_like(z)
        else:
            _, mu, logvar = vae.encode(t, sample=False)
            z = mu if eps is None else mu + eps[b] * torch.exp(0.5 * logvar)
        res = VAEOutput(vae.decoder.teacher_forced(t, z), vae.decoder.bbox(z), mu, logvar, z)
        out.append((res, macro_program_loss(res, t, vae.layout, kl=kl)))
    return out


@pytest.mark.parametrize("which", ["hand-built", "shipped chair"])
def test_the_batched_pass_equals_the_tree_by_tree_pass(which, chairs):
    from shapeprog.vae.macro_batch import MacroTreeBatch, macro_batch_forward, macro_batch_loss
    if which == "hand-built":
        lib = Library.from_text(LIB_TEXT)
        lay = LineLayout(lib)
        h = parse_hierarchy(TWO_LEVELS, library=lib)
        flat = parse_hierarchy("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nc, d = legs(0.1, 0.2, True, X)\n\n",
                               library=lib)
        hs = [h, flat, h]
    else:
        lib, progs = chairs
        lay = LineLayout(lib)
        deep = [p for p in progs.values() if len(p.programs) >= 3][:4]
        hs = deep + list(progs.values())[:6]
        assert len(deep) == 4
    trees = [macro_program_to_tree(x, lay, dtype=torch.float64) for x in hs]
    torch.manual_seed(0)
    vae = MacroVAE(lay, hidden_dim=24).double()
    eps = torch.randn(len(trees), 24, dtype=torch.float64)
    codes = torch.randn(len(trees), 24, dtype=torch.float64)
    batch = MacroTreeBatch(trees)
    for kw in ({"sample": False}, {"eps": eps}, {"codes": codes, "kl": False}):
        ref = _per_tree_losses(vae, trees, eps=kw.get("eps"), codes=kw.get("codes"), kl=kw.get("kl", True))
        total, terms = macro_batch_loss(vae, batch, **kw)
        torch.testing.assert_close(total, torch.stack([r[1][0] for r in ref]), rtol=1e-10, atol=1e-10)
        assert sorted(terms) == sorted(ref[0][1][1])
        for name in terms:
            torch.testing.assert_close(terms[name], torch.stack([r[1][1][name] for r in ref]), rtol=1e-10, atol=1e-9)
    # the split output is the per-tree output, node by node
    out = macro_batch_forward(vae, batch, sample=False)
    for got, (want, _) in zip(batch.plan(lay).split(out), _per_tree_losses(vae, trees)):
        assert len(got.nodes) == len(want.nodes)
        for g, w in zip(got.nodes, want.nodes):
            torch.testing.assert_close(g.lines, w.lines, rtol=1e-10, atol=1e-10)
            torch.testing.assert_close(g.leaf, w.leaf, rtol=1e-10, atol=1e-10)
    # gradients of the summed losses, z sampled with the same eps
    vae.zero_grad()
    sum(r[1][0] for r in _per_tree_losses(vae, trees, eps=eps)).backward()
    want = {k: p.grad.clone() for k, p in vae.named_parameters()}
    vae.zero_grad()
    macro_batch_loss(vae, batch, eps=eps)[0].sum().backward()
    for k, p in vae.named_parameters():
        torch.testing.assert_close(p.grad, want[k], rtol=1e-8, atol=1e-8 * (1 + want[k].abs().max().item()),
                                   msg=lambda m: f"{k}: {m}")


def test_the_batched_pass_refuses_bad_noise_codes_and_trees():
    from shapeprog.vae.macro_batch import MacroTreeBatch, macro_batch_loss
    lib = Library.from_text(LIB_TEXT)
    lay = LineLayout(lib)
    tree = macro_program_to_tree(parse_hierarchy(TWO_LEVELS, library=lib), lay)
    vae = MacroVAE(lay, hidden_dim=16)
    batch = MacroTreeBatch([tree, tree])
    with pytest.raises(ValueError, match=r"eps must be \(B, H\) = \(2, 16\)"):
        macro_batch_loss(vae, batch, eps=torch.zeros(3, 16))
    with pytest.raises(ValueError, match="codes must be"):
        macro_batch_loss(vae, batch, codes=torch.zeros(3, 16), kl=False)
    with pytest.raises(ValueError, match="no posterior"):
        macro_batch_loss(vae, batch, codes=torch.zeros(2, 16))
    with pytest.raises(ValueError, match="at least one tree"):
        MacroTreeBatch([])
    other = LineLayout(Library())  # a narrower line vector than the trees'
    with pytest.raises(ValueError, match=r"lines must be \(L, \d+\)"):
        MacroTreeBatch([tree]).plan(other)
    mixed = MacroTreeBatch([tree, tree.to(dtype=torch.float64)])
    with pytest.raises(ValueError, match="the batch is torch.float32"):
        mixed.plan(lay)


def test_decoder_input_dropout_acts_in_training_only_and_adds_no_weights():
    from shapeprog.vae.macro_batch import MacroTreeBatch, macro_batch_loss
    from shapeprog.vae.model import VAE
    from shapeprog.vae.train import VAEModule

    lib = Library.from_text(LIB_TEXT)
    lay = LineLayout(lib)
    trees = [macro_program_to_tree(parse_hierarchy(TWO_LEVELS, library=lib), lay)]
    torch.manual_seed(0)
    plain = MacroVAE(lay, hidden_dim=16)
    drop = MacroVAE(lay, hidden_dim=16, dropout=0.5)
    assert drop.state_dict().keys() == plain.state_dict().keys()
    assert VAE(16, dropout=0.5).state_dict().keys() == VAE(16).state_dict().keys()
    drop.load_state_dict(plain.state_dict())
    batch = MacroTreeBatch(trees)
    want = macro_batch_loss(plain.eval(), batch, sample=False)[0]
    torch.testing.assert_close(macro_batch_loss(drop.eval(), batch, sample=False)[0], want, rtol=0, atol=0)
    drop.train()
    torch.manual_seed(1)
    a = macro_batch_loss(drop, batch, sample=False)[0]
    b = macro_batch_loss(drop, batch, sample=False)[0]
    assert not torch.equal(a, want) and not torch.equal(a, b)
    # the embeddings are zeroed at about the rate asked, and scaled by 1 / (1 - p)
    x = drop.decoder.embed(torch.zeros(4000, lay.width), torch.ones(4000, 3), 0)
    ref = plain.decoder.embed(torch.zeros(4000, lay.width), torch.ones(4000, 3), 0)
    zeroed = (x == 0) & (ref != 0)
    assert 0.45 < zeroed.float().mean() < 0.55
    torch.testing.assert_close(x[~zeroed], 2 * ref[~zeroed])
    for bad in (-0.1, 1.0):
        with pytest.raises(ValueError, match="dropout must be in"):
            MacroVAE(lay, hidden_dim=16, dropout=bad)
    assert VAEModule("chair", hidden_dim=8, dropout=0.25).vae.decoder.input_dropout.p == 0.25
