"""Tests of csgnet.refinement: Powell refinement of 2D and 3D program parameters (spec section (g))."""

from __future__ import annotations

import random

import numpy as np
import pytest
import torch
from scipy.optimize import OptimizeResult

import csgnet
from csgnet import metrics, refinement
from csgnet.lang import Draw, Op, Program, parse
from csgnet.primitives import SIZES, primitive
from csgnet.renderer import pack, render_programs
from csg_testutil import random_program


def rendered(program) -> np.ndarray:
    return render_programs([program], 2)[0].numpy()


def perturbed(program: Program, rng: random.Random, step: int = 3) -> Program:
    return Program(tuple(Draw(t.kind, tuple(v + rng.randint(-step, step) for v in t.params))
                         if isinstance(t, Draw) else t for t in program.tokens), program.dim)


def grid_program(rng: random.Random, n_prims: int) -> Program:
    """A random valid program whose parameters stay in the reference's box [8, 56] after perturbation."""
    p = random_program(rng, 2, n_prims)
    return Program(tuple(Draw(t.kind, (rng.randint(12, 52), rng.randint(12, 52), rng.randint(11, 24)))
                         if isinstance(t, Draw) else t for t in p.tokens), 2)


def cases(n: int, seed: int):
    """(start program, target image) pairs: a random program's rendering and a perturbed copy."""
    rng = random.Random(seed)
    out = []
    while len(out) < n:
        p = grid_program(rng, rng.randint(1, 4))
        target = rendered(p)
        if target.any() and not target.all():
            out.append((perturbed(p, rng), target))
    return out


def test_public_entry_point_is_the_function():
    assert csgnet.refine is refinement.refine
    assert callable(csgnet.refine) and csgnet.refine_beams is refinement.refine_beams


@pytest.mark.parametrize("mode", ["improved", "reference"])
@pytest.mark.parametrize("maxiter", [1, None])
def test_never_worsens_chamfer_and_score_is_the_programs(mode, maxiter):
    for start, target in cases(6, seed=1 if maxiter else 2):
        res = refinement.refine(start, target, maxiter=maxiter, mode=mode)
        assert res.initial_score == metrics.chamfer(rendered(start), target)
        actual = metrics.chamfer(rendered(res.program), target)
        if mode == "improved":
            assert res.score == actual  # bit for bit: the returned score is the returned program's
            assert res.score <= res.initial_score
            if not res.improved:
                assert res.program is start
        else:
            assert res.score <= res.initial_score  # Powell's objective never rises
        assert res.evaluations >= res.rendered > 0 and res.iterations >= 1


def test_iou_metric_never_worsens_and_is_exact():
    for start, target in cases(4, seed=3):
        res = refinement.refine(start, target, metric="iou", maxiter=2)
        assert res.score == metrics.iou(rendered(res.program), target)
        assert res.initial_score == metrics.iou(rendered(start), target)
        assert res.score >= res.initial_score


@pytest.mark.parametrize("target_text, start_text", [
    ("c(32,32,16)", "c(30,35,12)"),
    ("c(24,30,12)s(40,36,16)+", "c(25,30,12)s(40,34,16)+"),
    ("s(32,32,24)t(30,34,12)-", "s(33,32,22)t(31,35,12)-"),
    ("c(32,32,20)c(32,32,12)-", "c(30,33,21)c(34,31,10)-"),
])
def test_perturbed_program_recovers_the_target(target_text, start_text):
    target = rendered(parse(target_text))
    res = csgnet.refine(start_text, target)
    assert res.score == 0.0 and res.initial_score > 0.5
    assert np.array_equal(rendered(res.program), target)
    assert res.text == target_text


def test_rounding_vs_truncation_on_a_hand_case():
    # Truncation: Powell's first probe below r = 12 (any tiny step down) lowers the radius, a probe up
    # needs a whole pixel; the reference stops at r = 14 here, the rounded objective reaches 16.
    target = rendered(parse("c(32,32,16)"))
    assert csgnet.refine("c(30,35,12)", target, mode="reference").text == "c(32,32,14)"
    assert csgnet.refine("c(30,35,12)", target, mode="improved").text == "c(32,32,16)"


