"""csgnet.editor: controls of CSG programs, edits equal to text edits, fuzzed values, the session (undo /
redo, exports) and the page (viser; skipped without it)."""
import random
import socket
import urllib.request

import numpy as np
import pytest

import csgnet
from csgnet.editor import CHOICE, INT, CSGEditError, CSGEditSession, apply, controls
from csgnet.lang import ParseError, parse

PROGRAMS = ["c(32,32,28)s(32,32,20)-", "c(16,24,8)t(40,40,12)+s(32,32,16)*",
            "sp(32,32,32,20)cu(32,32,32,28)*", "cy(32,32,32,12,24)sp(40,32,32,8)-"]


def _dim(text):
    return 3 if "sp(" in text or "cu(" in text or "cy(" in text else 2


def test_control_list():
    p = parse("c(32,32,28)s(32,32,20)-")
    cs = controls(p)
    assert [c.kind for c in cs] == [CHOICE, INT, INT, INT, CHOICE, INT, INT, INT, CHOICE]
    by = {c.name: c for c in cs}
    assert (by["0:circle.x"].low, by["0:circle.x"].high, by["0:circle.r"].high) == (0, 63, 64)
    assert by["0:circle.kind"].choices == ("c", "s", "t") and by["0:op"].choices == ("+", "*", "-")
    text = p.text()
    for c in cs:  # the value's token starts at the control's position
        assert text[c.position:].startswith(str(c.value)), c.name
    q = parse("cy(32,32,32,12,24)sp(40,32,32,8)-", 3)
    by = {c.name: c for c in controls(q)}
    assert by["0:cylinder.kind"].choices == ("y",) and by["1:sphere.kind"].choices == ("p", "u")
    assert by["0:cylinder.h"].high == 64
    assert controls(parse("c(-4,70,12)", 2))[1].low == -4 and controls(parse("c(-4,70,12)", 2))[2].high == 70


def test_round_trip_and_edits_equal_text_edits():
    rng = random.Random(0)
    for text in PROGRAMS:
        p = parse(text, _dim(text))
        cs = controls(p)
        assert apply(p, {c.name: c.value for c in cs}) == p
        for c in cs:
            v = rng.randint(c.low, c.high) if c.kind == INT else rng.choice(c.choices)
            q = apply(p, {c.name: v})
            edited = text[:c.position] + str(v) + text[c.position + len(str(c.value)):]
            if c.name.endswith(".kind") and _dim(text) == 3:
                continue  # 3D prints the long names: 'sp' vs 'p'
            assert q == parse(edited, p.dim), (text, c.name, v)
            assert np.array_equal(csgnet.render(q, p.dim), csgnet.render(edited, p.dim))


def test_bad_values_and_fuzz():
    p = parse("c(32,32,28)s(32,32,20)-")
    with pytest.raises(CSGEditError, match=r"at character 13: control '1:square.x': value 99 is outside \[0, 63\]"):
        apply(p, {"1:square.x": 99})
    with pytest.raises(CSGEditError, match="no such control"):
        apply(p, {"7:square.x": 3})
    with pytest.raises(CSGEditError, match="is not one of"):
        apply(p, {"0:op": "/"})
    assert isinstance(CSGEditError("x"), ParseError)
    rng = random.Random(1)
    ok = bad = 0
    for _ in range(500):
        text = rng.choice(PROGRAMS)
        p = parse(text, _dim(text))
        cs = controls(p)
        vals = {}
        for c in rng.sample(cs, rng.randint(1, 3)):
            vals[c.name] = rng.choice([rng.randint(-5, 70), 2.5, float("nan"), True, None, "c", "+", "u", "y",
                                       c.value, c.low if c.low is not None else 0])
        try:
            q = apply(p, vals)
        except CSGEditError:
            bad += 1
            continue
        ok += 1
        assert csgnet.render(q, p.dim).shape[0] == 1
    assert ok > 50 and bad > 50


def test_session(tmp_path):
    s = CSGEditSession("c(32,32,28)s(32,32,20)-", name="ring")
    assert s.dim == 2 and s.canvas.shape == (64, 64)
    before = s.canvas.copy()
    assert s.set({"1:square.r": 8}) and s.canvas.sum() > before.sum()
    assert not s.set({"1:square.r": 100}) and isinstance(s.error, CSGEditError)
    assert s.text == "c(32,32,28)s(32,32,8)-"
    assert s.undo() and np.array_equal(s.canvas, before) and not s.undo()
    assert s.redo() and s.reset() and s.text == "c(32,32,28)s(32,32,20)-"
    paths = s.export(tmp_path)
    assert [p.name for p in paths] == ["ring_edit001.txt", "ring_edit001.png"]
    assert paths[0].read_text() == "c(32,32,28)s(32,32,20)-\n"
    from PIL import Image

    img = np.asarray(Image.open(paths[1]))
    assert img.shape == (256, 256) and np.array_equal(img[::4, ::4] == 0, s.canvas)
    assert [p.name for p in s.export(tmp_path)][0] == "ring_edit002.txt"
    s3 = CSGEditSession("sp(32,32,32,20)cu(32,32,32,28)*")
    assert s3.dim == 3 and s3.canvas.shape == (64, 64, 64)
    assert [p.suffix for p in s3.export(tmp_path)] == [".txt", ".obj"]
    bad = CSGEditSession("c(32,32,28)q(1,2,3)-")
    assert bad.program is None and isinstance(bad.error, ParseError) and bad.error.position == 11
    assert bad.set_text("c(32,32,28)") and bad.canvas.any()


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_page(tmp_path):
    from csgnet.editor.server import CSGEditorApp

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=_free_port(), export_dir=tmp_path)
    try:
        with urllib.request.urlopen(app.url, timeout=10) as r:
            assert r.status == 200
        v = app.state["version"]
        app.handle("1:square.r").value = 8
        assert app.state["version"] == v + 1 and app.state["text"] == "c(32,32,28)s(32,32,8)-"
        assert np.array_equal(app.state["canvas"], csgnet.render("c(32,32,28)s(32,32,8)-")[0])
        app.handle("0:op").value = "+"
        assert app.state["text"] == "c(32,32,28)s(32,32,8)+"
        assert app.undo() and app.handle("0:op").value == "-"
        assert not app.run_text("c(32,32,28)s(")
        assert app.state["error"] is not None and app.state["text"] == "c(32,32,28)s(32,32,8)-"
        assert len(app.export()) == 2
    finally:
        app.stop()


def test_defect_editor_accepts_any_web_origin_is_refused(tmp_path):
    from csgnet.editor.server import CSGEditorApp
    from editor_testutil import assert_only_this_machines_pages_reach

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=_free_port(), export_dir=tmp_path)
    try:
        assert_only_this_machines_pages_reach(app.url)
    finally:
        app.stop()


def test_defect_edit_port_out_of_range_is_refused(tmp_path):
    from csgnet.editor.server import CSGEditorApp

    with pytest.raises(ValueError, match=r"port 70000 is not a TCP port \(an integer from 0 to 65535\)"):
        CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=70000, export_dir=tmp_path)


def test_defect_edit_port_out_of_range_is_an_argument_error(capsys):
    from csgnet.__main__ import main

    with pytest.raises(SystemExit) as e:
        main(["edit", "c(32,32,28)", "--port", "70000", "--no-browser"])
    assert e.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        "error: argument --port: port '70000' is not a TCP port (an integer from 0 to 65535)")
