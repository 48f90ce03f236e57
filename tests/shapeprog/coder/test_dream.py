"""The dream phase: each rejection rule, sampling laws inherited by abstraction parameters, composite scenes,
determinism under a seed, and the executor path."""
import concurrent.futures as cf
import random

import pytest

from shapeprog.coder.dream import (BOUND, REJECTIONS, compose, dream, dreamed_functions, function_dreams,
                                   reject_reason, sample_dream, slot_kinds, split_cost)
from shapeprog.coder.execute import corners, execute
from shapeprog.coder.lang import LANG_2D, Library, parse, parse_abstraction, to_text

LIB = Library().add(parse_abstraction(
    "P(w: Float, h: Float, x: Float, a: Float) = SymRef(Rotate(Move(Cuboid(w,h,w),x,0.0,0.0),AZ,a),AX)"))

# one expression per rule, each passing every earlier rule
REJECTED = [
    ("exception", "SymRef(Move(Cuboid(w,0.5,0.1),-0.4,0.0,0.0),AX)"),
    ("hard error", "SymRef(Move(Cuboid(-0.1,0.5,0.1),-0.4,0.0,0.0),AX)"),
    ("soft error", "SymRef(Move(Cuboid(0.1,0.5,0.1),0.4,0.0,0.0),AX)"),
    ("nested", "SymRef(Move(Move(Cuboid(0.1,0.5,0.1),-0.4,0.0,0.0),0.0,0.1,0.0),AX)"),
    ("too many prims", "SymTrans(Move(Cuboid(0.05,0.5,0.5),-0.9,0.0,0.0),AX,INT#16#,1.6)"),
    ("dim <= 0", "SymRef(Move(Cuboid(0.004,0.5,0.5),-0.4,0.0,0.0),AX)"),
    ("out of bounds", "SymRef(Move(Cuboid(0.1,0.5,0.1),-1.1,0.0,0.0),AX)"),
    ("volume", "SymRef(Move(Cuboid(0.05,0.1,0.05),-0.4,0.0,0.0),AX)"),
    ("overlap", "SymRef(Move(Cuboid(0.5,0.5,0.5),-0.1,0.0,0.0),AX)"),
    ("literal", "SymRef(Rotate(Move(Cuboid(0.1,0.5,0.3),-0.4,0.0,0.0),AY,0.9),AX)"),  # re-oriented: angle -0.67
    ("not cheaper", "Move(Cuboid(0.3,0.5,0.4),-0.4,0.1,0.2)"),
]


@pytest.mark.parametrize("reason,text", REJECTED, ids=[r for r, _ in REJECTED])
def test_each_rejection_rule(reason, text):
    assert reject_reason(parse(text, LIB), LIB) == reason


def test_rules_are_checked_in_order_and_valid_dreams_are_kept():
    assert [r for r, _ in REJECTED] == list(REJECTIONS)
    assert reject_reason(parse("SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,0.0,0.2),AX)")) is None
    assert reject_reason(parse("SymTrans(Move(Cuboid(0.1,0.5,0.1),-0.4,0.0,0.0),AX,INT#2#,0.8)")) is None
    # a soft error rejects base-function dreams only
    soft = parse("P(0.1,0.5,0.4,0.0)", LIB)
    assert reject_reason(soft, LIB) is None and reject_reason(soft, LIB, base=True) == "soft error"
    # a hard error beats every later rule; out of bounds beats overlap
    assert reject_reason(parse("SymRef(Move(Cuboid(0.0,0.5,0.5),-2.0,0.0,0.0),AX)")) == "hard error"
    assert reject_reason(parse("SymRef(Move(Cuboid(0.5,0.5,0.5),-0.9,0.0,0.0),AX)")) == "out of bounds"


def test_split_cost_counts_distinct_floats():
    e = parse("SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,0.0,0.5),AX)")
    assert split_cost(e) == (3.0, 2.0 * 3 + 0.5 + 0.5)  # 0.1 0.5 -0.4 distinct; the constant 0.0; AX


