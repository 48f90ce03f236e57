"""shapeedit: the editors' undo / redo history and session moves, the lazy viser import, the port check and
the request guard (which pages may reach an editor)."""
import argparse
import sys

import pytest

from shapeedit import (EDITOR_EXTRA, History, UndoableSession, check_port, import_viser, port_argument,
                       refused_request)


def test_history_limit_keeps_the_newest():
    h = History("a", limit=2)
    for x in "bcd":
        h.push(x)
    assert len(h) == 2 and h.initial == "c" and h.current == "d"
    assert h.undo() == "c" and not h.can_undo


def test_undoable_session_moves_sync_and_clear_the_error():
    class Counter(UndoableSession):
        def __init__(self):
            self.history, self.error, self.value = None, None, None

        def _sync(self):
            self.value = self.history.current

    s = Counter()
    assert not s.undo() and not s.redo() and not s.reset()  # nothing loaded yet
    s._record(1)
    s._record(2)
    assert s.value == 2
    s.error = "last edit failed"
    assert s.undo() and s.value == 1 and s.error is None and not s.undo()
    assert s.redo() and s.value == 2 and not s.redo()
    assert s.reset() and s.value == 1 and s.history.can_undo
    assert not s.reset()  # already at the first state
    assert s.undo() and s.value == 2


def test_import_viser_names_the_extra_when_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # an import of viser now fails
    with pytest.raises(ImportError, match=rf"pip install -e '\.\[{EDITOR_EXTRA}\]'"):
        import_viser()


@pytest.mark.parametrize("port", [-1, 65536, 70000, True, 8080.0, "8080"])
def test_check_port_refuses_what_is_not_a_tcp_port(port):
    with pytest.raises(ValueError, match="is not a TCP port \\(an integer from 0 to 65535\\)"):
        check_port(port)


def test_port_argument_reads_a_port_or_names_the_text():
    assert port_argument("0") == 0 and port_argument("65535") == 65535
    with pytest.raises(argparse.ArgumentTypeError, match="port 'x' is not a TCP port"):
        port_argument("x")


@pytest.mark.parametrize("host, origin, reason", [
    ("127.0.0.1:8080", None, None),
    ("localhost:8080", "http://localhost:8080", None),
    ("[::1]:8080", "http://[::1]:8080", None),
    ("LOCALHOST:8080", "http://localhost:8080", None),
    (None, None, "host '' is not this machine's address"),
    ("evil.example", None, "host 'evil.example' is not this machine's address"),
    ("localhost.evil.example:80", None, "host 'localhost.evil.example:80' is not this machine's address"),
    ("127.0.0.1:8080", "null", "origin 'null' is not this editor's page"),
    ("127.0.0.1:8080", "https://127.0.0.1:8080", "origin 'https://127.0.0.1:8080' is not this editor's page"),
    ("127.0.0.1:8080", "http://127.0.0.1:9090", "origin 'http://127.0.0.1:9090' is not this editor's page"),
])
def test_refused_request(host, origin, reason):
    assert refused_request(host, origin) == reason


def test_frame_box_puts_the_outermost_corner_at_the_margin():
    import math

    import numpy as np

    from editor_testutil import view_fill
    from shapeedit.camera import FRAME_MARGIN, MIN_HALF_SIZE, frame_box

    low, high = np.array([-0.4, 0.0, -0.3]), np.array([0.6, 1.8, 0.5])
    pose = frame_box(low, high, direction=(0.9, 0.75, 1.5), up=(0, 1, 0))
    assert np.allclose(pose.look_at, [0.1, 0.9, 0.1]) and math.isclose(pose.fov, math.radians(45.0))
    assert np.array_equal(pose.up, [0, 1, 0])  # orbiting turns around the world's up, not a tilted one
    corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])
    assert math.isclose(view_fill(pose, corners), 1 / FRAME_MARGIN, rel_tol=1e-9)
    distance = float(np.linalg.norm(pose.position - pose.look_at))
    assert pose.near < distance - 1.0 and pose.far > distance + 1.0  # the box is between the clipping planes
    # a flat square seen straight on: its edge at the margin, whatever its size
    for half in (0.5, 700.0):
        flat = frame_box((-half, -half, 0), (half, half, 0), direction=(0, 0, -1), up=(0, -1, 0))
        depth = MIN_HALF_SIZE + FRAME_MARGIN * half / math.tan(math.radians(22.5))  # a flat box is 2e-3 thick
        assert np.allclose(flat.position, [0, 0, -depth], rtol=0, atol=1e-12)
        assert np.allclose(flat.up, [0, -1, 0])
    point = frame_box((1, 2, 3), (1, 2, 3), direction=(0, 0, 1), up=(0, 1, 0))  # a point: a tiny box, no zero
    assert np.allclose(point.look_at, [1, 2, 3]) and point.position[2] > 3


@pytest.mark.parametrize("kwargs, message", [
    (dict(low=(0, 0), high=(1, 1, 1)), "`low` must be 3 finite numbers"),
    (dict(low=(0, 0, float("nan"))), "`low` must be 3 finite numbers"),
    (dict(low=(2, 0, 0)), r"`low` \[2.0, 0.0, 0.0\] is above `high`"),
    (dict(direction=(0, 0, 0)), "`direction` must not be the zero vector"),
    (dict(up=(0, 0, 2)), "`up` must not be parallel to `direction`"),
    (dict(fov=180.0), r"`fov` must be in \(0, 180\) degrees"),
    (dict(margin=0.5), "`margin` must be a finite number >= 1"),
])
def test_frame_box_refuses_bad_input(kwargs, message):
    from shapeedit.camera import frame_box

    args = dict(low=(0, 0, 0), high=(1, 1, 1), direction=(0, 0, 1), up=(0, 1, 0)) | kwargs
    with pytest.raises(ValueError, match=message):
        frame_box(**args)


def test_show_pose_sets_the_initial_view_and_moves_the_open_pages():
    """New pages and "Reset View" get the pose; a page that has sent its view is moved to it; a page that has
    not (viser's camera handle asserts) is left to the initial pose."""
    from types import SimpleNamespace

    import numpy as np

    from shapeedit.camera import frame_box, show_pose

    class Camera:
        def __init__(self, ready):
            self.ready, self.set = ready, []

        @property
        def update_timestamp(self):
            assert self.ready
            return 1.0

        def __setattr__(self, name, value):
            if name not in ("ready", "set"):
                self.set.append(name)
            object.__setattr__(self, name, value)

    pose = frame_box((0, 0, 0), (1, 2, 3), direction=(1, 1, 1), up=(0, 0, 1))
    open_page, new_page = Camera(True), Camera(False)
    server = SimpleNamespace(initial_camera=SimpleNamespace(),
                             get_clients=lambda: {0: SimpleNamespace(camera=open_page),
                                                  1: SimpleNamespace(camera=new_page)})
    show_pose(server, pose)
    init = server.initial_camera
    assert np.array_equal(init.position, pose.position) and np.array_equal(init.look_at, pose.look_at)
    assert (init.fov, init.near, init.far) == (pose.fov, pose.near, pose.far) and np.array_equal(init.up, pose.up)
    assert open_page.set == ["up_direction", "fov", "near", "far", "position", "look_at"]  # look_at after position
    assert np.array_equal(open_page.look_at, pose.look_at) and np.array_equal(open_page.position, pose.position)
    assert new_page.set == []
