"""Short programs: pruning operands, choosing by IoU minus a price per primitive, the short refinement rule."""
import numpy as np
import pytest

import csgnet
from csgnet.lang import Op, Program, parse
from csgnet.refinement import refine_guarded
from csgnet.score import program_scores
from csgnet.rewrite import LENGTH_PENALTY, choose, objective, prune, removals


def test_removals_replace_each_operator_by_each_operand():
    p = parse("c(32,32,20)s(32,32,8)c(20,20,8)+-")
    got = [r.text() for r in removals(p)]
    assert got == ["c(32,32,20)s(32,32,8)-", "c(32,32,20)c(20,20,8)-",
                   "c(32,32,20)", "s(32,32,8)c(20,20,8)+"]
    assert removals(parse("c(32,32,20)")) == []
    assert removals(parse("c(32,32,20)+", strict=False)) == []  # invalid: nothing to remove


def test_prune_removes_what_does_not_pay_and_keeps_what_does():
    target = csgnet.render("c(32,32,20)")[0]
    assert prune("c(32,32,20)c(8,8,8)-", target).text() == "c(32,32,20)"  # subtracts nothing
    assert prune("c(32,32,20)c(32,32,20)+", target).text() == "c(32,32,20)"  # a union with itself
    ring = csgnet.render("c(32,32,28)c(32,32,12)-")[0]
    assert prune("c(32,32,28)c(32,32,12)-", ring).text() == "c(32,32,28)c(32,32,12)-"
    # a hole of 113 pixels in 2,500: worth a primitive at the default price, not at a price of 0.5
    assert prune("c(32,32,28)c(32,32,6)-", ring, penalty=0.5).text() == "c(32,32,28)"
    bad = parse("c(32,32,20)+", strict=False)
    assert prune(bad, target) == bad


def test_prune_never_lowers_the_objective():
    rng = np.random.default_rng(0)
    from csgnet.synth import sample_programs
    from csgnet.vocab import vocabulary
    vocab = vocabulary(2)
    for row in sample_programs(2, 9, 8, rng):
        p = vocab.decode(list(row))
        target = csgnet.render(vocab.decode(list(sample_programs(2, 5, 1, rng)[0])).text())[0]
        q = prune(p, target, 0.01)
        (a, _), (b, _) = program_scores([p, q], target)
        assert objective(b, q, 0.01) >= objective(a, p, 0.01)
        assert len(q.draws) <= len(p.draws)


def test_choose_prefers_the_shorter_program_unless_the_longer_pays():
    target = csgnet.render("c(32,32,28)c(32,32,12)-")[0]
    exact, longer = "c(32,32,28)c(32,32,12)-", "c(32,32,28)c(32,32,12)-c(32,32,4)-"
    i, ious = choose([longer, exact], target)
    assert i == 1 and ious[0] == ious[1] == 1.0
    i, _ = choose(["c(32,32,28)", exact], target, penalty=0.0)
    assert i == 1
    i, _ = choose(["c(32,32,28)", exact], target, penalty=1.0)
    assert i == 0
    with pytest.raises(ValueError, match="at least one"):
        choose([], target)
    with pytest.raises(ValueError, match="2D program for a 3D"):
        choose([parse("c(32,32,8)")], csgnet.render("sp(32,32,32,12)", 3)[0])


def test_short_rule_writes_the_exact_two_circle_ring():
    target = csgnet.render("c(32,32,28)c(32,32,12)-")[0]
    bloated = "c(32,32,28)c(31,30,8)c(32,32,12)--c(31,31,12)-s(49,24,27)c(24,40,20)*+c(32,32,12)-"
    ref = refine_guarded("c(32,32,28)c(32,32,12)-", [bloated], target)
    assert ref.rule == "short" and ref.program.text() == "c(32,32,28)c(32,32,12)-" and ref.kept_start
    assert ref.after == ref.before
    paper = refine_guarded("c(32,32,28)c(32,32,12)-", [bloated], target, rule="chamfer")
    assert len(paper.program.draws) > 2
    assert LENGTH_PENALTY[2] > 0 and LENGTH_PENALTY[3] > 0


def test_graft_adds_a_donor_primitive_only_where_it_pays():
    from csgnet.rewrite import MAX_GRAFT_DRAWS, graft
    ring = csgnet.render("c(32,32,28)c(32,32,12)-")[0]
    assert graft("c(32,32,28)", ["c(32,32,12)c(20,20,8)+"], ring).text() == "c(32,32,28)c(32,32,12)-"
    assert graft("c(32,32,28)c(32,32,12)-", ["c(20,20,8)"], ring).text() == "c(32,32,28)c(32,32,12)-"
    assert graft("c(32,32,28)", [], ring).text() == "c(32,32,28)"
    # a hole of 113 of 2,460 pixels: worth a primitive at the default price, not at a price of 0.5
    small_hole = csgnet.render("c(32,32,28)c(32,32,6)-")[0]
    assert graft("c(32,32,28)", ["c(32,32,6)"], small_hole, penalty=0.5).text() == "c(32,32,28)"
    assert graft("c(32,32,28)", ["c(32,32,6)"], small_hole).text() == "c(32,32,28)c(32,32,6)-"
    many = "".join(f"c({8 + 4 * i},32,4)" for i in range(MAX_GRAFT_DRAWS)) + "+" * (MAX_GRAFT_DRAWS - 1)
    assert graft(many, ["c(32,32,28)"], ring).text() == parse(many).text()  # at the size limit: unchanged


