"""csgnet.editor: controls of CSG programs, edits equal to text edits, fuzzed values, the session (undo /
redo, exports) and the page (viser; skipped without it)."""
import random
import urllib.request

import numpy as np
import pytest

import csgnet
from csgnet.editor import CHOICE, INT, CSGEditError, CSGEditSession, apply, controls
from csgnet.lang import ParseError, parse
from csgnet.primitives import primitives
from editor_testutil import assert_port_argument_error, free_port

PROGRAMS = ["c(32,32,28)s(32,32,20)-", "c(16,24,8)t(40,40,12)+s(32,32,16)*",
            "sp(32,32,32,20)cu(32,32,32,28)*", "cy(32,32,32,12,24)sp(40,32,32,8)-"]


def _dim(text):
    return 3 if "sp(" in text or "cu(" in text or "cy(" in text else 2


def _token(value, dim):
    """How a control's value is written in a program text (a primitive by its name, in 3D its long name)."""
    row = next((r for r in primitives(dim) if r.name == value), None)
    return str(value) if row is None else row.head(long=dim == 3)


def test_control_list():
    p = parse("c(32,32,28)s(32,32,20)-")
    cs = controls(p)
    assert [c.kind for c in cs] == [CHOICE, INT, INT, INT, CHOICE, INT, INT, INT, CHOICE]
    by = {c.name: c for c in cs}
    assert (by["0:circle.x"].low, by["0:circle.x"].high, by["0:circle.r"].high) == (0, 63, 64)
    assert by["0:circle.kind"].choices == ("circle", "square", "triangle") and by["0:circle.kind"].value == "circle"
    assert by["0:op"].choices == ("+", "*", "-")
    text = p.text()
    for c in cs:  # the value's token starts at the control's position
        assert text[c.position:].startswith(_token(c.value, 2)), c.name
    q = parse("cy(32,32,32,12,24)sp(40,32,32,8)-", 3)
    by = {c.name: c for c in controls(q)}
    assert by["0:cylinder.kind"].choices == ("cylinder",) and by["1:sphere.kind"].choices == ("sphere", "cube")
    assert apply(q, {"1:sphere.kind": "cube"}).text() == "cy(32,32,32,12,24)cu(40,32,32,8)-"
    with pytest.raises(CSGEditError, match="control '1:sphere.kind': 'u' is not one of sphere, cube"):
        apply(q, {"1:sphere.kind": "u"})  # the vocabulary letters stay inside the language
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
            old, new = _token(c.value, p.dim), _token(v, p.dim)
            edited = text[:c.position] + new + text[c.position + len(old):]
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
            vals[c.name] = rng.choice([rng.randint(-5, 70), 2.5, float("nan"), True, None, "c", "+", "u", "cube",
                                       "circle", c.value, c.low if c.low is not None else 0,
                                       rng.choice(c.choices) if c.kind == CHOICE else rng.randint(c.low, c.high)])
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


def test_page(tmp_path):
    from csgnet.editor.server import CSGEditorApp

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=free_port(), export_dir=tmp_path)
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


def test_the_2d_page_shows_the_render_in_the_main_view_framed(tmp_path):
    """The render is an image plane in the 3D view (not a picture in the side panel), seen straight on with its
    top row up, and filling the view up to the frame margin."""
    from csgnet.editor.server import IMAGE_SCALE, PLANE_SIZE, CSGEditorApp
    from editor_testutil import view_fill
    from shapeedit.camera import FRAME_MARGIN

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=free_port(), export_dir=tmp_path)
    try:
        import viser

        assert isinstance(app.image, viser.ImageHandle) and app.image.name == "/render"  # a scene node
        assert (app.image.render_width, app.image.render_height) == (PLANE_SIZE, PLANE_SIZE)
        shown = app.image.image[::IMAGE_SCALE, ::IMAGE_SCALE, 0] == 0  # black on white
        assert np.array_equal(shown, csgnet.render("c(32,32,28)s(32,32,20)-")[0])
        pose = app.state["camera"]
        assert np.allclose(pose.look_at, 0) and pose.position[2] < 0 and np.allclose(pose.position[:2], 0)
        assert np.allclose(pose.up, [0, -1, 0])  # the image's first row is at -y
        plane = [(x, y, 0) for x in (-PLANE_SIZE / 2, PLANE_SIZE / 2) for y in (-PLANE_SIZE / 2, PLANE_SIZE / 2)]
        assert abs(view_fill(pose, plane) - 1 / FRAME_MARGIN) < 1e-3
        assert np.allclose(app.server.initial_camera.position, pose.position)
        assert np.allclose(app.server.initial_camera.look_at, pose.look_at)
        app.handle("1:square.r").value = 8
        shown = app.image.image[::IMAGE_SCALE, ::IMAGE_SCALE, 0] == 0
        assert np.array_equal(shown, csgnet.render("c(32,32,28)s(32,32,8)-")[0])
    finally:
        app.stop()


