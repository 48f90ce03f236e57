"""The editor page (viser): it serves HTTP on 127.0.0.1, a control change replaces the geometry, refused
edits and parse errors show in the page, undo / redo / reset / export. Skipped without viser (the
``editor`` extra); the real-browser test (a slider dragged in headless Chromium, driven by Playwright) is skipped
without Chromium, except in CI."""
import shutil
import urllib.request

import numpy as np
import pytest

from editor_testutil import assert_port_argument_error, free_port
from shapeprog import corpus
from shapeprog.editor import EditSession, apply
from shapeprog.execute import execute
from shapeprog.lang import parse

import viser  # noqa: E402  (the dev extra)

from shapeprog.editor.server import EditorApp, cuboid_edges  # noqa: E402

CHAIR = corpus.read("chair", 173)


@pytest.fixture
def app(tmp_path):
    s = EditSession(CHAIR, "chair/173.txt")
    s.set_target(corpus.read("chair", 42220))
    a = EditorApp(s, port=free_port(), export_dir=tmp_path)
    yield a
    a.stop()


def test_serves_the_page_on_localhost(app):
    assert app.url.startswith("http://127.0.0.1:")
    with urllib.request.urlopen(app.url, timeout=10) as r:
        assert r.status == 200 and b"<html" in r.read().lower()


def test_a_control_change_replaces_the_geometry(app):
    s = app.session
    c = next(c for c in s.controls() if c.name == "Program_0:1:cuboid.h")
    v0, d0 = app.state["version"], app.state["distance"]
    app.handle(c.name).value = 0.5
    assert app.state["version"] == v0 + 1
    want = execute(apply(parse(CHAIR), {c.name: 0.5})).corners.numpy()
    assert np.array_equal(app.state["corners"], want)
    assert app.state["highlight"] == c.cuboids and len(c.cuboids) > 0
    assert app.state["distance"] != d0 and app.state["error"] is None
    assert "0.5" in app.state["text"].split("\n")[2] and app.text_box.value == app.state["text"]
    # undo, redo, reset move the controls too
    assert app.undo() and app.handle(c.name).value == pytest.approx(c.value)
    assert np.array_equal(app.state["corners"], execute(parse(CHAIR)).corners.numpy())
    assert app.redo() and app.handle(c.name).value == pytest.approx(0.5)
    assert app.reset() and app.state["text"] == CHAIR
    # a structural change (a drop-down) keeps the controls, with their new values
    face = next(c for c in s.controls() if c.name.endswith("squeeze.face"))
    other = next(f for f in face.choices if f != face.value)
    app.handle(face.name).value = other
    assert app.state["error"] is None and f", {other}, " in app.state["text"]
    assert app.handle(face.name).value == other
    # a new attach target: the same widgets, the line's folder retitled
    att = next(c for c in app.session.controls() if c.name.endswith("attach.b") and len(c.choices) > 1)
    h = app.handle(att.name)
    h.value = next(x for x in att.choices if x != att.value)
    assert app.state["error"] is None and app.handle(att.name) is h
    assert f", {h.value})" in app._folders[att.line].label


def test_a_refused_edit_shows_the_error_and_keeps_the_geometry(app):
    before, version = app.state["corners"].copy(), app.state["version"]
    assert not app.run_text(CHAIR.replace("squeeze(", "squeez(", 1))
    assert "chair/173.txt:" in app.state["error"] and "unknown command 'squeez'" in app.state["error"]
    assert np.array_equal(app.state["corners"], before) and app.state["version"] == version
    assert app.run_text(CHAIR) is True and app.state["error"] is None  # a good text afterwards is taken
    assert np.allclose(app.state["corners"], before)


def test_a_refused_control_value_is_shown_and_the_control_put_back(app):
    before, text = app.state["corners"].copy(), app.state["text"]
    h = app.handle("Program_0:1:cuboid.h")
    old = h.value
    h.value = 9.0  # beyond the slider's range, as a stale or hand-made message could send
    assert "control 'Program_0:1:cuboid.h': value 9.0 is outside [0.01, 4.0]" in app.state["error"]
    assert h.value == old and app.state["text"] == text and np.array_equal(app.state["corners"], before)
    assert "Error" in app.error_md.content