def test_dreams_are_valid_and_within_bounds():
    fd = function_dreams("SymTrans", Library(), n=30, seed=1)
    assert len(fd.dreams) == 30 and sum(fd.failures.values()) > 0
    for d in fd.dreams:
        assert reject_reason(d.expr) is None
        assert abs(corners(d.prims)).max() <= BOUND + 1e-9
    assert set(fd.failures) <= set(REJECTIONS)


def test_abstraction_parameters_take_the_law_of_their_slot():
    lib = LIB.add(parse_abstraction("Q(w: Float, d: Float) = SymTrans(Move(Cuboid(w,0.1,Mul(w,2.0)),-0.3,0.0,0.0),"
                                    "AZ,INT#2#,d)", LIB))
    assert slot_kinds("P", lib) == {"w": "w", "h": "h", "x": "x", "a": "rz"}
    assert slot_kinds("Q", lib) == {"w": "w", "d": "dist"}
    assert dreamed_functions(lib) == ("SymRef", "SymTrans", "P", "Q")
    rng = random.Random(0)
    dists = [sample_dream("Q", lib, rng).args[1].value for _ in range(200)]
    assert min(dists) >= 0.1 and max(dists) <= 1.5  # U(0.1, 1.5)
    assert len(function_dreams("Q", lib, n=5, seed=0).dreams) == 5


def test_abandoned_after_too_many_failures(monkeypatch):
    import shapeprog.coder.dream as dm

    monkeypatch.setattr(dm, "MAX_FAILURES", 30)
    lib = Library().add(parse_abstraction("Big(w: Float) = Move(Cuboid(Add(w,3.0),1.0,1.0),0.0,0.0,0.0)"))
    fd = function_dreams("Big", lib, n=5, seed=0)
    assert fd.abandoned and not fd.dreams and fd.failures == {"out of bounds": 31}
    assert "Big" not in {p.fn for p in dream(lib, n=3, seed=0).pairs}


def test_dreams_are_deterministic_and_the_executor_gives_the_same():
    shapes = [d.prims for d in function_dreams("SymRef", Library(), n=5, seed=9).dreams]
    a = dream(LIB, n=12, seed=3, shapes=shapes)
    b = dream(LIB, n=12, seed=3, shapes=shapes)
    c = dream(LIB, n=12, seed=4, shapes=shapes)
    key = lambda d: [(p.scene, to_text(p.target), p.moved) for p in d.pairs]  # noqa: E731
    assert key(a) == key(b) != key(c)
    with cf.ProcessPoolExecutor(2) as ex:
        assert key(dream(LIB, n=12, seed=3, shapes=shapes, executor=ex)) == key(a)
    counts = {f: sum(p.fn == f for p in a.pairs) for f in ("SymRef", "SymTrans", "P")}
    assert counts == {"SymRef": 12, "SymTrans": 12, "P": 12}
    assert any(p.moved for p in a.pairs) and any(not p.moved for p in a.pairs)
    assert max(len(p.scene) for p in a.pairs) <= 16
    cache: dict = {}
    dream(LIB, n=12, seed=3, cache=cache)
    assert list(cache) == [LIB["P"].to_text()]


def test_composite_scenes_hold_their_targets():
    pools = {"SymRef": list(function_dreams("SymRef", Library(), n=6, seed=2).dreams)}
    pairs = compose(pools, 6, random.Random(0), Library().lang)
    assert len(pairs) == 6
    for p in pairs:
        got = set(execute(p.target))
        if p.moved:  # the extra Move shifts the primitives: same dimensions, not the same positions
            assert {q[:3] for q in got} <= {q[:3] for q in p.scene}
        else:
            assert got <= set(p.scene)


def test_2d_dreams():
    d = dream(Library(LANG_2D), n=5, seed=0)
    assert {p.fn for p in d.pairs} == {"SymRef", "SymTrans"}
    assert all(len(p.scene[0]) == 4 and len(p.scene) <= 12 for p in d.pairs)
