"""The table of primitives: derived tables, and a new 2D primitive added as one row at run time."""

import numpy as np
import pytest
import torch

import csgnet
from csgnet import export, primitives as P
from csgnet.lang import Draw, ParseError, parse
from csgnet.renderer import render_programs
from csgnet.renderer.raster import bits
from csgnet.renderer.reference import render_np
from csgnet.synth import Rules, sample_programs
from csgnet.vocab import codes, vocabulary


def test_codes_and_vocabulary_derive_from_the_table():
    c = codes()
    assert c.kind == {p.kind: i for i, p in enumerate(P.primitives())} == {"c": 0, "s": 1, "t": 2, "p": 3, "u": 4, "y": 5}
    assert c.op == {"+": 6, "*": 7, "-": 8} and c.stop == 9
    for dim, n in ((2, 400), (3, 6635)):
        texts = sorted(t for row in P.primitives(dim) for t in P.grammar_texts(row))
        assert vocabulary(dim).tokens == tuple(texts) + ("+", "*", "-", "$")
        assert len(vocabulary(dim)) == n
    assert P.primitive("y").sizes == ("r", "h") and P.by_name("cy") is P.primitive("y")
    with pytest.raises(KeyError, match="unknown primitive kind 'q'"):
        P.primitive("q")
    with pytest.raises(ValueError, match="'sp' is taken by the sphere"):
        P.register(P.Primitive("q", "ball", 3, ("x", "y", "z", "r"), P.primitive("p").ranges,
                               *(getattr(P.primitive("p"), f) for f in ("fits", "reference", "scad", "raster")),
                               long="sp"))


# ---- a made-up primitive: the diamond d(x, y, r), the pixels with |row - y| + |col - x| <= r ----------

def diamond_rows(x, y, r):
    """(P,) int64 each -> (P, 64) packed rows."""
    half = r[:, None] - (torch.arange(P.SIZE)[None, :] - y[:, None]).abs()
    return torch.where(half >= 0, bits(x[:, None] - half, x[:, None] + half), torch.zeros((), dtype=torch.int64))


def diamond_np(x, y, r):
    rows, cols = np.ogrid[:P.SIZE, :P.SIZE]
    return np.abs(rows - y) + np.abs(cols - x) <= r


def diamond_fits(x, y, r):
    return x - r >= 0 and y - r >= 0 and x + r <= P.SIZE - 1 and y + r <= P.SIZE - 1


def diamond_scad(p, fn, label):
    x, y, r = p
    return f"polygon([[{x - r}, {y}], [{x}, {y - r}], [{x + r}, {y}], [{x}, {y + r}]]);  // {label}"


DIAMOND = P.Primitive("d", "diamond", 2, ("x", "y", "r"), (P.GRID, P.GRID, P.SIZES), diamond_fits, diamond_np,
                      diamond_scad, diamond_rows)


@pytest.fixture
def diamond():
    before = (codes(), vocabulary(2).tokens, vocabulary(3).tokens)
    P.register(DIAMOND)
    try:
        yield DIAMOND
    finally:
        P.unregister("d")
        assert (codes(), vocabulary(2).tokens, vocabulary(3).tokens) == before
        assert len(vocabulary(2)) == 400
        # the restored tables render and sample the built-in primitives again
        assert render_programs(["c(32,32,8)"], 2).sum() == render_np(parse("c(32,32,8)")).sum()
        with pytest.raises(ParseError, match="unknown 2D primitive 'd'"):
            parse("d(32,32,8)")


def test_a_new_2d_primitive_is_one_row(diamond, tmp_path):
    # codes and vocabulary follow the table
    assert codes().kind["d"] == 6 and codes().op == {"+": 7, "*": 8, "-": 9} and codes().stop == 10
    vocab = vocabulary(2)
    n_d = len(P.grammar_texts(diamond))
    assert len(vocab) == 400 + n_d and vocab.tokens[91:91 + n_d] == tuple(sorted(P.grammar_texts(diamond)))
    # both renderers, pixel for pixel, on programs given as text, objects and token indices
    texts = ["d(32,32,12)c(32,32,8)-", "s(20,20,16)d(30,34,20)*", "d(-3,70,9)t(30,30,20)+d(60,2,30)-", "d(5,5,0)"]
    progs = [parse(t) for t in texts]
    ref = np.stack([render_np(p) for p in progs])
    assert ref[0].any() and ref[1].any()
    assert (render_programs(texts, 2).numpy() == ref).all()
    assert (csgnet.render(progs) == ref).all()
    assert (csgnet.render(torch.tensor([vocab.encode(progs[0])])) == ref[:1]).all()
    assert Draw("d", (32, 32, 8)).name == "diamond"
    # export: the OpenSCAD form and a PNG
    scad = export.to_scad(progs[0])
    assert "polygon([[20, 32], [32, 20], [44, 32], [32, 44]]);  // d(32,32,12)" in scad
    png = export.save_png(ref[0], tmp_path / "d.png")
    assert png.stat().st_size > 0
    # synthetic data draws it
    rows = sample_programs(2, 3, 64, np.random.default_rng(0), Rules())
    drawn = {vocab.token(int(i))[0] for i in rows[:, :2].ravel()}
    assert "d" in drawn
    with pytest.raises(ValueError, match="one weight per 2D primitive type"):
        Rules(type_weights=(1, 1, 1)).resolved(2)