def test_exports_go_to_the_export_folder(app, tmp_path):
    paths = app.export()
    assert [p.parent for p in paths] == [tmp_path] * 3 and all(p.is_file() for p in paths)
    assert parse(paths[0].read_text()) == app.session.program


def test_a_program_that_does_not_parse_opens_with_its_error(tmp_path):
    bad = CHAIR.replace("attach(", "attach(nothing, ", 1)
    a = EditorApp(EditSession(bad, "bad.txt"), port=free_port(), export_dir=tmp_path, source_text=bad)
    try:
        assert a.state["error"].startswith("bad.txt:") and a.text_box.value == bad
        with urllib.request.urlopen(a.url, timeout=10) as r:
            assert r.status == 200
        assert a.run_text(CHAIR) and a.state["error"] is None and len(a.state["corners"]) == 6
    finally:
        a.stop()


def test_the_view_frames_the_shape_on_open_after_run_text_and_on_reset(app):
    """The camera looks at the shape and the target from the PNG pictures' direction, close enough that their
    bounding box reaches the frame margin (the shape no longer fills a tenth of the view); an edit leaves the
    view alone, a new program and Reset frame it again."""
    from editor_testutil import view_fill
    from shapeprog.picture import VIEW_DIRECTION
    from shapeedit.camera import FRAME_MARGIN

    def framed(pose, *shapes):
        points = np.concatenate([x.corners.detach().reshape(-1, 3).numpy() for x in shapes])
        lo, hi = points.min(0), points.max(0)
        box = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        back = (pose.position - pose.look_at) / np.linalg.norm(pose.position - pose.look_at)
        return (np.allclose(pose.look_at, (lo + hi) / 2) and np.allclose(back, VIEW_DIRECTION)
                and abs(view_fill(pose, box) - 1 / FRAME_MARGIN) < 1e-6 and view_fill(pose, points) > 0.5)

    s = app.session
    pose = app.state["camera"]
    assert framed(pose, s.shape, s.target) and np.array_equal(pose.up, [0, 1, 0])
    assert np.allclose(app.server.initial_camera.position, pose.position) and app.server.initial_camera.fov == pose.fov
    app.handle("Program_0:1:cuboid.h").value = 0.5
    assert app.state["camera"] is pose
    small = "bbox = Cuboid(0.1, 0.1, 0.1, True)\ncube0 = Cuboid(0.05, 0.02, 0.05, True)\n" \
            "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
    assert app.run_text(small)
    assert framed(app.state["camera"], s.shape, s.target)
    assert app.reset() and framed(app.state["camera"], s.shape, s.target)
    assert np.allclose(app.state["camera"].position, pose.position)


def test_cuboid_edges():
    corners = execute(parse(CHAIR)).corners
    e = cuboid_edges(corners)
    assert e.shape == (12 * len(corners), 2, 3)
    lengths = np.linalg.norm(e[:, 0] - e[:, 1], axis=-1).reshape(-1, 12)
    dims = execute(parse(CHAIR)).dims.numpy()
    for k in range(len(corners)):  # each extent appears on 4 edges
        assert np.allclose(np.sort(lengths[k]), np.sort(np.repeat(dims[k], 4)), atol=1e-6)


#: Chromium builds Playwright may drive when its own is not installed (``python -m playwright install chromium``).
SYSTEM_BROWSERS = ("chromium", "chromium-browser", "google-chrome")
#: Software WebGL for a machine without a GPU.
BROWSER_ARGS = ["--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader"]

# the visible slider thumbs: value, centre, and the text of their row (its label comes first)
_THUMBS = """JSON.stringify([...document.querySelectorAll('[role=slider]')].map(e => {
  const b = e.getBoundingClientRect(); let row = e;
  for (let k = 0; k < 10 && !/[a-z]/.test(row.innerText || ''); k++) row = row.parentElement;
  return {value: e.getAttribute('aria-valuenow'), x: b.x + b.width / 2, y: b.y + b.height / 2, w: b.width,
          label: (row.innerText || '').trim().split('\\n')[0]}; }).filter(t => t.w > 0)).replace(/^\\[\\]$/, '')"""