def test_the_3d_page_names_its_primitives_and_frames_the_shape(tmp_path):
    from csgnet.editor.server import VOXEL_CENTRE, VOXEL_HALF, CSGEditorApp
    from editor_testutil import view_fill
    from shapeedit.camera import FRAME_MARGIN

    def box(canvas):  # the mesh's bounding box corners in scene units
        filled = np.argwhere(canvas)
        lo, hi = (filled.min(0) - 0.5 - VOXEL_CENTRE) / VOXEL_HALF, (filled.max(0) + 0.5 - VOXEL_CENTRE) / VOXEL_HALF
        return [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], (lo + hi) / 2

    app = CSGEditorApp(CSGEditSession("cy(32,32,32,12,24)sp(40,32,32,8)-"), port=free_port(), export_dir=tmp_path)
    try:
        assert app.handle("0:cylinder.kind").options == ("cylinder",)
        kind = app.handle("1:sphere.kind")
        assert kind.options == ("sphere", "cube") and kind.value == "sphere"
        app.handle("1:sphere.kind").value = "cube"
        assert app.state["text"] == "cy(32,32,32,12,24)cu(40,32,32,8)-" and app.state["error"] is None
        assert app.handle("1:cube.kind").options == ("sphere", "cube")
        corners, centre = box(app.state["canvas"])
        pose = app.state["camera"]  # framed when the page opened; an edit leaves the view alone
        assert np.allclose(pose.look_at, centre) and abs(view_fill(pose, corners) - 1 / FRAME_MARGIN) < 1e-3
        assert app.run_text("sp(16,16,16,6)")  # a new program: framed again
        corners, centre = box(app.state["canvas"])
        moved = app.state["camera"]
        assert np.allclose(moved.look_at, centre) and abs(view_fill(moved, corners) - 1 / FRAME_MARGIN) < 1e-3
        assert np.linalg.norm(moved.position - moved.look_at) < np.linalg.norm(pose.position - pose.look_at) / 2
        assert np.allclose(app.server.initial_camera.look_at, centre)
    finally:
        app.stop()


def test_defect_a_non_finite_slider_value_is_shown_not_raised(tmp_path):
    """A slider message of NaN or infinity (the page's websocket carries msgpack floats) is refused by the
    control's check and shown; it used to raise in the server's handler thread."""
    from csgnet.editor.server import CSGEditorApp

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=free_port(), export_dir=tmp_path)
    try:
        for bad in (float("nan"), float("inf"), "12"):
            app._changed("1:square.r", bad)
            assert app.state["error"].startswith(f"at character 19: control '1:square.r': expected an integer, got "
                                                 f"{type(bad).__name__} {bad!r} (token '20')")
            assert app.state["text"] == "c(32,32,28)s(32,32,20)-" and app.handle("1:square.r").value == 20
        app._changed("1:square.r", 12.4)  # a slider's float, rounded as before
        assert app.state["error"] is None and app.state["text"] == "c(32,32,28)s(32,32,12)-"
    finally:
        app.stop()


def test_defect_editor_accepts_any_web_origin_is_refused(tmp_path):
    from csgnet.editor.server import CSGEditorApp
    from editor_testutil import assert_only_this_machines_pages_reach

    app = CSGEditorApp(CSGEditSession("c(32,32,28)s(32,32,20)-"), port=free_port(), export_dir=tmp_path)
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

    assert_port_argument_error(main, ["edit", "c(32,32,28)"], capsys)
