"""The objective f, the fits and the best-program search, against hand-computed values."""
import math
import random

import pytest

from shapeprog.macros.grammar import BBOX, AttachLine, CuboidLine, ReflectLine, SqueezeLine, TranslateLine
from shapeprog.macros.library import Library
from shapeprog.macros.objective import (ABS_MAX_ERROR, beam_search, best_program, exact_search, fit, fit_options,
                                        score, template, templates, to_program)

BB = CuboidLine(1.0, 0.8, 1.2, True)
LEG = ("def leg(s: float, b: bool, t: float):\n    c = Cuboid(s, bb_y, s, b)\n"
       "    squeeze(bbox, bbox, bot, 0.6 * s, t)\n    reflect(X)\n")


def leg_lines(s=0.1, t=0.3):
    return (BB, CuboidLine(s, 0.8, s, False), SqueezeLine(BBOX, BBOX, "bot", 0.6 * s, t), ReflectLine("X"))


def test_base_program_costs():
    # Cuboid: 8 + 3 floats + 0.25 bool; attach: 8 + 8 (cube) + 6 floats
    lines = (BB, CuboidLine(0.5, 0.2, 0.5, True), AttachLine(BBOX, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5))
    assert best_program([lines], Library()).f == 11.25 + 22.0
    # squeeze: 8 + 2 cubes + 2 floats + 0.5 face; reflect: 8 + 0.5 axis
    r = best_program([leg_lines()], Library())
    assert r.f == 11.25 + 26.5 + 8.5
    assert score(r.calls, 0, bbox_params=True) == r.f + 3.25


def test_macro_exact_and_rounded_fit():
    lib = Library.from_text(LEG)
    r = best_program([leg_lines()], lib)
    assert [o.func for o in r.calls] == ["leg"]
    assert r.f == pytest.approx(1 + 8 + 2 + 0.25)  # one macro in L; s, t, b
    # s = 0.104 is tied (three slots): rounded to 0.10, residuals 0.004 + 0.004 + 0.0024
    r = best_program([leg_lines(s=0.104)], lib)
    assert [o.func for o in r.calls] == ["leg"]
    assert r.calls[0].args[0] == 0.1
    assert r.error == pytest.approx(0.0104)
    assert r.f == pytest.approx(11.25 + 10 * 0.0104)


def test_fit_tolerance_accept_reject():
    lib = Library.from_text("def post(b: bool):\n    c = Cuboid(0.1, bb_y, 0.1, b)\n")
    tpl = template(lib, "post")
    ok = (BB, CuboidLine(0.155, 0.8, 0.1, True))
    bad = (BB, CuboidLine(0.165, 0.8, 0.1, True))
    o = fit(tpl, ok, 1, 0)
    assert o is not None and o.error == pytest.approx(0.055) and o.args == (True,)
    assert fit(tpl, bad, 1, 0) is None
    assert fit(tpl, bad, 1, 0, max_error=0.07) is not None
    assert ABS_MAX_ERROR == 0.06


def test_discrete_slots_must_match():
    lib = Library.from_text(LEG)
    tpl = template(lib, "leg")
    wrong_face = (BB, CuboidLine(0.1, 0.8, 0.1, False), SqueezeLine(BBOX, BBOX, "top", 0.06, 0.3), ReflectLine("X"))
    wrong_axis = leg_lines()[:3] + (ReflectLine("Z"),)
    assert fit(tpl, leg_lines(), 1, 0) is not None
    assert fit(tpl, wrong_face, 1, 0) is None
    assert fit(tpl, wrong_axis, 1, 0) is None
    # a cube parameter may not name a cuboid the call itself creates
    lib2 = Library.from_text("def pair(t: cube):\n    c = Cuboid(0.1, 0.1, 0.1, True)\n"
                             "    attach(t, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\n")
    lines = (BB, CuboidLine(0.1, 0.1, 0.1, True), AttachLine(BBOX, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5),
             CuboidLine(0.1, 0.1, 0.1, True), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
    t2 = template(lib2, "pair")
    assert fit(t2, lines, 3, 1).args == (0,)
    bad = lines[:4] + (AttachLine(1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5),)
    assert fit(t2, bad, 3, 1) is None


def test_expression_and_translate_fit():
    lib = Library.from_text("def row(d: float):\n    c = Cuboid(0.2, 0.2, 0.2, True)\n"
                            "    attach(bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n    translate(X, 3, 1.0 - d)\n")
    lines = (BB, CuboidLine(0.2, 0.2, 0.2, True), AttachLine(BBOX, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5),
             TranslateLine("X", 3, 0.7))
    o = fit(template(lib, "row"), lines, 1, 0)
    assert o.args == (pytest.approx(0.3),) and o.error == pytest.approx(0.0, abs=1e-12)
    assert fit(template(lib, "row"), lines[:3] + (TranslateLine("X", 2, 0.7),), 1, 0) is None


def _random_lines(rng):
    lines = [CuboidLine(1.0, 1.0, 1.0, True)]
    for k in range(rng.randint(1, 4)):
        lines.append(CuboidLine(rng.choice([0.1, 0.2]), 1.0, 0.1, True))
        tgt = rng.choice([BBOX] + list(range(k)))
        lines.append(AttachLine(tgt, 0.5, 0.0, 0.5, rng.choice([0.5, 0.1]), 0.0, 0.5))
        if rng.random() < 0.5:
            lines.append(ReflectLine("X"))
    return tuple(lines)


def test_exact_never_worse_than_beam_and_both_cover():
    lib = Library.from_text("def a(s: float):\n    c = Cuboid(s, 1.0, 0.1, True)\n"
                            "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n\n"
                            "def r():\n    reflect(X)\n\n"
                            "def b(t: cube):\n    c = Cuboid(0.2, bb_y, 0.1, True)\n"
                            "    attach(t, 0.5, 0.0, 0.5, 0.1, 0.0, 0.5)\n    reflect(X)\n")
    rng = random.Random(0)
    tpls = templates(lib)
    for _ in range(200):
        lines = _random_lines(rng)
        opts = fit_options(lines, tpls)
        cb, fb = beam_search(opts, 3)
        ce, fe = exact_search(opts, 3)
        assert fe <= fb + 1e-9
        assert math.isfinite(fb)
        for calls in (cb, ce):
            pos = 1
            for o in calls:
                assert o.pos == pos
                pos += o.k
            assert pos == len(lines)
        assert score(ce, 3) == pytest.approx(fe)


def test_to_program_expands_to_the_lines():
    lib = Library.from_text(LEG)
    lines = leg_lines() + (CuboidLine(0.5, 0.1, 0.5, True), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
    r = best_program([lines], lib)
    prog = to_program(lines, r.calls, lib)
    assert [c.func for c in prog.lines] == ["Cuboid", "leg", "Cuboid", "attach"]
    assert lib.expand(prog).lines == lines