def _launch(playwright):
    """Headless Chromium: Playwright's own build when installed, else one on the PATH. Without either the test
    is skipped, except in CI (``CI`` set), where ``.ci/run`` installs one and a missing browser is a failure."""
    import os
    from pathlib import Path

    own = Path(playwright.chromium.executable_path)
    system = next((shutil.which(b) for b in SYSTEM_BROWSERS if shutil.which(b)), None)
    if not own.is_file() and system is None:
        reason = ("no headless Chromium: `python -m playwright install chromium`, or Debian's 'chromium' package, "
                  "installs one")
        if os.environ.get("CI"):
            pytest.fail(reason)
        pytest.skip(reason)
    return playwright.chromium.launch(executable_path=None if own.is_file() else system, args=BROWSER_ARGS)


def test_real_browser_slider_drag_changes_the_geometry(app):
    """Headless Chromium, driven by Playwright, opens the page and draws the chair in the 3D view, framed (taller
    than 40 % of the view); a mouse drag on the slider of the base's height (``Program_0:1:cuboid.h``:
    ``Program_1``, the legs' box, on line 3) reaches the server, which applies the value the page shows (the
    geometry equals the edited program's), and the 3D view draws the new chair."""
    import io
    import json
    import time

    from PIL import Image
    from playwright.sync_api import sync_playwright

    name = "Program_0:1:cuboid.h"
    control = next(c for c in app.session.controls() if c.name == name)
    head, label = control.label.rsplit(" ", 1)  # "line 3 Program_1 = Cuboid", "h"
    with sync_playwright() as playwright:
        browser = _launch(playwright)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 800})
            page.set_default_timeout(60_000)  # a loaded machine is slow, not failing
            page.goto(app.url)

            def thumbs(seconds: float = 60.0) -> list:
                return json.loads(page.wait_for_function(_THUMBS, timeout=seconds * 1000).json_value())

            def coloured():
                """The 3D view's saturated pixels (the coloured cuboids), left of the control panel."""
                rgb = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(int)
                view = rgb[:, : int(panel_x) - 10]
                return view, (view.max(-1) - view.min(-1)) > 60

            shown = []
            for _ in range(3):  # a click opens the line's folder (folders start closed: 54 controls); retried, as
                page.get_by_text(head, exact=True).last.click()  # the panel may still be moving on a slow machine
                try:
                    shown = thumbs(10)
                    break
                except Exception as e:  # Playwright's TimeoutError
                    if type(e).__name__ != "TimeoutError":
                        raise
            mine = [t for t in shown if t["label"] == label and float(t["value"]) == pytest.approx(control.value)]
            assert len(mine) == 1, shown
            thumb = mine[0]
            panel_x = min(t["x"] for t in shown) - 150
            deadline = time.time() + 60  # the scene arrives after the GUI; wait until the cuboids are drawn
            before, parts_before = coloured()
            while parts_before.sum() < 2000 and time.time() < deadline:
                time.sleep(0.5)
                before, parts_before = coloured()
            assert parts_before.sum() > 2000, "the 3D view is blank"
            rows, _ = np.nonzero(parts_before)  # framed: the chair is not a speck in the middle of the view
            assert rows.max() - rows.min() > 0.4 * parts_before.shape[0], (rows.min(), rows.max())
            corners, version = app.state["corners"].copy(), app.state["version"]

            # the drag: press on the thumb, move it 60 px to the right in steps, release
            page.mouse.move(thumb["x"], thumb["y"])
            page.mouse.down()
            page.mouse.move(thumb["x"] + 60, thumb["y"], steps=10)
            page.mouse.up()
            # the value the slider in the page shows once released: the last one the drag sent to the server
            new = float(next(t["value"] for t in thumbs() if abs(t["y"] - thumb["y"]) < 2))
            assert new > control.value

            def applied():
                """The geometry and error once the server has applied the page's last value (a drag sends
                several values, applied in turn), else None."""
                with app.lock:
                    if (round(app.handle(name).value, 9) == pytest.approx(new, abs=1e-9)
                            and f", {new:g}, " in app.state["text"].split("\n")[2]):
                        return app.state["corners"].copy(), app.state["error"]
                return None

            deadline = time.time() + 60
            while not applied() and time.time() < deadline:
                time.sleep(0.1)
            assert app.state["version"] > version, "the slider drag never reached the server"
            assert applied(), (new, app.handle(name).value, app.state["text"].split("\n")[2])
            moved, error = applied()
            assert error is None
            want = execute(apply(parse(CHAIR), {name: new})).corners.numpy()
            assert np.array_equal(moved, want) and not np.allclose(moved, corners)

            deadline = time.time() + 60  # and the page draws the taller base
            after, parts_after = coloured()
            while (np.abs(before - after).sum(-1) > 30).sum() <= 500 and time.time() < deadline:
                time.sleep(0.5)
                after, parts_after = coloured()
            assert parts_after.sum() > 2000
            assert (np.abs(before - after).sum(-1) > 30).sum() > 500, "the 3D view did not change"
        finally:
            browser.close()