def test_reference_objective_truncates_and_clips_everything_to_8_56():
    prog = parse("c(32,32,16)")
    scorer = refinement._Scorer(rendered(prog), "chamfer")
    lo, hi = refinement._box(prog, "reference", None)
    ref = refinement._Problem(prog, scorer, lo, hi, "trunc")
    assert ref.values(np.array([31.7, -3.2, 60.9])).tolist() == [31, 8, 56]
    assert ref.values(np.array([8.99, 55.5, 40.2])).tolist() == [8, 55, 40]  # radius 40 allowed inside
    lo, hi = refinement._box(prog, "improved", None)
    imp = refinement._Problem(prog, scorer, lo, hi, "round")
    assert imp.values(np.array([31.7, 8.4, 40.2])).tolist() == [32, 8, 32]  # radius kept in 8..32
    assert imp.values(np.array([30.5, 31.5, 7.6])).tolist() == [30, 32, 8]  # halves to even


def test_reference_output_rules_and_returned_objective(monkeypatch):
    """The reference's output: truncate, radii to [8, 32], everything to [8, 56]; score = Powell's fun."""
    import scipy.optimize

    def fake_minimize(fun, x0, method, tol, options):
        assert method == "Powell" and tol == 1e-4
        fun(x0)
        return OptimizeResult(x=np.array([20.9, 60.3, 45.7, 7.2, 33.9, 5.5]), fun=1.25, nit=1)

    monkeypatch.setattr(scipy.optimize, "minimize", fake_minimize)
    target = rendered(parse("c(20,40,12)s(30,30,16)+"))
    res = refinement.refine("c(22,38,12)s(30,30,16)+", target, mode="reference", maxiter=1)
    assert res.text == "c(20,56,32)s(8,33,8)+"
    assert res.score == 1.25 and res.iterations == 1


def test_reference_score_can_differ_from_the_program_improved_cannot():
    # A disk of radius 40 (clipped by the canvas): the reference objective reaches it with r = 40
    # inside [8, 56], then clips the radius to 32 on output and still reports the r = 40 score.
    target = rendered(parse("c(32,32,40)"))
    ref = csgnet.refine("c(32,32,30)", target, mode="reference")
    assert ref.score == 0.0
    assert ref.program.draws[0].params[2] == 32
    assert metrics.chamfer(rendered(ref.program), target) > 1.0
    imp = csgnet.refine("c(32,32,30)", target)
    assert imp.program.draws[0].params[2] <= 32
    assert imp.score == metrics.chamfer(rendered(imp.program), target)


def test_improved_box_contains_the_input():
    # A radius above 32 in the input stays reachable (the box widens to contain it), and the start
    # point scores the input itself.
    target = rendered(parse("c(32,32,40)"))
    res = csgnet.refine("c(32,32,40)", target, maxiter=2)
    assert res.initial_score == 0.0 and res.text == "c(32,32,40)" and not res.improved
    lo, hi = refinement._box(parse("c(-4,70,3)"), "improved", None)
    assert lo.tolist() == [-4, 8, 3] and hi.tolist() == [56, 70, 32]


def test_maxiter_zero_returns_the_input():
    start, target = cases(1, seed=4)[0]
    for mode in refinement.MODES:
        res = csgnet.refine(start, target, maxiter=0, mode=mode)
        assert res.program is start and res.score == res.initial_score == metrics.chamfer(rendered(start), target)
        assert res.iterations == 0 and res.evaluations == 0


def test_more_iterations_are_counted():
    start, target = cases(1, seed=5)[0]
    one = csgnet.refine(start, target, maxiter=1)
    full = csgnet.refine(start, target, maxiter=None)
    assert one.iterations == 1 and full.iterations > one.iterations and full.evaluations > one.evaluations


