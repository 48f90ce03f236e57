"""Renderer tests: exact pixels against the spec's tables and against scikit-image, stack order,
the batched renderer against the NumPy path (random programs, off-grid parameters), stack traces."""

import random

import numpy as np
import pytest
import torch

import csgnet
from csg_testutil import random_program, skimage_2d
from csgnet.lang import Draw, ParseError, Program, parse
from csgnet.renderer.reference import bresenham, draw_np, render_np
from csgnet.renderer import (StackMachine, encode_programs, encode_tokens, execute, pack, render_programs, render_tokens,
                              stack_trace, unpack)
from csgnet.data import ProgramDataset
from csgnet.primitives import GRID, SIZES
from csgnet.vocab import KIND_CODES, PAD_CODE, vocabulary

import skimage.draw as skdraw  # noqa: E402  (scikit-image: a core dependency)


# ------------------------------------------------------------------- exact pixels from the spec

@pytest.mark.parametrize("r,c0,c1", [(8, 26, 37), (12, 23, 40), (16, 20, 43), (20, 17, 46), (24, 15, 48),
                                     (28, 12, 51), (32, 9, 54)])
def test_square_columns_at_x32(r, c0, c1):
    img = csgnet.render(f"s(32,32,{r})")[0]
    cols = np.nonzero(img.any(axis=0))[0]
    assert (cols[0], cols[-1]) == (c0, c1)
    assert img[:, c0:c1 + 1].any(axis=1).sum() == c1 - c0 + 1  # a square: as many rows as columns
    assert img.sum() == (c1 - c0 + 1) ** 2


@pytest.mark.parametrize("r,base,apex,c0,c1", [(8, 36, 24, 25, 38), (16, 40, 16, 18, 45), (32, 48, 0, 4, 59)])
def test_triangle_vertices_at_32_32(r, base, apex, c0, c1):
    img = csgnet.render(f"t(32,32,{r})")[0]
    rows = np.nonzero(img.any(axis=1))[0]
    assert (rows[0], rows[-1]) == (apex, base)
    assert np.nonzero(img[base])[0].tolist() == list(range(c0, c1 + 1))
    assert np.nonzero(img[apex])[0].tolist() == [32]  # the apex points up (smaller rows)


def test_circle_is_strict_and_row_is_y():
    img = csgnet.render("c(20,40,8)")[0]
    assert img.sum() == 193
    rows, cols = np.nonzero(img)
    assert (rows.min(), rows.max(), cols.min(), cols.max()) == (33, 47, 13, 27)
    assert not img[40, 28] and not img[48, 20] and img[40, 27]  # distance exactly r is off


def test_3d_voxel_counts():
    counts = [int(v.sum()) for v in csgnet.render(["sp(32,32,32,8)", "sp(32,32,32,32)", "cu(32,32,32,32)"], 3)]
    assert counts == [1419, 124487, 31 ** 3]
    cyl = csgnet.render("cy(20,30,40,8,16)", 3)[0]
    zs = np.nonzero(cyl.any(axis=(0, 1)))[0]
    assert (zs[0], zs[-1]) == (40 - 7, 40 + 7)  # h - 1 voxels along z (axis 2)
    assert cyl[:, :, 40].sum() == 149  # the disk x^2 + y^2 <= 7^2
    assert cyl[20 + 7, 30, 40] and not cyl[20 + 8, 30, 40]  # axis 0 is x


def test_zero_sizes_follow_the_formulas():
    assert not csgnet.render("c(32,32,0)")[0].any()  # an empty circle, as scikit-image's disk
    sphere, cyl = csgnet.render(["sp(32,32,32,0)", "cy(32,32,32,8,0)"], 3)
    cross = np.zeros((64, 64, 64), bool)
    for axis in range(3):
        for d in (-1, 0, 1):
            c = [32, 32, 32]
            c[axis] += d
            cross[tuple(c)] = True
    assert (sphere == cross).all()  # (r - 1)^2 = 1: the centre and its 6 neighbours
    assert np.nonzero(cyl.any(axis=(0, 1)))[0].tolist() == [32]  # h = 0: one layer


