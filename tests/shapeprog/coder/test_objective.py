"""The ShapeCoder objective: token costs, ω, Hungarian matching with the corner-Hausdorff distance, and the
naive cost of the data (the paper's "Input Prims" row)."""
import math

import numpy as np
import pytest

from shapeprog.coder import data
from shapeprog.coder.execute import execute
from shapeprog.coder.lang import LANG_2D, Library, parse, parse_abstraction
from shapeprog.coder.objective import (WEIGHTS, AbstractionStats, TokenWeights, abstraction_stats, distance_matrix,
                                       match, naive_cost, naive_program, naive_summary, objective, omega, preference,
                                       program_cost, token_counts)

# Table 2 of the paper, "Input Prims": F, and the re-computation of the specification (to 2 decimals)
PAPER = {"chair": 146.0, "table": 125.0, "storage": 154.0}
CHECKED = {"chair": (146.46, 29.42, 60.83), "table": (125.80, 24.58, 51.15), "storage": (154.00, 30.17, 62.34)}


def test_naive_cost_of_the_discovery_shapes_is_the_papers_input_prims_row():
    for cat in data.CATEGORIES:
        row = naive_summary(r.prims for r in data.load(cat))
        assert row.shapes == 400
        assert abs(row.F - PAPER[cat]) / PAPER[cat] < 0.01, (cat, row)
        assert (round(row.F, 2), round(row.num_struct, 2), round(row.num_param, 2)) == CHECKED[cat]


def test_naive_cost_by_hand_and_as_a_program():
    one = naive_cost([(1, 1, 1, 0, 0, 0, 0, 0, 0)])  # one Cuboid at the origin: 1 function, 3 dims
    assert (one.fn, one.floats, one.cats) == (1, 3, 0) and one.cost() == 1 + 2 * 3
    c = naive_cost([(1, 1, 1, 0, 0, 0, 0, 0, 0), (0.5, 0.2, 0.3, 0.1, 0, 0, 0.2, 0, -0.1)])
    # Union, 2 Cuboids, 1 Move, 2 Rotates; 3 + 3 dims, 3 offsets, 2 angles; 2 axes
    assert (c.fn, c.floats, c.cats) == (6, 11, 2) and c.cost() == 6 + 22 + 1
    assert c.struct() == 6 and c.param(TokenWeights(float_var=1.0, cat=1.0)) == 13
    c2 = naive_cost([(0.2, 0.1, -0.3, 0.4), (0.2, 0.1, 0.0, 0.0)])  # 2D: 2 dims, 2 offsets
    assert (c2.fn, c2.floats, c2.cats) == (4, 6, 0)
    for cat in data.CATEGORIES:
        for rec in data.load(cat)[::20]:
            expr, _ = naive_program(rec.prims)
            counts, naive = token_counts(expr), naive_cost(rec.prims)
            assert (counts.fn, counts.float_var, counts.cat, counts.float_const) == (naive.fn, naive.floats,
                                                                                       naive.cats, 0)
            assert program_cost(expr) == naive.cost()


def test_token_weights():
    lib = Library().add(parse_abstraction("Leg(w: Float, a: Axis) = SymRef(Move(Cuboid(w,0.5,w),w,0,1),a)"))
    e = parse("Union(Leg(Add(x,0.1),AX),SymTrans(Cuboid(x,2,0.0),AY,INT#3#,Inv(y)))", lib)
    c = token_counts(e, lib)
    # fn: Union Leg SymTrans Cuboid; float_fn: Add Inv; float_var: x 0.1 x y; const: 2 0.0; cat: AX AY INT#3#
    assert (c.fn, c.float_fn, c.float_var, c.float_const, c.cat) == (4, 2, 4, 2, 3)
    assert program_cost(e, lib) == pytest.approx(4 + 0.2 + 8 + 1 + 1.5)
    assert program_cost(e, lib, error=0.03) == pytest.approx(14.7 + 0.3)
    assert c.num_struct == 4 and c.num_param == 7
    assert token_counts(parse("SymRef(Cuboid(a,b,a),v)")).cat == 1  # an Axis variable is categorical
    assert WEIGHTS == TokenWeights(1.0, 0.1, 2.0, 0.5, 0.5, 10.0)