def test_short_rule_grafts_a_missing_part_from_another_beam():
    target = csgnet.render("c(20,32,12)s(44,32,12)+")[0]
    without = refine_guarded("c(20,32,12)", ["c(20,32,12)", "s(44,32,12)c(8,8,8)*"], target, maxiter=0,
                             use_graft=False, use_extend=False, use_fit=False)
    assert without.program.text() == "c(20,32,12)"
    grafted = refine_guarded("c(20,32,12)", ["c(20,32,12)", "s(44,32,12)c(8,8,8)*"], target, maxiter=0,
                             use_extend=False, use_fit=False)
    assert grafted.program.text() == "c(20,32,12)s(44,32,12)+" and grafted.after[0] == 1.0


def test_extend_finds_the_missing_primitive_in_the_whole_vocabulary():
    from csgnet.rewrite import extend
    target = csgnet.render("s(16,16,12)c(16,16,8)-c(48,48,12)+")[0]  # primitives of the vocabulary's grid
    got = extend("s(16,16,12)", target)
    assert got.text() == "s(16,16,12)c(48,48,12)+c(16,16,8)-"  # the larger gain first
    assert program_scores([got], target)[0] == (1.0, 0.0)
    assert extend(got, target) == got  # nothing left to add
    assert extend("s(16,16,12)", target, penalty=1.0).text() == "s(16,16,12)"  # nothing pays at that price
    vol = csgnet.render("sp(32,32,32,16)cy(32,32,24,8,28)-", dim=3)[0]
    assert extend("sp(32,32,32,16)", vol).text() == "sp(32,32,32,16)cy(32,32,24,8,28)-"


def _intersection(draws, dim: int) -> Program:
    return Program(tuple(draws[:1]) + tuple(t for d in draws[1:] for t in (d, Op("*"))), dim)


def test_two_cubes_draw_any_box_exactly():
    from csgnet.rewrite import _box
    rng = np.random.default_rng(3)
    for _ in range(20):
        lo = rng.integers(0, 40, size=3)
        hi = lo + rng.integers(0, 24, size=3)
        vol = csgnet.render(_intersection(_box(lo, hi, 3), 3).text(), 3)[0]
        want = np.zeros((64,) * 3, bool)
        want[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = True
        assert np.array_equal(vol, want)
    assert _box(np.array([3, 3, 3]), np.array([7, 7, 7]), 3) == [parse("cu(5,5,5,5)", 3).draws[0]]  # one cube
    for _ in range(50):  # squares: trunc(centre -+ r * 1.412 / 2) bounds
        lo = rng.integers(0, 50, size=2)
        hi = lo + rng.integers(0, 64 - lo.max(), size=2)
        img = csgnet.render(_intersection(_box(lo, hi, 2), 2).text())[0]
        want = np.zeros((64, 64), bool)
        want[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1] = True
        assert np.array_equal(img, want), (lo, hi)


def _thin_table() -> np.ndarray:
    """A table whose 4-voxel legs and 6-voxel top are thinner than any primitive of the grammar (8)."""
    vol = np.zeros((64,) * 3, bool)
    vol[4:60, 16:48, 42:48] = True
    for x in (7, 52):
        for y in (18, 41):
            vol[x:x + 4, y:y + 4, 16:42] = True
    return vol


def test_fit_draws_parts_thinner_than_the_grammar():
    from csgnet.rewrite import MAX_FIT_DRAWS, fit
    vol = _thin_table()
    got = fit(None, vol)
    (iou, _), = program_scores([got], vol)
    assert iou > 0.9 and len(got.draws) <= MAX_FIT_DRAWS
    # from a wrong start, the missed parts are added and the wrong ones taken away
    start = parse("sp(32,32,20,12)", 3)
    better = fit(start, vol)
    (a, _), (b, _) = program_scores([start, better], vol)
    assert b > a + 0.5 and better.tokens[:1] == start.tokens
    # nothing pays at a price of one IoU per primitive; an exact program is left as it is
    assert fit(start, vol, penalty=1.0) == start
    assert fit(None, vol, penalty=1.0) is None
    exact = parse("cu(32,32,32,17)", 3)
    assert fit(exact, csgnet.render(exact.text(), 3)[0]) == exact
    bad = parse("cu(32,32,32,17)+", 3, strict=False)
    assert fit(bad, vol) == bad


def test_fit_in_2d_draws_a_bar_thinner_than_the_smallest_square():
    from csgnet.rewrite import fit
    img = np.zeros((64, 64), bool)
    img[30:34, 8:56] = True  # 4 rows by 48 columns
    got = fit(None, img)
    (iou, _), = program_scores([got], img)
    assert iou > 0.85


def test_short_rule_fits_the_thin_table():
    vol = _thin_table()
    start = parse("cu(32,32,40,25)", 3)
    without = refine_guarded(start, [start], vol, maxiter=0, use_extend=False, use_fit=False)
    fitted = refine_guarded(start, [start], vol, maxiter=0, use_extend=False)
    assert fitted.after[0] > 0.9 > without.after[0]


def test_the_grown_box_fills_the_thickest_arm_of_an_l_shaped_part():
    from csgnet.rewrite import _grown_box, part_candidates
    img = np.zeros((64, 64), bool)
    img[10:50, 10:30] = True   # the thick arm, 40 x 20
    img[40:50, 30:60] = True   # the thin arm, 10 x 30
    lo, hi = _grown_box(img)
    assert (lo.tolist(), hi.tolist()) == ([10, 10], [49, 29])
    cands = [_intersection(c, 2) for c in part_candidates(img)]
    ious = [iou for iou, _ in program_scores(cands, img)]
    assert ious[1] == pytest.approx(800 / 1100)  # the grown box: exactly the thick arm
    assert max(ious) < 1.0