@pytest.mark.parametrize("mode", ["improved", "reference"])
def test_invalid_program_is_returned_unchanged(mode):
    target = rendered(parse("c(32,32,16)"))
    bad = Program((Draw("c", (32, 32, 16)), Draw("s", (30, 30, 12))), 2)  # two shapes left
    res = csgnet.refine(bad, target, mode=mode)
    assert res.program is bad and res.score == res.initial_score == 16.0 and res.evaluations == 0
    assert csgnet.refine("c(32,32,16)+", target, metric="iou", mode=mode).score == 0.0
    assert csgnet.refine("c(32,32,16)+", target, mode=mode).text == "c(32,32,16)+"


def test_bad_input_errors():
    target = rendered(parse("c(32,32,16)"))
    with pytest.raises(ValueError, match=r"shape \(64, 64\), got \(2, 64, 64\)"):
        csgnet.refine("c(32,32,16)", np.stack([target, target]))
    with pytest.raises(ValueError, match="target image is empty"):
        csgnet.refine("c(32,32,16)", np.zeros((64, 64), bool))
    with pytest.raises(ValueError, match="2D programs, got a 3D program"):
        csgnet.refine(parse("sp(32,32,32,8)", dim=3), target)
    with pytest.raises(ValueError, match="metric must be one of"):
        csgnet.refine("c(32,32,16)", target, metric="l2")
    with pytest.raises(ValueError, match="mode must be one of"):
        csgnet.refine("c(32,32,16)", target, mode="fast")
    with pytest.raises(ValueError, match="maxiter must be a non-negative integer"):
        csgnet.refine("c(32,32,16)", target, maxiter=-1)
    with pytest.raises(csgnet.ParseError, match="unknown 2D primitive"):
        csgnet.refine("q(32,32,16)", target)
    with pytest.raises(ValueError, match="bounds must be integers"):
        csgnet.refine("c(32,32,16)", target, bounds=((8, 56), (32, 8)))
    with pytest.raises(TypeError, match="Program or program text"):
        csgnet.refine(42, target)


def test_torch_and_uint8_targets():
    start, target = cases(1, seed=6)[0]
    a = csgnet.refine(start, target, maxiter=1)
    b = csgnet.refine(start, torch.from_numpy(target), maxiter=1)
    c = csgnet.refine(start, target.astype(np.uint8) * 255, maxiter=1)
    assert a.program == b.program == c.program and a.score == b.score == c.score


def test_refine_beams_keeps_the_best():
    rng = random.Random(7)
    truth = grid_program(rng, 3)
    while not rendered(truth).any():
        truth = grid_program(rng, 3)
    target = rendered(truth)
    beams = [perturbed(truth, rng, 4) for _ in range(3)] + [Program((Op("+"),), 2)]
    best = csgnet.refine_beams(beams, target, maxiter=2)
    singles = [csgnet.refine(b, target, maxiter=2) for b in beams]
    assert best.score == min(r.score for r in singles)
    assert best.program == min(singles, key=lambda r: r.score).program
    assert best.score == metrics.chamfer(rendered(best.program), target)
    iou_best = csgnet.refine_beams(beams, target, metric="iou", maxiter=1)
    assert iou_best.score == max(csgnet.refine(b, target, metric="iou", maxiter=1).score for b in beams)
    with pytest.raises(ValueError, match="at least one program"):
        csgnet.refine_beams([], target)


def test_composition_equals_the_renderer():
    """The cached composition of a fixed structure renders exactly as render_programs."""
    rng = random.Random(8)
    scorer = refinement._Scorer(rendered(parse("c(32,32,16)")), "chamfer")
    for _ in range(40):
        p = random_program(rng, 2, rng.randint(1, 7))
        lo, hi = refinement._box(p, "improved", None)
        prob = refinement._Problem(p, scorer, lo, hi, "round")
        v = np.array([x for d in p.draws for x in d.params], np.int64)
        assert np.array_equal(prob.compose(v), pack(torch.from_numpy(rendered(p))).numpy()), p.text()


