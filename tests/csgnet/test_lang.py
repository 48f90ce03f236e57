import random
import re

import pytest

from csg_testutil import random_program
from csgnet.lang import Draw, Node, Op, ParseError, Program, is_valid, parse, parse_lines, prefix_status, to_text

EXAMPLE = "c(32,32,28)c(32,32,24)-s(32,32,28)s(32,32,20)-+t(32,32,20)+"


def test_parse_2d_example():
    p = parse(EXAMPLE)
    assert p.dim == 2 and len(p) == 9 and len(p.draws) == 5
    assert p.tokens[0] == Draw("c", (32, 32, 28))
    assert p.tokens[2] == Op("-")
    assert p.text() == EXAMPLE


def test_3d_long_and_vocabulary_forms_parse_to_the_same_program():
    a = parse("sp(32,32,32,8)cu(16,16,16,12)+cy(24,24,24,8,16)-", dim=3)
    b = parse("p(32,32,32,8)u(16,16,16,12)+y(24,24,24,8,16)-", dim=3)
    assert a == b
    assert a.text() == "sp(32,32,32,8)cu(16,16,16,12)+cy(24,24,24,8,16)-"
    assert a.text(long=False) == "p(32,32,32,8)u(16,16,16,12)+y(24,24,24,8,16)-"


def test_text_after_stop_is_dropped_and_whitespace_ignored():
    assert parse("c(8,8,8) s(16,16,8)\n+$t(1,2,3)+++") == parse("c(8,8,8)s(16,16,8)+")


@pytest.mark.parametrize("dim,n", [(2, 1), (2, 4), (2, 7), (3, 1), (3, 4)])
def test_round_trip_random_programs(dim, n):
    rng = random.Random(dim * 10 + n)
    for _ in range(50):
        p = random_program(rng, dim, n)
        assert parse(to_text(p), dim) == p
        assert parse(p.text(long=False), dim) == p
        assert to_text(parse(to_text(p), dim)) == to_text(p)


def test_tree_view_round_trip_and_operand_order():
    p = parse("c(8,8,8)s(16,16,8)-t(24,24,8)+")
    tree = p.tree()
    assert isinstance(tree, Node) and tree.op == "+"
    assert tree.left == Node("-", Draw("c", (8, 8, 8)), Draw("s", (16, 16, 8)))
    assert tree.right == Draw("t", (24, 24, 8))
    assert Program.from_tree(tree) == p


@pytest.mark.parametrize("text,fragment,position", [
    ("c(32,32,28)q(1,2,3)+", "unknown 2D primitive 'q'", 11),
    ("c(32,32,28)s(1,2)+", "square takes 3 parameters", 11),
    ("c(32,32,28)s(1,2.5,3)+", "non-integer '2.5'", 11),
    ("c(32,32,28)s(1,,3)+", "parameter y is missing", 11),
    ("c(32,32,28)+", "stack underflow", 11),
    ("c(32,32,28)s(8,8,8)", "unfinished program", 19),
    ("c(32,32,28),s(8,8,8)+", "malformed token", 11),
    ("c(32,32,-4)", "must be >= 0", 0),
    ("c(32,32,28", "malformed token", 0),
])
def test_errors_name_token_and_position(text, fragment, position):
    with pytest.raises(ParseError) as e:
        parse(text)
    assert fragment in str(e.value)
    assert e.value.position == position
    assert repr(text) in str(e.value)


def test_empty_program_is_an_error_when_strict_and_invalid_otherwise():
    with pytest.raises(ParseError, match="empty program"):
        parse("")
    assert not is_valid(parse("", strict=False))


def test_3d_primitive_in_2d_program_is_rejected():
    with pytest.raises(ParseError, match="unknown 2D primitive 'sp'"):
        parse("sp(1,2,3,4)", dim=2)
    with pytest.raises(ParseError, match="cylinder takes 5 parameters"):
        parse("cy(1,2,3,4)", dim=3)


def test_negative_positions_are_allowed():
    assert parse("c(-4,70,12)").tokens[0].params == (-4, 70, 12)


def test_validity_automaton():
    assert prefix_status([]) == "open"
    assert prefix_status(["d"]) == "complete"
    assert prefix_status(["d", "d"]) == "open"
    assert prefix_status(["d", "+"]) == "invalid"
    assert prefix_status(["d", "d", "+", "d", "-"]) == "complete"
    assert not is_valid(parse("c(8,8,8)+s(8,8,8)", strict=False))
    assert is_valid(parse(EXAMPLE))


def test_dataset_lines_report_file_and_line():
    lines = ["c(8,8,8)", "c(8,8,8)s(8,8,8)+", "c(8,8,8)x(1,2,3)+", "", "t(8,8,8)"]
    with pytest.raises(ParseError) as e:
        parse_lines(lines, file="data/train.txt")
    assert str(e.value).startswith("data/train.txt:3:9: unknown 2D primitive 'x'")
    progs, errs = parse_lines(lines, file="data/train.txt", errors="collect")
    assert len(progs) == 3 and len(errs) == 1 and errs[0].line == 3


def test_program_rejects_mixed_dimensions():
    with pytest.raises(ValueError, match="3D primitive in a 2D program"):
        Program((Draw("p", (1, 2, 3, 4)),), 2)