def test_3d_is_clipped_never_wrapped():
    vol = csgnet.render("sp(2,60,30,8)", 3)[0]
    i, j, k = np.ogrid[:80, :80, :80]
    ref = (i - 10) ** 2 + (j - 68) ** 2 + (k - 38) ** 2 <= 49  # same sphere on a padded grid
    assert (vol == ref[8:72, 8:72, 8:72]).all()
    assert not vol[60:, :, :].any()  # nothing wrapped around to the far side


def test_stack_order_earlier_minus_later():
    circle_minus_square = csgnet.render("c(32,32,20)s(32,32,12)-")[0]
    c, s = csgnet.render(["c(32,32,20)", "s(32,32,12)"])
    assert (circle_minus_square == (c & ~s)).all()
    assert not (circle_minus_square == (s & ~c)).all()
    assert (csgnet.render("c(32,32,20)s(32,32,12)*")[0] == (c & s)).all()
    assert (csgnet.render("c(32,32,20)s(32,32,12)+")[0] == (c | s)).all()


def test_invalid_programs_render_empty():
    progs = [parse(t, strict=False) for t in ["", "c(8,8,8)+", "c(8,8,8)s(16,16,8)", "+c(8,8,8)"]]
    assert not csgnet.render(progs).any()


# ------------------------------------------------------------------- against scikit-image

def test_every_vocabulary_primitive_matches_scikit_image():
    v = vocabulary(2)
    ids = torch.arange(v.num_primitives)[:, None]
    imgs = render_tokens(ids, 2).numpy()
    for i in range(v.num_primitives):
        d = v.decode([i]).tokens[0]
        assert (imgs[i] == skimage_2d(d.kind, *d.params)).all(), d


def test_grammar_and_off_grid_primitives_match_scikit_image():
    # every grammar triple, inside the canvas (the vocabulary) or not
    draws = [Draw(k, (x, y, r)) for k in "cst" for x in GRID for y in GRID for r in SIZES]
    assert len(draws) == 3 * 343
    rng = random.Random(7)
    draws += [Draw(k, (rng.randint(-20, 84), rng.randint(-20, 84), rng.randint(0, 70)))
              for k in "cst" for _ in range(700)]
    draws += [Draw("t", (32, 32, r)) for r in (13, 26, 27, 52, 53, 54)]  # float-sensitive apex rows
    imgs = render_programs([Program((d,), 2) for d in draws], 2).numpy()
    for d, img in zip(draws, imgs):
        assert (img == skimage_2d(d.kind, *d.params)).all(), d
        assert (img == draw_np(d)).all(), d


def test_bresenham_matches_scikit_image_line():
    rng = random.Random(3)
    for _ in range(500):
        r0, c0, r1, c1 = (rng.randint(-8, 72) for _ in range(4))
        rr, cc = skdraw.line(r0, c0, r1, c1)
        assert bresenham(r0, c0, r1, c1) == list(zip(rr.tolist(), cc.tolist()))


# ------------------------------------------------------------------- batched == NumPy path

@pytest.mark.parametrize("dim,count,max_prims", [(2, 300, 7), (3, 40, 4)])
@pytest.mark.parametrize("vocab_only", [True, False])
def test_batched_equals_numpy_path(dim, count, max_prims, vocab_only):
    rng = random.Random(dim + 10 * vocab_only)
    progs = [random_program(rng, dim, rng.randint(1, max_prims), vocab_only) for _ in range(count)]
    # a few broken ones too
    progs += [Program(p.tokens[:-1], dim) for p in progs[:10]] + [Program(p.tokens[1:], dim) for p in progs[10:15]]
    out = csgnet.render(progs, dim)
    for p, o in zip(progs, out):
        assert (o == render_np(p)).all(), p.text()
    if vocab_only:  # the token-index path (primitive cache) gives the same
        assert (csgnet.render(ProgramDataset(progs, dim).tokens, dim) == out).all()


def test_batched_equals_single_calls():
    rng = random.Random(11)
    progs = [random_program(rng, 2, rng.randint(1, 7)) for _ in range(40)]
    batch = csgnet.render(progs)
    for p, b in zip(progs, batch):
        assert (csgnet.render(p)[0] == b).all()


def test_token_padding_and_lengths():
    v = vocabulary(2)
    ids = torch.tensor([v.encode("c(32,32,28)s(32,32,20)-") + [v.stop, 5],
                        v.encode("c(32,32,28)s(32,32,20)-t(32,32,8)+")])
    out = render_tokens(ids, 2)
    assert (out[0].numpy() == csgnet.render("c(32,32,28)s(32,32,20)-")[0]).all()
    out2 = render_tokens(ids, 2, lengths=torch.tensor([3, 3]))
    assert (out2[1] == out2[0]).all()


