"""Decoding a 3D target together with its mirror images (``views`` of csgnet.decode, infer and parse)."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import csgnet
from csgnet.decode import VIEWS, beam_search, check_views, decode, flip_view, greedy, mirror
from csgnet.inference import infer
from csgnet.models import CSGNet, preset
from csgnet.vocab import vocabulary

TEXTS = ["sp(32,32,32,16)", "cu(24,32,40,16)sp(40,24,32,12)-", "cy(24,40,32,8,16)cu(32,32,24,20)+"]


def tiny(dim=3, seed=0):
    torch.manual_seed(seed)
    cfg = dict(hidden=32, channels=(4, 4, 4), enc_dropout=0.0, dropout=0.0)
    if dim == 3:
        cfg.update(channels=(2, 2, 2), input_pool=4)
    return CSGNet(preset("small", dim, False, **cfg)).eval()


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


def test_views_decoding_scores_are_the_mean_of_the_views_teacher_forced_logprobs():
    m = tiny(seed=1)
    with torch.no_grad():
        m.head[-1].bias[m.stop] += 2.0  # beams that end before max_len, so that '$' is scored too
    tgt = volumes(TEXTS[:2])
    views = VIEWS[4]
    d = beam_search(m, tgt, 3, max_len=5, views=4)
    compared = 0
    for i in range(2):
        for j in range(3):
            n = int(d.lengths[i, j])
            if n >= 5 or not bool(d.valid[i, j]):
                continue
            seq = torch.cat([d.tokens[i, j, :n], torch.tensor([m.stop])])
            per_view = []
            for axes, swap in views:
                index, missing = mirror(axes, swap)
                s = index[seq]  # a token without an image in this view is read as itself and not averaged
                tok_in = torch.cat([torch.tensor([m.start]), s[:-1]])[None]
                with torch.no_grad():
                    lp = F.log_softmax(m(flip_view(tgt[i: i + 1], axes, swap), tok_in, None), -1)[0]
                per_view.append(lp.gather(1, s[:, None])[:, 0].masked_fill(missing[seq], float("nan")))
            expected = float(torch.stack(per_view).nanmean(0).sum())
            assert expected == pytest.approx(float(d.logprob[i, j]), abs=1e-3)
            compared += 1
    assert compared >= 2


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