def test_with_params_replaces_draw_parameters_in_order():
    p = parse("c(32,32,16)s(24,40,12)+t(8,8,8)-")
    q = p.with_params([1, 2, 3, 4, 5, 6, 7, 8, 9])
    assert q.text() == "c(1,2,3)s(4,5,6)+t(7,8,9)-"
    assert p.with_params([v for d in p.draws for v in d.params]) == p
    p3 = parse("cy(32,32,32,8,16)sp(32,32,32,8)+", 3)
    assert p3.with_params(range(9)).text() == "cy(0,1,2,3,4)sp(5,6,7,8)+"
    with pytest.raises(ValueError, match="9 parameter values needed"):
        p.with_params([1, 2])


def test_completable_agrees_with_exhaustive_completion():
    """From every state reachable by following the rule (the empty stack, or one that can still finish),
    draw/op/stop are allowed exactly when a valid program within the length limit extends the prefix."""
    import numpy as np

    from csgnet.lang import completable

    for limit in range(1, 8):
        for depth in range(0, 6):
            for used in range(limit):
                remaining = limit - used

                def can_finish(d, r):  # with d shapes and r tokens left, can we end with one shape?
                    return d >= 1 and d - 1 <= r

                if depth and not can_finish(depth, remaining):
                    continue  # unreachable when every earlier token followed the rule

                draw, op, stop = completable(depth, remaining)
                assert draw == can_finish(depth + 1, remaining - 1)
                assert op == (depth >= 2 and can_finish(depth - 1, remaining - 1))
                assert stop == (depth == 1)
    d = np.array([0, 1, 2, 3])
    assert [a.tolist() for a in completable(d, 3)] == [[True, True, True, False], [False, False, True, True],
                                                       [False, True, False, False]]


FAST_PATH_TEXTS = [
    ("c(32,32,28)c(32,32,24)-", 2), (" c( 1, 2 ,3 ) s(4,5,6)\t+ $ junk(", 2), ("c(-4,70,0)t(+3,2,1)*", 2),
    ("sp(32,32,32,8)u(16,16,16,12)+", 3), ("y(1,2,3,4,5)$", 3), ("c(1,2,3)c(4,5,6)", 2), ("+", 2), ("", 2),
    ("   ", 2), ("c(1,2,3)-", 2), ("c(1,$,3)", 2), ("c(1,2,-3)", 2), ("c(1,2)", 2), ("q(1,2,3)", 2),
    ("sp(1,2,3,4)", 2), ("c(1,2,3)", 3), ("c(1,2,3)x", 2), ("c(1,2,3))", 2), ("c(a,2,3)", 2), ("C(1,2,3)", 2),
    ("c(1,2,3)c(1,2,3)c(1,2,3)++", 2), ("c(1,2,3)++", 2), ("$c(1,2,3)", 2), ("cy(1,2,3,4,-1)", 3),
]


@pytest.mark.parametrize("strict", [True, False])
def test_fast_path_agrees_with_the_full_scan(monkeypatch, strict):
    """parse() takes cached per-token objects when a text is well formed; the result (or the error,
    text and position) is what the full scan gives."""
    from csgnet import lang

    def outcome(text, dim):
        try:
            return parse(text, dim, strict)
        except ParseError as e:
            return (str(e), e.position, e.token)

    fast = [outcome(t, d) for t, d in FAST_PATH_TEXTS]
    fast_again = [outcome(t, d) for t, d in FAST_PATH_TEXTS]  # from the per-token cache
    monkeypatch.setattr(lang, "_fast_tokens", lambda text, dim: None)
    assert fast == fast_again == [outcome(t, d) for t, d in FAST_PATH_TEXTS]


@pytest.mark.parametrize("text, message", [
    ("c(٣٢,32,10)", "non-integer '٣٢'"),
    ("c(32,32,１０)", "non-integer '１０'"),
    ("c(99999999999999999999,32,10)", "parameter x is 999999999...: parameters are within ±1000"),
    ("s(32,-1001,10)", "parameter y is -1001"),
])
def test_defect9_parameters_are_ascii_integers_within_the_limit(text, message):
    from csgnet.lang import MAX_PARAM

    with pytest.raises(ParseError, match=re.escape(message)) as e:
        parse(text)
    assert e.value.position == 0
    assert parse(f"c({MAX_PARAM},-{MAX_PARAM},{MAX_PARAM})").draws[0].params == (1000, -1000, 1000)
    with pytest.raises(ValueError, match="within"):
        Draw("c", (10**20, 32, 10))


def test_defect9_program_length_limit_is_located():
    from csgnet.lang import MAX_TOKENS

    n = MAX_TOKENS // 2
    ok = "c(1,1,1)" * (n + 1) + "+" * n  # MAX_TOKENS + 1 tokens
    with pytest.raises(ParseError, match=f"more than {MAX_TOKENS} tokens") as e:
        parse(ok)
    assert e.value.position == len("c(1,1,1)" * (n + 1) + "+" * (n - 1))
    assert len(parse("c(1,1,1)" * n + "+" * (n - 1))) == MAX_TOKENS - 1
    err = ParseError("x", "t", 3).located("data.txt", 7)
    assert str(err).startswith("data.txt:7:4: x")


def test_rendering_a_text_holds_it_to_the_token_limit_as_parse_does():
    import csgnet
    from csgnet.lang import MAX_TOKENS

    text = "c(32,32,8)" + "c(32,32,8)+" * (MAX_TOKENS // 2)
    with pytest.raises(ParseError, match="too long"):
        csgnet.parse(text)
    with pytest.raises(ParseError, match="too long"):
        csgnet.render([text])