@pytest.mark.parametrize("dim", [2, 3])
def test_packed_token_renders_unpack_to_the_bool_renders(dim):
    rng = random.Random(11 + dim)
    progs = [random_program(rng, dim, rng.randint(1, 3), vocab_only=True) for _ in range(6)]
    ids = ProgramDataset(progs, dim).tokens
    lengths = torch.tensor([len(p.tokens) for p in progs])
    words = render_tokens(ids, dim, lengths, packed=True)
    assert words.dtype == torch.int64
    assert torch.equal(unpack(words, dim), render_tokens(ids, dim, lengths))


# ------------------------------------------------------------------- stack trace

@pytest.mark.parametrize("dim", [2, 3])
def test_stack_trace_matches_numpy_stack(dim):
    rng = random.Random(5 + dim)
    progs = [random_program(rng, dim, rng.randint(1, 4 if dim == 3 else 7), vocab_only=True) for _ in range(25)]
    progs.append(Program(progs[0].tokens[1:] + progs[1].tokens, dim))  # underflows midway
    tr = stack_trace(progs, dim, k=3).numpy()
    T = max(len(p) for p in progs)
    assert tr.shape == (T + 1, len(progs), 3) + (64,) * dim
    assert not tr[0].any()  # state 0: empty stack
    for i, p in enumerate(progs):
        _, states = render_np(p, return_stack=True)
        for t in range(T + 1):
            state = states[min(t, len(p))]  # frozen after the end
            for k in range(3):
                ref = state[k] if k < len(state) else np.zeros((64,) * dim, bool)
                assert (tr[t, i, k] == ref).all(), (p.text(), t, k)


def test_stack_trace_slot0_of_last_state_is_the_render():
    v = vocabulary(2)
    ids = torch.tensor([v.encode("c(32,32,28)s(32,32,20)-t(32,32,8)+")])
    tr = stack_trace(ids, 2, k=7)
    assert tr.shape == (6, 1, 7, 64, 64)
    assert (tr[-1, 0, 0] == render_tokens(ids, 2)[0]).all()
    assert not tr[-1, 0, 1:].any()
    assert tr[2, 0, 1].any() and tr[2, 0, 0].any()  # two shapes after two draws; slot 0 is the square
    assert (tr[2, 0, 0].numpy() == csgnet.render("s(32,32,20)")[0]).all()


def test_incremental_machine_equals_execute():
    rng = random.Random(9)
    progs = [random_program(rng, 2, rng.randint(1, 7)) for _ in range(30)]
    kinds, params = encode_programs(progs, 2)
    m = StackMachine(len(progs), 2, depth=7)
    for t in range(kinds.shape[1]):
        m.step(kinds[:, t], params[:, t])
    assert (m.result() == execute(kinds, params, 2).canvas).all()
    # stopping: a stop code freezes a program
    m2 = StackMachine(1, 2, depth=3)
    k, p = encode_programs(["c(32,32,20)"], 2)
    m2.step(k[:, 0], p[:, 0])
    m2.step(torch.tensor([PAD_CODE]), torch.zeros(1, 5, dtype=torch.long))
    m2.step(torch.tensor([KIND_CODES["s"]]), torch.tensor([[8, 8, 8, 0, 0]]))
    assert (unpack(m2.result(), 2)[0].numpy() == csgnet.render("c(32,32,20)")[0]).all()


def test_pack_unpack_round_trip():
    rng = np.random.default_rng(0)
    a = rng.random((3, 64, 64, 64)) > 0.5
    assert (unpack(pack(a), 3).numpy() == a).all()
    b = rng.random((5, 64, 64)) > 0.5
    assert (unpack(pack(b), 2).numpy() == b).all()


def test_bad_token_tensor_errors():
    with pytest.raises(ValueError, match=r"token indices must lie in \[0, 400\)"):
        render_tokens(torch.tensor([[400]]), 2)
    with pytest.raises(ValueError, match=r"tokens must be \(B, T\)"):
        render_tokens(torch.tensor([1, 2]), 2)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU")
