import pytest

from csgnet.lang import parse
from csgnet.vocab import vocabulary


# (dim, size, [(token head, first index, end index) per primitive type], first tokens): spec section (a)
LAYOUTS = [
    (2, 400, [("c(", 0, 91), ("s(", 91, 260), ("t(", 260, 396)],
     ("c(16,16,12)", "c(16,16,16)", "c(16,16,8)")),  # plain string sort: '12' before '16' before '8'
    (3, 6635, [("p(", 0, 649), ("u(", 649, 1990), ("y(", 1990, 6631)], ("p(16,16,16,12)",)),
]


@pytest.mark.parametrize("dim,n,blocks,first", LAYOUTS)
def test_vocabulary_layout(dim, n, blocks, first):
    v = vocabulary(dim)
    assert len(v) == n and v.start == n and v.stop == n - 1
    for head, lo, hi in blocks:
        assert all(t.startswith(head) for t in v.tokens[lo:hi]), head
    assert v.tokens[n - 4:] == ("+", "*", "-", "$")
    assert v.tokens[:len(first)] == first


def test_2d_vocabulary_holds_only_primitives_inside_the_canvas():
    v = vocabulary(2)
    assert "c(32,32,28)" in v.tokens and "c(32,32,32)" not in v.tokens


@pytest.mark.parametrize("dim", [2, 3])
def test_token_index_round_trip(dim):
    v = vocabulary(dim)
    for i, t in enumerate(v.tokens):
        assert v.index(t) == i
    program = parse(v.tokens[5] + v.tokens[7] + "+", dim)
    assert v.decode(v.encode(program)) == program


def test_encode_decode_program_and_cut_at_stop():
    v = vocabulary(2)
    text = "c(32,32,28)c(32,32,24)-s(32,32,28)s(32,32,20)-+t(32,32,20)+"
    ids = v.encode(text)
    assert v.text(ids + [v.stop, 3, 4]) == text
    assert v.index("+") == 396
    assert vocabulary(3).index("sp(32,32,32,8)") == vocabulary(3).index("p(32,32,32,8)")


def test_off_vocabulary_primitive_is_a_clear_error():
    with pytest.raises(KeyError, match="not in the 2D vocabulary"):
        vocabulary(2).index("c(27,33,13)")
    with pytest.raises(ValueError, match="out of range"):
        vocabulary(2).decode([400])