@pytest.mark.parametrize("text, stats, pref", [
    # the specification's example: one parametric expression (+0.1), 3 functions without Union (-0.05)
    ("A(a: Float, b: Float, c: Float) = SymRef(Move(Cuboid(a,b,a),c,Mul(b,2.0),0.0),AX)",
     AbstractionStats(3, 0, 3, 1, 1, 1), 0.05),
    # two expressions (+0.25), a Union (+0.25): clamped to 0.5
    ("A(a: Float, b: Float) = Union(Cuboid(a,b,Add(a,b)),Move(Cuboid(a,a,a),Sub(a,b),0.0,0.0))",
     AbstractionStats(4, 1, 2, 2, 3, 2), 0.5),
    # one function, no constant, re-use or expression: -0.5 - 0.15
    ("A(a: Float, b: Float, c: Float) = Cuboid(a,b,c)", AbstractionStats(1, 0, 3, 0, 0, 0), -0.65),
    # one re-use (-0.2), three functions (-0.05), 6 parameters (-0.1)
    ("A(a: Float, b: Float, c: Float, d: Float, e: Float, f: Float) = Rotate(Move(Cuboid(a,b,c),d,e,a),AX,f)",
     AbstractionStats(3, 0, 6, 0, 1, 0), -0.35),
    # 8 free parameters (7 floats and an axis): -0.5 - 0.05 - 0.5 = -1.05, clamped to -1
    ("A(a: Float, b: Float, c: Float, d: Float, e: Float, f: Float, g: Float, x: Axis) = "
     "Rotate(Move(Cuboid(a,b,c),d,e,f),x,g)", AbstractionStats(3, 0, 8, 0, 0, 0), -1.0),
])
def test_preferences(text, stats, pref):
    ab = parse_abstraction(text)
    assert abstraction_stats(ab) == stats
    assert preference(ab) == pytest.approx(pref)
    assert omega(ab) == pytest.approx(0.25 * (1 - pref))


def test_preference_rejections_and_objective():
    ab = parse_abstraction("A(a: Float, b: Float) = Union(Cuboid(a,b,Add(a,b)),Move(Cuboid(a,a,a),Sub(a,b),0,0))")
    assert preference(ab, frequency=0.005) is None and omega(ab, frequency=0.005) == 0.5
    ten = AbstractionStats(5, 1, 10, 0, 0, 2)
    assert preference(ten) is None and omega(ten) == 0.5
    assert preference(ab) == pytest.approx(0.5) and omega(ab) == pytest.approx(0.125)  # 0.25 * (1 - 0.5)
    lib = Library().add(ab)
    progs = [parse("A(0.1,0.2)", lib), parse("Union(A(0.1,x),Cuboid(1,1,1))", lib)]
    costs = [program_cost(p, lib) for p in progs]
    assert costs == [1 + 4, 3 + 4 + 1.5]
    assert objective(progs, lib) == pytest.approx(sum(costs) / 2 + 0.125)
    assert objective(progs, lib, errors=[0.0, 0.04]) == pytest.approx((sum(costs) + 0.4) / 2 + 0.125)
    with pytest.raises(ValueError, match="2 programs but 1 errors"):
        objective(progs, lib, errors=[0.0])
    # the public entry point: the module itself is F, its names stay reachable
    from shapeprog import coder
    assert coder.objective(progs, lib, errors=[0.0, 0.04]) == objective(progs, lib, errors=[0.0, 0.04])
    assert coder.objective.objective is objective and coder.objective.match is match


def _box(w, h, d, x=0.0, y=0.0, z=0.0, a=0.0, b=0.0, c=0.0):
    return (w, h, d, x, y, z, a, b, c)