def test_scorer_equals_metrics_bit_for_bit():
    rng = random.Random(9)
    images = [rendered(random_program(rng, 2, rng.randint(1, 5))) for _ in range(30)]
    images += [np.zeros((64, 64), bool), np.ones((64, 64), bool)]
    full_row = np.zeros((64, 64), bool)
    full_row[:, :40] = True  # touches three borders
    images.append(full_row)
    targets = [im for im in images[:10] if im.any()] + [np.ones((64, 64), bool), full_row]
    for t in targets:
        cd = refinement._Scorer(t, "chamfer")
        io = refinement._Scorer(t, "iou")
        for im in images:
            w = pack(torch.from_numpy(im)).numpy()
            assert cd.score(w) == metrics.chamfer(im, t)
            assert io.score(w) == metrics.iou(im, t)


def test_defect6_guarded_rule_keeps_the_program_when_chamfer_costs_iou():
    from csgnet.refinement import MAX_IOU_DROP, refine_guarded
    from csgnet.score import program_scores

    target = csgnet.render("c(17,29,15)s(21,42,13)-")[0]
    start = "c(25,43,26)"
    paper = refine_guarded(start, [start], target, rule="chamfer")
    assert paper.after[1] < paper.before[1]  # chamfer improves ...
    assert paper.after[0] < paper.before[0] - MAX_IOU_DROP  # ... while IoU drops a lot
    assert paper.program == paper.result.program and not paper.kept_start
    guarded = refine_guarded(start, [start], target, rule="guarded")
    assert guarded.kept_start and guarded.program == csgnet.parse(start)
    assert program_scores([guarded.program], target)[0] == guarded.before


# ---------------------------------------------------------------------------------------------
# 3D: IoU |A∧B| / (|A∨B| + 1) over (x, y, z, r[, h]) per primitive


def volume(program) -> np.ndarray:
    return render_programs([program], 3)[0].numpy()


def in_box(start: Program, result: Program) -> bool:
    """Every returned parameter lies in its grammar range (positions 8..56, sizes 8..32), widened to
    contain the start's value."""
    for a, b in zip(start.draws, result.draws):
        for name, grammar, v0, v in zip(primitive(a.kind).params, primitive(a.kind).ranges, a.params, b.params):
            lo, hi = min(min(grammar), v0), max(max(grammar), v0)
            if not lo <= v <= hi:
                return False
    return True


def test_3d_iou_scorer_equals_iou_3d_bit_for_bit():
    rng = random.Random(20)
    vols = [volume(random_program(rng, 3, rng.randint(1, 4))) for _ in range(12)]
    vols += [np.zeros((64,) * 3, bool), np.ones((64,) * 3, bool)]
    for t in [v for v in vols if v.any()][:6]:
        scorer = refinement._Scorer(t, "iou")
        for v in vols:
            assert scorer.score(pack(torch.from_numpy(v)).numpy()) == metrics.iou_3d(v, t)


def test_3d_composition_equals_the_renderer():
    rng = random.Random(21)
    scorer = refinement._Scorer(volume(parse("sp(32,32,32,16)", 3)), "iou")
    for _ in range(15):
        p = random_program(rng, 3, rng.randint(1, 5))
        lo, hi = refinement._box(p, "improved", None)
        v = np.array([x for d in p.draws for x in d.params], np.int64)
        composed = refinement._Problem(p, scorer, lo, hi, "round").compose(v)
        assert np.array_equal(composed, pack(torch.from_numpy(volume(p))).numpy()), p.text()


@pytest.mark.parametrize("seed, near", [(22, True), (23, False)])
def test_3d_never_worsens_iou_and_keeps_parameters_in_range(seed, near):
    """Starts near their target (a perturbed copy) or anywhere (another random program, parameters
    also outside the grammar's ranges): the returned score is the returned program's IoU, never below
    the start's, and every parameter stays inside the search box."""
    rng = random.Random(seed)
    for _ in range(5):
        truth = random_program(rng, 3, rng.randint(1, 3), lo=14, hi=50, sizes=(10, 26))
        target = volume(truth)
        if not target.any():
            continue
        start = perturbed(truth, rng) if near else random_program(rng, 3, rng.randint(1, 3))
        res = csgnet.refine(start, target, maxiter=2)
        assert res.metric == "iou" and res.mode == "improved"
        assert res.initial_score == metrics.iou_3d(volume(start), target)
        assert res.score == metrics.iou_3d(volume(res.program), target) >= res.initial_score
        assert in_box(start, res.program), (start.text(), res.text)
        if not res.improved:
            assert res.program is start


