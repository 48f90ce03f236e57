"""What the editor tests of both systems share: programs, a free port, the checks of which pages may reach an
editor and of the ``--port`` argument, and how much of a view a framed shape fills."""

# one statement of every kind
EVERY = """bbox = Cuboid(1.0, 1.0, 1.0, True)
cube0 = Cuboid(0.2, 0.5, 0.2, False)
cube1 = Cuboid(0.8, 0.1, 0.8, True)
cube2 = Cuboid(0.1, 0.3, 0.1, True)
attach(cube1, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)
squeeze(cube0, bbox, cube1, bot, 0.2, 0.3)
attach(cube2, cube1, 0.5, 0.0, 0.5, 0.1, 1.0, 0.1)
reflect(cube0, X)
translate(cube2, Z, 2, 0.5)
"""

MACROS = """def leg(s: float, b: bool, t: float):
    c = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, bot, 0.6 * s, t)
    reflect(X)

def four_legs(s: float, b: bool, t: float):
    c1 = leg(s, b, t)
    c2 = leg(0.95 * s, b, 1.0 - t)

bbox = Cuboid(1.2, 0.9, 1.0, True)
leg0, leg1 = four_legs(0.1, True, 0.2)
seat = Cuboid(1.2, 0.1, 1.0, True)
attach(leg0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)
"""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that no socket holds now."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def assert_port_argument_error(main, argv: list[str], capsys) -> None:
    """``main(argv + ["--port", "70000"])`` (an ``edit`` command's entry point) stops with argparse's exit status
    2 and a last line of usage error that names the port."""
    import pytest

    with pytest.raises(SystemExit) as e:
        main([*argv, "--port", "70000", "--no-browser"])
    assert e.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        "error: argument --port: port '70000' is not a TCP port (an integer from 0 to 65535)")


def assert_only_this_machines_pages_reach(url: str) -> None:
    """The editor page at ``url`` (``http://127.0.0.1:PORT``) answers 403 to HTTP with another site's
    ``Host`` and refuses websockets from another site's page or ``Host``; its own page's websocket gets the
    program's messages."""
    import urllib.error
    import urllib.request

    import pytest
    import viser
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    ws, protocol = "ws" + url[4:], [f"viser-v{viser.__version__}"]
    request = urllib.request.Request(url, headers={"Host": "evil.example"})
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(request, timeout=10)
    assert e.value.code == 403
    for headers in ({"origin": "http://evil.example"}, {"origin": "null"},
                    {"origin": "http://evil.example", "additional_headers": {"Host": "evil.example"}}):
        with pytest.raises(InvalidStatus) as e:
            connect(ws, subprotocols=protocol, open_timeout=10, **headers)
        assert e.value.response.status_code == 403, (headers, e.value.response.status_code, e.value.response.body)
    with connect(ws, subprotocols=protocol, origin=url, open_timeout=10) as c:
        assert len(c.recv(timeout=10)) > 0
    with urllib.request.urlopen(url.replace("127.0.0.1", "localhost"), timeout=10) as r:
        assert r.status == 200


def view_fill(pose, points) -> float:
    """How much of the view the points fill: the largest of their offsets from the view's centre, across or
    up, over the half-height of the view at their depth (1: a point on the edge of the vertical field of
    view; above 1: outside it)."""
    import math

    import numpy as np

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    back = (pose.position - pose.look_at) / np.linalg.norm(pose.position - pose.look_at)
    right = np.cross(pose.up, back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    rel = points - pose.position
    depth = -(rel @ back)
    assert (depth > 0).all(), "a point behind the camera"
    offset = np.maximum(np.abs(rel @ right), np.abs(rel @ up))
    return float((offset / (depth * math.tan(pose.fov / 2))).max())