def test_corner_hausdorff_distance():
    a = [_box(0.2, 0.4, 0.6)]
    assert distance_matrix(a, [_box(0.2, 0.4, 0.6, 0.03, -0.04)])[0, 0] == pytest.approx(0.05)
    assert distance_matrix(a, [_box(0.2, 0.5, 0.6)])[0, 0] == pytest.approx(0.05)  # half the size change
    # the corner sets, not the parametrisation: a half turn about z gives the same box
    assert distance_matrix(a, [_box(0.2, 0.4, 0.6, c=math.pi)])[0, 0] == pytest.approx(0.0, abs=1e-12)
    # a box swapped in w and d and turned a quarter about y is the same box
    assert distance_matrix(a, [_box(0.6, 0.4, 0.2, b=math.pi / 2)])[0, 0] == pytest.approx(0.0, abs=1e-12)
    # symmetric, (Pa, Pb)
    rng = np.random.default_rng(0)
    p, q = rng.uniform(0.05, 0.5, (4, 9)), rng.uniform(0.05, 0.5, (3, 9))
    assert distance_matrix(p, q).shape == (4, 3) and np.allclose(distance_matrix(p, q), distance_matrix(q, p).T)
    # 2D: the sum of absolute differences of W, H, X, Y
    assert distance_matrix([(0.2, 0.1, 0.0, 0.5)], [(0.21, 0.1, -0.02, 0.5)])[0, 0] == pytest.approx(0.03)
    with pytest.raises(ValueError, match=r"must be \(P, 9\) or \(P, 4\)"):
        distance_matrix([(1, 2, 3)], a)


def test_match_is_invariant_to_permutations():
    rng = np.random.default_rng(1)
    shape = execute(parse("Union(SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,-0.25,0.3),AX),"
                          "Union(Rotate(Move(Cuboid(0.8,0.1,0.6),0,0.1,0),AX,0.2),Cuboid(0.3,0.3,0.3)))"))
    for _ in range(10):
        target = np.array(shape) + rng.normal(0, 0.01, (len(shape), 9)) * [1, 1, 1, 1, 1, 1, 0, 0, 0]
        made = np.array(shape[1:4])
        m = match(made, target)
        assert m.valid and len(m.pairs) == 3 and m.error < 0.05
        pa, pb = rng.permutation(len(made)), rng.permutation(len(target))
        mp = match(made[pa], target[pb])
        assert mp.valid and mp.error == pytest.approx(m.error, abs=1e-12)
        # the same pairs, renamed through the permutations
        assert sorted((int(pa[i]), int(pb[j])) for i, j in mp.pairs) == sorted(m.pairs)
        assert m.covered == tuple(sorted(j for _, j in m.pairs))


def test_match_validity():
    t = [_box(0.2, 0.4, 0.6), _box(0.2, 0.4, 0.6, 0.5), _box(0.1, 0.1, 0.1, -0.5)]
    assert match(t, t).valid and match(t, t).error == 0.0 and match(t, t).covered == (0, 1, 2)
    far = match([_box(0.2, 0.4, 0.6, 0.5, 0.2)], t)
    assert not far.valid and far.error == pytest.approx(0.2) and far.pairs == ((0, 1),)
    assert match([_box(0.2, 0.4, 0.6, 0.5, 0.2)], t, threshold=0.25).valid
    assert not match(t, t[:2]).valid  # more primitives than the target
    assert not match([], t).valid and match([], t).error == 0.0
    # the penalty: a valid assignment wins over a cheaper one with a pair above the threshold
    a = [_box(1, 1, 1), _box(1, 1, 1, 0.09)]
    b = [_box(1, 1, 1), _box(1, 1, 1, 0.0, 0.09)]
    m = match(a, b)
    assert m.valid and m.pairs == ((0, 1), (1, 0)) and m.error == pytest.approx(0.09)
    m0 = match(a, b, penalty=0.0)
    assert not m0.valid and m0.pairs == ((0, 0), (1, 1)) and m0.error == pytest.approx(0.09 * math.sqrt(2) / 2)
    two_d = match([(0.2, 0.1, 0.0, 0.5)], [(0.2, 0.1, 0.3, 0.5), (0.21, 0.1, -0.02, 0.5)])
    assert two_d.threshold == LANG_2D.match_threshold and two_d.valid and two_d.pairs == ((0, 1),)