@pytest.mark.parametrize("target_text, start_text, exact", [
    ("sp(32,32,32,16)", "sp(30,34,31,13)", True),
    ("sp(32,32,32,24)cu(32,32,32,20)-", "sp(33,30,32,22)cu(31,33,30,22)-", True),
    ("cy(32,32,32,16,24)sp(32,32,44,12)+", "cy(30,33,34,14,20)sp(33,31,41,13)+", False),
])
def test_3d_perturbed_program_is_pulled_back_to_its_target(target_text, start_text, exact):
    target = volume(parse(target_text, 3))
    res = csgnet.refine(start_text, target)
    assert res.initial_score < 0.7 and res.score > 0.9
    if exact:  # the same volume (cube sizes 19 and 20 draw alike), so IoU = |A| / (|A| + 1)
        assert np.array_equal(volume(res.program), target)


def test_3d_search_box_sizes_include_the_cylinder_height():
    prog = parse("cy(70,32,-3,40,4)sp(32,32,32,16)+", 3)
    lo, hi = refinement._box(prog, "improved", None)
    assert lo.tolist() == [8, 8, -3, 8, 4, 8, 8, 8, 8] and hi.tolist() == [70, 56, 56, 40, 32, 56, 56, 56, 32]
    lo, hi = refinement._box(prog, "improved", ((10, 50), (12, 20)))
    assert lo.tolist() == [10, 10, -3, 12, 4, 10, 10, 10, 12] and hi.tolist() == [70, 50, 50, 40, 20, 50, 50, 50, 20]
    assert primitive("y").sizes == ("r", "h") and primitive("y").ranges[4] == SIZES


def test_3d_refine_beams_and_guarded_rule_never_lower_iou():
    rng = random.Random(24)
    truth = parse("sp(28,32,30,16)cu(40,32,32,12)+", 3)
    target = volume(truth)
    beams = [perturbed(truth, rng, 4) for _ in range(3)] + [Program((Op("+"),), 3)]
    best = csgnet.refine_beams(beams, torch.from_numpy(target), maxiter=1)
    assert best.score == max(csgnet.refine(b, target, maxiter=1).score for b in beams)
    ref = refinement.refine_guarded(beams[1], beams, target, maxiter=1, rule="guarded")
    assert not ref.kept_start and ref.program == best.program
    assert ref.after[0] == best.score >= ref.before[0] == metrics.iou_3d(volume(beams[1]), target)
    assert np.isnan(ref.before[1]) and np.isnan(ref.after[1])  # no 3D chamfer


def test_3d_bad_input_errors():
    target = volume(parse("sp(32,32,32,16)", 3))
    with pytest.raises(ValueError, match="'chamfer' is defined for 2D images only"):
        csgnet.refine("sp(30,32,32,16)", target, metric="chamfer")
    with pytest.raises(ValueError, match="'reference' is the published 2D procedure"):
        csgnet.refine("sp(30,32,32,16)", target, mode="reference")
    with pytest.raises(ValueError, match="3D target needs 3D programs, got a 2D program"):
        csgnet.refine(parse("c(32,32,16)"), target)
    with pytest.raises(csgnet.ParseError):
        csgnet.refine("c(32,32,16)", target)  # text is read as 3D
    with pytest.raises(ValueError, match="target volume is empty"):
        csgnet.refine("sp(30,32,32,16)", np.zeros((64,) * 3, bool))
    with pytest.raises(ValueError, match=r"\(64, 64, 64\) volume or one image of shape \(64, 64\), got \(64, 64, 2\)"):
        csgnet.refine("sp(30,32,32,16)", np.zeros((64, 64, 2), bool))
