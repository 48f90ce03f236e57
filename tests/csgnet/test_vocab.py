import pytest

from csgnet.lang import parse
from csgnet.vocab import vocabulary


def test_2d_vocabulary_layout():
    v = vocabulary(2)
    assert len(v) == 400 and v.start == 400 and v.stop == 399
    assert all(t.startswith("c(") for t in v.tokens[0:91])
    assert all(t.startswith("s(") for t in v.tokens[91:260])
    assert all(t.startswith("t(") for t in v.tokens[260:396])
    assert v.tokens[396:] == ("+", "*", "-", "$")
    # plain string sort: '12' before '16' before '8'
    assert v.tokens[:3] == ("c(16,16,12)", "c(16,16,16)", "c(16,16,8)")
    assert "c(32,32,28)" in v.tokens and "c(32,32,32)" not in v.tokens


def test_3d_vocabulary_layout():
    v = vocabulary(3)
    assert len(v) == 6635 and v.stop == 6634 and v.start == 6635
    assert all(t.startswith("p(") for t in v.tokens[0:649])
    assert all(t.startswith("u(") for t in v.tokens[649:1990])
    assert all(t.startswith("y(") for t in v.tokens[1990:6631])
    assert v.tokens[6631:] == ("+", "*", "-", "$")
    assert v.tokens[0] == "p(16,16,16,12)"


@pytest.mark.parametrize("dim", [2, 3])
def test_token_index_round_trip(dim):
    v = vocabulary(dim)
    for i, t in enumerate(v.tokens):
        assert v.index(t) == i
    assert v.decode(v.encode(parse(v.tokens[5] + v.tokens[7] + "+", dim))).tokens == parse(v.tokens[5] + v.tokens[7] + "+", dim).tokens


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
