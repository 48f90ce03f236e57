"""Framing a shape in the editors' 3D view: a perspective camera pose from which a bounding box fills the
view (:func:`frame_box`), and putting that pose on a ``viser`` server (:func:`show_pose`). NumPy only; the
server is passed in.

The pose looks at the box's centre along a given direction from the nearest distance at which every corner
of the box lies within ``1 / FRAME_MARGIN`` of the way from the view's centre to its edge, across and up
(measured against the vertical field of view, the narrower one for a view wider than tall).

Example:
    >>> pose = frame_box((-1, -1, -1), (1, 1, 1), direction=(0, 0, 1), up=(0, 1, 0), fov=90.0)
    >>> pose.look_at.tolist(), pose.position.round(3).tolist()
    ([0.0, 0.0, 0.0], [0.0, 0.0, 2.1])
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_FOV", "FRAME_MARGIN", "CameraPose", "frame_box", "show_pose"]

#: Vertical field of view of a framed view, in degrees (narrower than viser's 75: less distortion).
DEFAULT_FOV = 45.0
#: The box's outermost corner lies at 1 / FRAME_MARGIN of the half-view from the view's centre.
FRAME_MARGIN = 1.1
#: Near and far clipping planes as fractions and multiples of the camera's distance to the box's centre.
NEAR_FRACTION, FAR_MULTIPLE = 0.01, 100.0
#: Half the side of the box framed when a box is empty or a point (so the distance stays positive).
MIN_HALF_SIZE = 1e-3


@dataclass(frozen=True)
class CameraPose:
    """A perspective camera: ``position`` and ``look_at`` (3,) float64 world points, ``up`` (3,) the unit vector
    that shows up in the view and that orbiting turns around (not necessarily square to the view direction),
    ``fov`` the vertical field of view in radians (viser's unit), ``near`` and ``far`` clipping distances."""

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov: float
    near: float
    far: float


def _vector(value, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise ValueError(f"`{name}` must be 3 finite numbers, got {value!r}")
    return v


def _unit(value, name: str) -> np.ndarray:
    v = _vector(value, name)
    n = float(np.linalg.norm(v))
    if n == 0.0:
        raise ValueError(f"`{name}` must not be the zero vector")
    return v / n


def frame_box(low, high, direction, up, fov: float = DEFAULT_FOV, margin: float = FRAME_MARGIN) -> CameraPose:
    """The pose that frames the box ``[low, high]``.

    Args:
        low, high: (3,) the box's smallest and largest corner.
        direction: (3,) from the box towards the camera (any length).
        up: (3,) the view's up direction (not parallel to ``direction``).
        fov: vertical field of view in degrees, in (0, 180).
        margin: >= 1; 1 puts the outermost corner on the view's edge, 2 halfway to it.

    Raises:
        ValueError: a vector that is not 3 finite numbers, ``low`` above ``high``, a zero or parallel
            ``direction`` / ``up``, or ``fov`` / ``margin`` out of range.
    """
    low, high = _vector(low, "low"), _vector(high, "high")
    if (low > high).any():
        raise ValueError(f"`low` {low.tolist()} is above `high` {high.tolist()}")
    back, up_hint = _unit(direction, "direction"), _unit(up, "up")
    if not (isinstance(fov, (int, float)) and 0.0 < fov < 180.0):
        raise ValueError(f"`fov` must be in (0, 180) degrees, got {fov!r}")
    if not (isinstance(margin, (int, float)) and 1.0 <= margin < math.inf):
        raise ValueError(f"`margin` must be a finite number >= 1, got {margin!r}")
    right = np.cross(up_hint, back)
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("`up` must not be parallel to `direction`")
    right /= np.linalg.norm(right)
    view_up = np.cross(back, right)
    centre = (low + high) / 2.0
    half = np.maximum((high - low) / 2.0, MIN_HALF_SIZE)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    corners = signs * half  # relative to the centre
    t = math.tan(math.radians(fov) / 2.0)
    # a corner at depth b (towards the camera) and offsets (x, y) lies at the fraction 1 / margin of the
    # half-view or nearer the centre from distance d when margin * max(|x|, |y|) <= (d - b) * t
    extent = np.maximum(np.abs(corners @ right), np.abs(corners @ view_up))
    distance = float(np.max(corners @ back + margin * extent / t))
    position = centre + distance * back
    return CameraPose(position, centre, up_hint, math.radians(fov), NEAR_FRACTION * distance, FAR_MULTIPLE * distance)


def show_pose(server, pose: CameraPose) -> None:
    """Make ``pose`` the view of ``server`` (a ``viser.ViserServer``): the pose new pages open with and "Reset
    View" returns to, and the current view of every page already open."""
    cam = server.initial_camera
    cam.up, cam.fov, cam.near, cam.far = pose.up, pose.fov, pose.near, pose.far
    cam.position, cam.look_at = pose.position, pose.look_at
    for client in server.get_clients().values():
        camera = client.camera
        if not _has_view(camera):  # a page that has not sent its view yet opens with the initial pose
            continue
        camera.up_direction = pose.up
        camera.fov, camera.near, camera.far = pose.fov, pose.near, pose.far
        camera.position = pose.position  # moves look_at with it, so look_at comes after
        camera.look_at = pose.look_at


def _has_view(camera) -> bool:
    """Whether a page's camera handle holds the page's view (viser's getters assert until it arrives)."""
    try:
        return camera.update_timestamp != 0.0
    except AssertionError:
        return False