@pytest.mark.parametrize("argv", [["shapeprog", "edit", "chair/173", "--target", "chair/42220"],
                                  ["csgnet", "edit", "c(32,32,28)s(32,32,20)-"]])
def test_the_edit_command_serves_until_interrupted(argv, tmp_path):
    """``python -m shapeprog edit ... --port N --no-browser`` prints its address and serves the page."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    port = free_port()
    root = Path(__file__).resolve().parents[3]
    proc = subprocess.Popen([sys.executable, "-m", *argv, "--port", str(port), "--no-browser", "--export-dir",
                             str(tmp_path)], cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = ""
        deadline = time.time() + 120
        while "editing" not in line and time.time() < deadline and proc.poll() is None:
            line = proc.stdout.readline()
        assert f"http://127.0.0.1:{port}" in line, proc.stderr.read() if proc.poll() is not None else line
        with urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=10) as r:
            assert r.status == 200
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            code = None
    err = proc.stderr.read()
    assert code == 0 and "Traceback" not in err, err  # an interrupt ends the server cleanly


def test_the_edit_command_refuses_bad_arguments(tmp_path, capsys):
    from shapeprog.__main__ import main

    with pytest.raises(SystemExit, match="neither a file nor a corpus id"):
        main(["assembly", "edit", "chair/x", "--no-browser", "--export-dir", str(tmp_path)])
    with pytest.raises(SystemExit, match="export folder does not exist"):
        main(["assembly", "edit", "chair/173", "--no-browser", "--export-dir", str(tmp_path / "missing")])
    with pytest.raises(SystemExit, match="no program chair/1 in the corpus"):
        main(["assembly", "edit", "chair/1", "--no-browser", "--export-dir", str(tmp_path)])


def test_macro_program_page_and_expanded_toggle(tmp_path):
    from editor_testutil import MACROS

    a = EditorApp(EditSession(MACROS, "m.txt"), port=free_port(), export_dir=tmp_path)
    try:
        n_macro = len(a._handles)
        a.handle("1:four_legs.s").value = 0.15
        assert a.state["error"] is None and "four_legs(0.15," in a.state["text"]
        corners = a.state["corners"].copy()
        a.expanded.value = True  # the base-language parameters of the expansion
        assert len(a._handles) > n_macro and "def " not in a.state["text"]
        assert np.array_equal(a.state["corners"], corners)
        a.expanded.value = False
        assert len(a._handles) == n_macro and "four_legs(0.15," in a.state["text"]
    finally:
        a.stop()


def test_a_websocket_client_receives_the_new_geometry(app):
    """What the browser receives: after a control change, vertex updates of the moved parts' meshes and the new
    program text arrive over the page's websocket (viser 1.1's wire format: zstd-compressed msgpack)."""
    import asyncio
    import time

    import msgspec  # viser's dependencies
    import websockets
    import zstandard

    if not viser.__version__.startswith("1.1."):
        pytest.skip(f"viser {viser.__version__}'s wire format may not be the one this test decodes (viser 1.1's)")

    def decode(m):
        n, c = int.from_bytes(m[:8], "little"), int.from_bytes(m[8:16], "little")
        data = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(m[16:16 + c], max_output_size=n))
        return [x for batch in (data if isinstance(data, list) else [data]) for x in batch["messages"]]

    async def drain(ws, done, seconds=20.0):
        """Messages until ``done(messages)`` holds and no message came for 0.5 s, or ``seconds`` pass (a loaded
        machine may pause between the server's messages: a quiet gap alone does not end the wait)."""
        out, t = [], time.time()
        while time.time() - t < seconds:
            try:
                out += decode(await asyncio.wait_for(ws.recv(), 0.5))
            except asyncio.TimeoutError:
                if done(out):
                    break
        return out

    def moved_parts(messages):
        return {m["name"] for m in messages if m["type"] == "SceneNodeUpdateMessage" and "vertices" in m["updates"]}

    def program_texts(messages):
        return [m["updates"]["value"] for m in messages if m["type"] == "GuiUpdateMessage"
                and isinstance(m["updates"].get("value"), str) and m["updates"]["value"].startswith("Assembly")]

    async def session():
        url = app.url.replace("http://", "ws://")
        async with websockets.connect(url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:
            first = await drain(ws, lambda ms: any(m.get("name", "").startswith("/shape/part") for m in ms))
            assert any(m.get("name", "").startswith("/shape/part") for m in first)
            app.handle("Program_0:1:cuboid.h").value = 0.5
            return await drain(ws, lambda ms: moved_parts(ms) and program_texts(ms))

    after = asyncio.run(session())
    moved = moved_parts(after)
    parts = {f"/shape/part{k}" for k in range(len(set(app.state["lines"].tolist())))}
    assert moved and moved <= parts
    texts = program_texts(after)
    assert texts and texts[-1] == app.state["text"]


def test_refactored_chair_page_moves_every_leg_and_expands(tmp_path):
    from shapeprog import corpus, parse
    from shapeprog.macros import load_library, refactor

    lib = load_library("chair")
    text = refactor(parse(corpus.read("chair", 173)), lib, category="chair", shape_id=173).text
    a = EditorApp(EditSession(text, "chair/173_macros.txt", library=lib), port=free_port(), export_dir=tmp_path)
    try:
        assert len(a._handles) == 15
        name = next(n for n in a._handles if n.startswith("Program_1:1:") and n.endswith(".x0"))  # the legs' width
        before = a.state["corners"].copy()
        a.handle(name).value = 0.25
        assert a.state["error"] is None and "# chair/173/Program_1\n" in a.state["text"]
        moved = np.abs(a.state["corners"] - before).max(axis=(1, 2)) > 1e-4
        assert moved.sum() == 4  # the four legs, nothing else
        corners = a.state["corners"].copy()
        a.expanded.value = True
        assert len(a._handles) > 15 and "Assembly Program_1 {" in a.state["text"]
        assert np.allclose(a.state["corners"], corners, atol=1e-5)
        a.expanded.value = False
        assert len(a._handles) == 15
    finally:
        a.stop()


def test_an_interrupt_while_the_address_is_printed_stops_the_server_cleanly(monkeypatch, tmp_path):
    import builtins

    from shapeedit import serve_until_interrupted

    class App:
        url, stopped = "http://127.0.0.1:1", False

        def stop(self):
            App.stopped = True

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    import signal

    before = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a parent that runs the editor in the background hands it down
    monkeypatch.setattr(builtins, "print", interrupted)
    try:
        assert serve_until_interrupted(App(), "x", tmp_path, False) == 0 and App.stopped
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Ctrl-C works again
    finally:
        signal.signal(signal.SIGINT, before)


def test_defect_a_slider_value_that_is_not_a_number_is_shown_not_raised(app):
    """A float slider's message of text or NaN is refused by the control's check and shown, the geometry
    kept; text used to raise in the server's handler thread (``float('abc')``)."""
    corners = app.state["corners"].copy()
    for bad in ("abc", float("nan")):
        app._changed("Program_0:1:cuboid.h", bad)
        assert "control 'Program_0:1:cuboid.h'" in app.state["error"] and np.array_equal(app.state["corners"], corners)
    app._changed("Program_0:1:cuboid.h", 0.30000000000000004)  # a browser's float, rounded as before
    assert app.state["error"] is None and ", 0.3, " in app.state["text"].split("\n")[2]


def test_defect_editor_accepts_any_web_origin_is_refused(app):
    from editor_testutil import assert_only_this_machines_pages_reach

    assert_only_this_machines_pages_reach(app.url)


@pytest.mark.parametrize("port", [70000, -1, 65536])
def test_defect_edit_port_out_of_range_is_refused(tmp_path, port):
    with pytest.raises(ValueError, match=f"port {port} is not a TCP port \\(an integer from 0 to 65535\\)"):
        EditorApp(EditSession(CHAIR, "chair/173.txt"), port=port, export_dir=tmp_path)


def test_defect_edit_port_out_of_range_is_an_argument_error(capsys):
    from shapeprog.__main__ import main

    assert_port_argument_error(main, ["assembly", "edit", "chair/173"], capsys)
