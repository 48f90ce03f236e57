"""Decoding a 3D target together with its mirror images (``views`` of csgnet.decode, infer and parse)."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import csgnet
from csgnet.decode import VIEWS, beam_search, check_views, decode, flip_view, greedy, mirror
from csgnet.inference import infer
from csgnet.models import CSGNet, preset
from csgnet.renderer import stack_trace
from csgnet.vocab import vocabulary

TEXTS = ["sp(32,32,32,16)", "cu(24,32,40,16)sp(40,24,32,12)-", "cy(24,40,32,8,16)cu(32,32,24,20)+"]


def tiny(dim=3, seed=0, stack=False):
    torch.manual_seed(seed)
    cfg = dict(hidden=32, channels=(4, 4, 4), enc_dropout=0.0, dropout=0.0)
    if dim == 3:
        cfg.update(channels=(2, 2, 2), input_pool=4)
    return CSGNet(preset("small", dim, stack, **cfg)).eval()


def volumes(texts):
    return torch.from_numpy(csgnet.render(texts, 3))


@pytest.mark.parametrize("view", VIEWS[16])
def test_each_token_map_draws_the_mirrored_volume(view):
    axes, swap = view
    v = vocabulary(3)
    index, missing = mirror(axes, swap)
    rng = np.random.default_rng(len(axes) + 3 * swap)
    picked = [int(i) for i in rng.integers(0, v.num_primitives, 60) if not missing[i]]
    assert len(picked) >= 50
    flipped = flip_view(volumes([v.tokens[i] for i in picked]), axes, swap)
    assert torch.equal(flipped, volumes([v.tokens[int(index[i])] for i in picked]))
    # operators and '$' are their own images; a primitive marked missing really has no image in the vocabulary
    assert torch.equal(index[v.num_primitives:], torch.arange(v.num_primitives, len(v.tokens)))
    assert bool(missing[0: v.num_primitives].any()) == bool(axes) and not missing[v.num_primitives:].any()
    # flips are involutions: mapping twice gives the token back wherever both images exist
    if not swap:
        ok = ~missing & ~missing[index]
        assert torch.equal(index[index][ok], torch.arange(len(v.tokens))[ok])


def test_the_first_view_is_the_target_and_sets_grow():
    for n, views in VIEWS.items():
        assert len(views) == n and views[0] == ((), False) and len(set(views)) == n
    t = volumes(TEXTS)
    assert torch.equal(flip_view(t, ()), t)
    assert torch.equal(flip_view(flip_view(t, (0, 2)), (0, 2)), t)  # no primitive reaches voxel plane 0


@pytest.mark.parametrize("stack", [False, True])
@pytest.mark.parametrize("n_views", [4, 16])
def test_views_decoding_scores_are_the_mean_of_the_views_teacher_forced_logprobs(n_views, stack):
    """Every beam's score is, step by step, the mean over the views still voting of each view's teacher-forced
    log-probability of the token mirrored into that view (fed its own mirrored prefix and, for CSGNetStack, the
    stack of that prefix); a view stops voting from the first token it has no image of."""
    m = tiny(seed=1, stack=stack)
    v = vocabulary(3)
    with torch.no_grad():  # favour primitives off every mirror plane, so that every view maps them elsewhere
        for text in ("p(16,24,40,8)", "p(40,16,24,12)", "u(24,40,16,8)"):
            m.head[-1].bias[v.tokens.index(text)] += 4.0
    tgt = volumes(TEXTS)
    views = VIEWS[n_views]
    d = beam_search(m, tgt, 4, max_len=5, views=n_views, constrained=True)
    compared = mirrored = 0
    for i in range(len(TEXTS)):
        for j in range(4):
            n = int(d.lengths[i, j])
            if not bool(d.valid[i, j]):
                continue
            # the program and its '$', or at max_len the program alone (decoding stops there)
            seq = torch.cat([d.tokens[i, j, :n], torch.tensor([m.stop] if n < 5 else [], dtype=torch.long)])
            per_view = []
            for axes, swap in views:
                index, missing = mirror(axes, swap)
                s = index[seq]  # a token without an image in this view is fed as itself
                tok_in = torch.cat([torch.tensor([m.start]), s[:-1]])[None]
                st = stack_trace(s[None, :-1], 3, k=m.config.stack_k) if stack else None
                with torch.no_grad():
                    lp = F.log_softmax(m(flip_view(tgt[i: i + 1], axes, swap), tok_in, st), -1)[0]
                off = missing[seq].long().cummax(0).values.bool()  # from its first missing token on
                per_view.append(lp.gather(1, s[:, None])[:, 0].masked_fill(off, float("nan")))
                mirrored += int(n >= 3 and bool(((s[:n] != seq[:n]) & ~off[:n]).any()))
            expected = float(torch.stack(per_view).nanmean(0).sum())
            assert expected == pytest.approx(float(d.logprob[i, j]), abs=1e-5)
            compared += 1
    assert compared >= 4 and mirrored >= 1  # programs of several primitives, mapped to other tokens by some view


def test_a_view_that_cannot_follow_a_primitive_stops_voting_for_that_row():
    from csgnet.decode import _Views

    vw = _Views(2, 3, "cpu")  # the volume and its mirror image along x
    V = len(vocabulary(3))
    _, missing = mirror((0,))
    gone = int(torch.nonzero(missing)[0])  # a cube at the grid's upper x edge: no image along x
    logp = torch.cat([torch.zeros(2, V), torch.full((2, V), -1.0)])  # view 0 says 0, view 1 says -1, two rows
    c = vw.combine(logp)
    assert c[0, 0] == -0.5 and c[0, gone] == 0.0  # the missing token: view 0 alone
    assert torch.equal(vw.tokens(torch.tensor([gone, 0]))[2:], torch.tensor([gone, int(mirror((0,))[0][0])]))
    c = vw.combine(logp)
    assert (c[0] == 0.0).all() and c[1, 0] == -0.5  # row 0 lost view 1's vote, row 1 did not
    vw.rows(torch.tensor([1, 0]), 2)  # beams exchange places: the vote follows the row
    c = vw.combine(logp)
    assert c[0, 0] == -0.5 and (c[1] == 0.0).all()


@pytest.mark.parametrize("width", [1, 3])
def test_a_mirrored_target_decodes_to_the_mirrored_program(width):
    """With the view set {identity, flip x}, decoding the flipped target is the same computation with the views'
    roles exchanged: its programs are the first programs mirrored, token for token."""
    m = tiny(seed=2)
    tgt = volumes(TEXTS)
    index, missing = mirror((0,))
    a = decode(m, tgt, width, views=2, max_len=7, constrained=True)
    b = decode(m, flip_view(tgt, (0,)), width, views=2, max_len=7, constrained=True)
    assert not missing[a.tokens].any() and a.valid.all() and b.valid.all()
    assert torch.allclose(a.logprob, b.logprob, atol=1e-5)
    for i in range(len(TEXTS)):  # as sets: beams of equal score may come in either order
        assert {tuple(index[t].tolist()) for t in a.tokens[i]} == {tuple(t.tolist()) for t in b.tokens[i]}


def test_one_view_is_the_plain_decode_and_views_keep_the_output_shape():
    m = tiny(seed=3)
    tgt = volumes(TEXTS)
    plain, one = greedy(m, tgt), greedy(m, tgt, views=1)
    assert torch.equal(plain.tokens, one.tokens) and torch.equal(plain.logprob, one.logprob)
    d = beam_search(m, tgt, 2, views=16, constrained=True)
    assert d.tokens.shape[:2] == (3, 2) and d.valid.all()
    assert all(csgnet.is_valid(csgnet.parse(t, 3)) for row in d.texts() for t in row)


@pytest.mark.parametrize("bad", [0, 3, 32, True, 8.0, "8", None])
def test_bad_views_are_refused_by_name(bad):
    with pytest.raises(ValueError, match="views must be one of"):
        check_views(bad, 3)


def test_more_than_one_view_is_refused_for_2d_and_bad_views_before_any_work(tmp_path, capsys):
    from csgnet.__main__ import main
    from csgnet.inference import parse_shape

    with pytest.raises(ValueError, match="views must be one of"):
        parse_shape(tmp_path / "not_read.png", views=3)  # refused before the file is looked at
    with pytest.raises(SystemExit, match="more than 1 view is for 3D models"):
        main(["evaluate", "--dim", "2", "--data", str(tmp_path), "--views", "1", "8"])
    img = tmp_path / "c.png"
    assert main(["render", "c(32,32,16)", "-o", str(img)]) == 0
    capsys.readouterr()
    assert main(["parse", str(img), "--beam", "1", "--views", "8", "--out", str(tmp_path / "out")]) == 0
    assert "note: --views 8 was not used: it is for 3D inputs, and every input was 2D" in capsys.readouterr().err


def test_more_than_one_view_is_refused_for_2d():
    m2 = tiny(dim=2)
    img = torch.from_numpy(csgnet.render(["c(32,32,16)"], 2))
    with pytest.raises(ValueError, match="3D"):
        greedy(m2, img, views=2)
    with pytest.raises(ValueError, match="3D"):
        infer(m2, img, beam=1, views=8)
    assert len(infer(m2, img, beam=1)) == 1  # the 2D default is one view


def test_infer_defaults_to_the_3d_views_and_records_them_in_its_choice():
    m = tiny(seed=4)
    tgt = volumes(TEXTS[:1])
    default = infer(m, tgt, beam=2)[0]
    eight = infer(m, tgt, beam=2, views=8)[0]
    one = infer(m, tgt, beam=2, views=1)[0]
    assert default.text == eight.text and default.score == eight.score
    assert one.beams == beam_search(m, tgt, 2, constrained=True).texts()[0]
    assert default.beams == beam_search(m, tgt, 2, constrained=True, views=8).texts()[0]