def test_gpu_equals_cpu():
    rng = random.Random(1)
    progs = [random_program(rng, 3, rng.randint(1, 4)) for _ in range(20)]
    assert (csgnet.render(progs, 3, device="cuda") == csgnet.render(progs, 3)).all()


# ------------------------------------------------------------------- planned execution

def _machine_run(kinds, params, dim, token_ids=None):
    """The stack machine stepped token by token (the reference for the planned executor)."""
    m = StackMachine(kinds.shape[0], dim, kinds.shape[1] + 1)
    for t in range(kinds.shape[1]):
        m.step(kinds[:, t], params[:, t], None if token_ids is None else token_ids[:, t])
    return m.result(), m.valid


@pytest.mark.parametrize("dim,T", [(2, 9), (3, 7)])
def test_planned_execute_equals_stack_machine(dim, T):
    """Random token strings (mostly invalid: underflows, leftovers, stops in the middle) and valid
    programs, through both the primitive-cache and the drawn-parameter paths."""
    rng = np.random.default_rng(dim)
    v = vocabulary(dim)
    noise = rng.integers(0, len(v), size=(120, T))
    noise[rng.random(noise.shape) < 0.1] = v.stop  # stops in the middle
    weighted = np.where(rng.random((120, T)) < 0.4, rng.integers(v.num_primitives, len(v) - 1, size=(120, T)),
                        rng.integers(0, v.num_primitives, size=(120, T)))  # ops often enough to be valid
    valid_progs = [random_program(random.Random(i), dim, 1 + i % ((T + 1) // 2), vocab_only=True) for i in range(60)]
    ids = ProgramDataset(valid_progs, dim, max_len=T).tokens[:, :T]  # padded with $
    tokens = torch.cat([torch.from_numpy(noise), torch.from_numpy(weighted), ids])
    kinds, params = encode_tokens(tokens, dim)
    want, want_valid = _machine_run(kinds, params, dim, tokens)
    assert want_valid.sum() > 60  # the comparison covers many valid programs
    for got in (execute(kinds, params, dim, token_ids=tokens), execute(kinds, params, dim)):
        assert torch.equal(got.valid, want_valid)
        assert torch.equal(got.canvas, want)
    assert torch.equal(render_tokens(tokens, dim), unpack(want, dim))


def test_planned_execute_off_grid_3d_matches_numpy_path():
    """Single primitives, disjoint intersections (empty results feeding later operations), shapes
    clipped at every side, and empty programs."""
    progs = [parse(t, 3) for t in (
        "sp(-4,30,30,12)",
        "cu(70,70,70,20)",
        "sp(10,10,10,8)cu(50,50,50,8)*",  # empty intersection
        "sp(10,10,10,8)cu(50,50,50,8)*cy(30,30,30,12,20)+",  # empty result unioned with a shape
        "cy(30,30,30,12,20)sp(10,10,10,8)cu(50,50,50,8)*-",  # minus an empty result
        "sp(10,10,10,8)cu(50,50,50,8)*cy(30,30,30,12,20)-",  # an empty result minus a shape
        "sp(2,60,33,20)cu(60,2,31,24)+sp(32,32,32,16)-",
        "cy(0,0,0,40,60)cu(63,63,63,40)*",
    )]
    out = csgnet.render(progs, 3)
    for p, o in zip(progs, out):
        assert (o == render_np(p)).all(), p.text()
    assert not out[2].any() and (out[3] == render_np(parse("cy(30,30,30,12,20)", 3))).all()


def test_results_stay_valid_while_referenced():
    """Large CPU results reuse released memory, never memory still referenced (views included)."""
    v = vocabulary(3)
    rng = np.random.default_rng(1)
    a = torch.from_numpy(rng.integers(0, v.num_primitives, size=(40, 1)))
    b = torch.from_numpy(rng.integers(0, v.num_primitives, size=(40, 1)))
    first = render_tokens(a, 3)
    kept = first[3].clone()
    view = first[3]
    del first
    second = render_tokens(b, 3)  # must not overwrite the memory `view` still uses
    assert torch.equal(view, kept)
    assert not np.shares_memory(view.numpy(), second.numpy())
    want = np.stack([render_np(v.decode(list(r))) for r in b.numpy()])
    assert (second.numpy() == want).all()
    del view, second
    third = render_tokens(a, 3)  # memory released above may be reused, and is fully rewritten
    assert torch.equal(third[3], kept)
    assert (third.numpy() == np.stack([render_np(v.decode(list(r))) for r in a.numpy()])).all()


@pytest.mark.parametrize("pool_max", [None, 0])
@pytest.mark.parametrize("dim", [2, 3])
def test_unpack_matches_numpy_unpackbits(dim, pool_max, monkeypatch):
    from csgnet import renderer

    if pool_max is not None:  # outputs larger than the pool keeps: calloc'd zeros, zero rows untouched
        monkeypatch.setattr(renderer._POOL, "max_bytes", pool_max)
    rng = np.random.default_rng(dim)
    shape = (300, 64) if dim == 2 else (20, 64, 64)
    words = rng.integers(-2**63, 2**63 - 1, size=shape, dtype=np.int64, endpoint=True)
    words[rng.random(shape[:-1]) < 0.8] = 0  # mostly empty rows: the sparse path
    for w in (words, np.where(rng.random(shape) < 0.5, 0, words)):
        got = unpack(torch.from_numpy(w), dim).numpy()
        want = np.unpackbits(w.view(np.uint8), axis=-1, bitorder="little").reshape(shape + (64,)).astype(bool)
        assert np.array_equal(got, want)
    dense = rng.integers(-2**63, 2**63 - 1, size=shape, dtype=np.int64, endpoint=True)
    assert np.array_equal(unpack(torch.from_numpy(dense), dim).numpy(),
                          np.unpackbits(dense.view(np.uint8), axis=-1, bitorder="little").reshape(shape + (64,)))


def test_popcount_counts_every_bit_including_the_sign_bit():
    from csgnet.renderer import popcount

    img = np.zeros((2, 64, 64), dtype=bool)
    img[0, :, 63] = True          # the last column: the sign bit of every row word
    img[1] = True
    assert popcount(pack(torch.from_numpy(img))).tolist() == [64, 4096]


def test_stack_machine_reset_starts_rows_afresh():
    from csgnet.renderer import primitive_cache

    vocab = vocabulary(2)
    ids = torch.tensor([vocab.encode("c(32,32,16)")[0], vocab.encode("s(24,24,12)")[0]])
    kinds = primitive_cache(2, "cpu").kinds[ids]
    m = StackMachine(2, 2, depth=3)
    m.step(kinds, token_ids=ids)
    m.step(torch.full((2,), PAD_CODE), token_ids=ids)  # both stop
    m.reset(torch.tensor([1]))
    m.step(kinds[[1, 0]], token_ids=ids[[1, 0]])       # row 0 ignores it (stopped), row 1 draws anew
    want = csgnet.render(["c(32,32,16)", "c(32,32,16)"])
    assert torch.equal(unpack(m.result(), 2), torch.from_numpy(want)) and m.valid.all()


def test_programs_as_text_render_like_objects_and_fail_like_parse():
    """The text path (per-token cache, primitives from the cache when every one is a vocabulary token)
    renders what the parsed objects render; a malformed text raises parse()'s error."""
    rng = random.Random(11)
    vocab_progs = [random_program(rng, 2, 4, vocab_only=True) for _ in range(20)]
    any_progs = [random_program(rng, 2, 4) for _ in range(20)]
    for progs in (vocab_progs, vocab_progs + any_progs):
        texts = [p.text() for p in progs]
        want = render_programs(progs, 2).numpy()
        assert (render_programs(texts, 2).numpy() == want).all()
        assert (want == np.stack([render_np(p) for p in progs])).all()
    k1, p1 = encode_programs([p.text() for p in any_progs], 2)
    k2, p2 = encode_programs(any_progs, 2)
    assert torch.equal(k1, k2) and torch.equal(p1, p2)
    assert (render_programs(["sp(32,32,32,8) u(20,20,20,12)-"], 3).numpy()
            == render_np(parse("sp(32,32,32,8)u(20,20,20,12)-", 3))).all()
    with pytest.raises(ParseError) as e:
        render_programs(["c(8,8,8)", "c(8,8,8)q(1,2,3)+"], 2)
    with pytest.raises(ParseError) as e2:
        parse("c(8,8,8)q(1,2,3)+", strict=False)
    assert str(e.value) == str(e2.value) and e.value.position == 8
