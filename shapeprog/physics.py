"""Physical metrics of ShapeAssembly shapes: box distances, contact graph, rootedness, stability.

Definitions follow the reference code (``valid.py``) where it differs from the paper;
``docs/shapeassembly_metrics.md`` lists every such choice. Everything works on CPU in NumPy,
float64, on leaf cuboids ``corners (L, 8, 3)`` (tensor or array) in the y-up world.
:func:`stability` needs ``pybullet`` and runs it headless (``DIRECT``), writing no files.

Example:
    >>> import torch
    >>> from shapeprog.geometry import cuboid_corners
    >>> centres = torch.tensor([[0.0, 0.5, 0.0], [0.0, 2.0, 0.0]])  # a box on the ground, one floating
    >>> parts = cuboid_corners(centres, torch.ones(2, 3), torch.eye(3).expand(2, 3, 3))
    >>> rooted_parts(parts).tolist(), rootedness(parts[:1])
    ([True, False], True)
"""
from __future__ import annotations

import math
from typing import List, Tuple

import numpy as np
import torch

from shapeio.files import c_output_silenced
from shapeprog.geometry import CORNER_SIGNS, numpy_corners

__all__ = ["CODE_STABILITY_TOLERANCE", "PAPER_STABILITY_TOLERANCE", "box_distances", "contact_graph", "rooted_parts",
           "rootedness", "stability", "stability_displacement"]

#: The stability rule of the reference code: a group's base may move vertically by 2.5 % of its height.
CODE_STABILITY_TOLERANCE = 0.025
#: The rule the ShapeAssembly paper's appendix E describes: 10 % of the height.
PAPER_STABILITY_TOLERANCE = 0.10


# --------------------------------------------------------------------------------------------------
# Oriented-box geometry (NumPy, float64)


def _frames(corners: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (L,3), rotation rows (L,3,3) (proper, orthonormal) and half extents (L,3) from corners."""
    c = corners.mean(axis=1)
    # corner 0 = (+,+,+), 4 = (-,+,+), 2 = (+,-,+), 1 = (+,+,-)
    edges = np.stack([corners[:, 0] - corners[:, 4], corners[:, 0] - corners[:, 2], corners[:, 0] - corners[:, 1]], 1)
    half = np.linalg.norm(edges, axis=-1) / 2
    # nearest orthonormal frame (polar decomposition); zero-length edges get an arbitrary axis
    u, _, vt = np.linalg.svd(edges)
    rot = u @ vt
    det = np.linalg.det(rot)
    rot[det < 0, 2] *= -1
    return c, rot, half


#: (8, 3) float64 corner signs in the spec's order.
_SIGNS = CORNER_SIGNS.double().numpy()


def _box_corners(c: np.ndarray, rot: np.ndarray, half: np.ndarray) -> np.ndarray:
    return c[:, None, :] + np.einsum("nk,lk,lkc->lnc", _SIGNS, half, rot)


_EDGES = np.array(
    [[0, 4], [1, 5], [2, 6], [3, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 1], [2, 3], [4, 5], [6, 7]]
)


def _point_box_outside(p: np.ndarray, c: np.ndarray, rot: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Distance from points (P,K,3) to solid boxes (P,...) (0 inside)."""
    local = np.einsum("pkc,pjc->pkj", p - c[:, None], rot)
    return np.linalg.norm(np.maximum(np.abs(local) - half[:, None], 0.0), axis=-1)


def _point_box_slack(p: np.ndarray, c: np.ndarray, rot: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Signed depth of points inside boxes: min over axes of half - |local| (negative outside)."""
    local = np.einsum("pkc,pjc->pkj", p - c[:, None], rot)
    return (half[:, None] - np.abs(local)).min(-1)


def _segment_distances(p1, q1, p2, q2) -> np.ndarray:
    """Distances between segments [p1,q1] and [p2,q2], arrays (..., 3)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.maximum((d1 * d1).sum(-1), 1e-300)
    e = np.maximum((d2 * d2).sum(-1), 1e-300)
    f = (d2 * r).sum(-1)
    c = (d1 * r).sum(-1)
    b = (d1 * d2).sum(-1)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-12 * a * e, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        s = np.where(t < 0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1, np.clip((b - c) / a, 0.0, 1.0), s))
        t = np.clip(t, 0.0, 1.0)
    diff = (p1 + s[..., None] * d1) - (p2 + t[..., None] * d2)
    return np.linalg.norm(diff, axis=-1)


def _separated(ca, ra, ha, cb, rb, hb) -> np.ndarray:
    """Separating-axis test for pairs of oriented boxes (P,...) -> (P,) True if disjoint."""
    axes = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            axes.append(np.cross(ra[:, i], rb[:, j]))
    axes = np.stack(axes, 1)  # (P, 15, 3)
    norm = np.linalg.norm(axes, axis=-1)
    valid = norm > 1e-9
    axes = axes / np.where(valid, norm, 1.0)[..., None]
    t = cb - ca
    rad_a = (np.abs(np.einsum("pkc,pjc->pkj", axes, ra)) * ha[:, None]).sum(-1)
    rad_b = (np.abs(np.einsum("pkc,pjc->pkj", axes, rb)) * hb[:, None]).sum(-1)
    dist = np.abs(np.einsum("pkc,pc->pk", axes, t))
    return (valid & (dist > rad_a + rad_b)).any(-1)


def box_distances(corners: np.ndarray, surface: bool = True) -> np.ndarray:
    """Pairwise minimum distances between cuboids (exact, float64).

    Two disjoint boxes get their Euclidean distance. Overlapping or touching boxes get 0, except
    that with ``surface=True`` a box lying strictly inside another gets the distance between the two
    *surfaces* (the depth of its shallowest corner), which is what a collision library returns for
    two closed triangle meshes (the reference compares meshes with FCL).

    Args:
        corners: ``(L, 8, 3) float`` array or tensor.
        surface: measure nested boxes surface to surface (reference) instead of as solids (0).

    Returns:
        ``(L, L) float64`` symmetric, zero diagonal.
    """
    corners = np.asarray(corners.detach().cpu() if isinstance(corners, torch.Tensor) else corners, dtype=np.float64)
    c, rot, half = _frames(corners)
    pts = _box_corners(c, rot, half)
    n = corners.shape[0]
    out = np.zeros((n, n))
    if n < 2:
        return out
    ia, ib = np.triu_indices(n, 1)
    sep = _separated(c[ia], rot[ia], half[ia], c[ib], rot[ib], half[ib])
    # disjoint: min of vertex-box and edge-edge distances
    d_ab = _point_box_outside(pts[ia], c[ib], rot[ib], half[ib]).min(-1)
    d_ba = _point_box_outside(pts[ib], c[ia], rot[ia], half[ia]).min(-1)
    ea0, ea1 = pts[ia][:, _EDGES[:, 0]], pts[ia][:, _EDGES[:, 1]]
    eb0, eb1 = pts[ib][:, _EDGES[:, 0]], pts[ib][:, _EDGES[:, 1]]
    d_ee = _segment_distances(
        ea0[:, :, None], ea1[:, :, None], eb0[:, None, :], eb1[:, None, :]
    ).reshape(len(ia), -1).min(-1)
    d = np.where(sep, np.minimum(np.minimum(d_ab, d_ba), d_ee), 0.0)
    if surface:
        slack_ab = _point_box_slack(pts[ia], c[ib], rot[ib], half[ib]).min(-1)  # A in B
        slack_ba = _point_box_slack(pts[ib], c[ia], rot[ia], half[ia]).min(-1)  # B in A
        nested = np.maximum(np.maximum(slack_ab, slack_ba), 0.0)
        d = np.where(sep, d, nested)
    out[ia, ib] = d
    out[ib, ia] = d
    return out


def _ground_corners(corners: np.ndarray) -> np.ndarray:
    """The reference's ground: a 10 x 0.01 x 10 box (y-up) whose top is the shape's lowest point."""
    low = corners[..., 1].min()
    half = np.array([5.0, 0.005, 5.0])
    return (np.array([0.0, low - 0.005, 0.0]) + _SIGNS * half)[None]


def contact_graph(corners, tolerance: float = 0.02, surface: bool = True) -> np.ndarray:
    """Adjacency ``(L + 1, L + 1) bool`` of parts and the ground (last node).

    Two parts, or a part and the ground box, are adjacent when their minimum distance is below
    ``tolerance`` times the diagonal of the shape's axis-aligned bounding box.
    """
    corners = numpy_corners(corners)
    flat = corners.reshape(-1, 3)
    scale = float(np.linalg.norm(flat.max(0) - flat.min(0)))
    dist = box_distances(np.concatenate([corners, _ground_corners(corners)]), surface=surface)
    adj = dist < tolerance * scale
    np.fill_diagonal(adj, False)
    return adj


def _reachable(adj: np.ndarray, start: int) -> np.ndarray:
    seen = np.zeros(adj.shape[0], dtype=bool)
    stack = [start]
    seen[start] = True
    while stack:
        i = stack.pop()
        for j in np.flatnonzero(adj[i] & ~seen):
            seen[j] = True
            stack.append(j)
    return seen


def _rooted(adj: np.ndarray) -> np.ndarray:
    """Parts ``(L,) bool`` reachable from the ground (the last node) of a contact graph."""
    return _reachable(adj, adj.shape[0] - 1)[:-1]


def rooted_parts(corners, tolerance: float = 0.02, surface: bool = True) -> np.ndarray:
    """Which parts ``(L,) bool`` connect to the ground through a chain of contacts (see :func:`rootedness`)."""
    return _rooted(contact_graph(corners, tolerance, surface))


def rootedness(corners, tolerance: float = 0.02, surface: bool = True) -> bool:
    """Whether every part is connected to the ground through contacts (reference ``check_rooted``).

    A ground box of 10 x 0.01 x 10 (y-up) is placed with its top at the shape's lowest point. Two
    parts (or a part and the ground) are in contact when their minimum distance is below
    ``tolerance`` (2 %) of the shape's bounding-box diagonal. The shape is rooted when every part is
    reachable from the ground. Distances are exact box-to-box distances; with ``surface=True``
    (the reference's mesh-to-mesh behaviour) a part buried inside another counts from surface to
    surface, with ``surface=False`` it touches it.

    Args:
        corners: ``(L, 8, 3) float`` leaf cuboids (tensor or array), y-up.
        tolerance: contact distance as a fraction of the bounding-box diagonal.
        surface: see above.

    Returns:
        True when rooted.
    """
    return bool(rooted_parts(corners, tolerance, surface).all())


def _groups(adj: np.ndarray) -> List[List[int]]:
    """Connected components of the parts (ground excluded), each in DFS order from its lowest index."""
    n = adj.shape[0] - 1
    parts = adj[:n, :n]
    seen = np.zeros(n, dtype=bool)
    out = []
    for s in range(n):
        if seen[s]:
            continue
        order, parent, stack = [], {s: -1}, [s]
        seen[s] = True
        while stack:
            i = stack.pop()
            order.append(i)
            for j in np.flatnonzero(parts[i] & ~seen)[::-1]:
                seen[j] = True
                parent[j] = i
                stack.append(j)
        out.append([(i, parent[i]) for i in order])
    return out


def _quat(m: np.ndarray) -> List[float]:
    """(x, y, z, w) quaternion of a proper rotation matrix (columns = local axes in world)."""
    from scipy.spatial.transform import Rotation  # lazy: adds ~0.5 s to `import shapeprog`

    return Rotation.from_matrix(m).as_quat().tolist()


def stability(
    corners,
    tolerance: float = CODE_STABILITY_TOLERANCE,
    steps: int = 10000,
    contact_tolerance: float = 0.02,
    surface: bool = True,
    inertia: str = "identity",
) -> bool:
    """Whether a shape stays put under gravity after a kick (reference ``check_stability``, pybullet).

    The shape must be rooted first (:func:`rootedness`); an unrooted shape is unstable. The world is
    converted to z-up by swapping y and z. Parts are grouped into connected components of the
    contact graph (same 2 % rule, ground excluded). Each group becomes one pybullet multibody: one
    box link per part with mass = volume (density 1) and, as in the reference's URDF, an identity
    inertia tensor about the part's centre (``inertia="box"`` uses the solid box's inertia
    instead), joined by fixed joints along a DFS tree. It is placed with its lowest point on the ground plane ``z = 0``.
    Groups do not collide with each other, so each is simulated in its own world. With
    ``v = volume * base`` (``base`` = the smaller horizontal extent of the group's bounding box), the
    group gets an upward force ``(0, 0, 1000 v)`` at its base position and torques ``(0, 4 v, 0)``,
    ``(4 v, 0, 0)``, ``(0, 0, 80 v)`` for the first step, then ``steps`` steps of 1/240 s run under
    gravity ``-9.8 z``. The shape is unstable when some group's base moved vertically by more than
    ``tolerance`` (:data:`CODE_STABILITY_TOLERANCE`, 2.5 %; the paper says 10 %,
    :data:`PAPER_STABILITY_TOLERANCE`) of the group's height: ``stability_displacement(...) <= tolerance``
    (:func:`stability_displacement`, one simulation for any number of rules).

    Deterministic: the same input gives the same answer. Headless, writes no files.

    Args:
        corners: ``(L, 8, 3) float`` leaf cuboids, y-up.
        tolerance: allowed vertical displacement of a group's base as a fraction of its height.
        steps: simulation steps (10,000 in the reference).
        contact_tolerance: contact distance for rootedness and grouping (fraction of the diagonal).
        surface: see :func:`rootedness`.
        inertia: ``"identity"`` (reference URDF, default) or ``"box"`` (physical solid boxes; much
            more sensitive to the kick: most corpus chairs then count as unstable).

    Returns:
        True when stable.

    Raises:
        ImportError: if pybullet is not installed.
    """
    return stability_displacement(corners, steps, contact_tolerance, surface, inertia) <= tolerance


def stability_displacement(
    corners,
    steps: int = 10000,
    contact_tolerance: float = 0.02,
    surface: bool = True,
    inertia: str = "identity",
) -> float:
    """The simulation of :func:`stability`: the largest vertical displacement of a group's base as a fraction of
    the group's height (``inf`` for a shape that is not rooted). A shape is stable under a rule ``tolerance``
    when the displacement is at most ``tolerance``, so one simulation answers the code's 2.5 % and the paper's
    10 % rules (:data:`CODE_STABILITY_TOLERANCE`, :data:`PAPER_STABILITY_TOLERANCE`). Arguments as
    :func:`stability`."""
    if inertia not in ("identity", "box"):
        raise ValueError(f"`inertia` must be 'identity' or 'box', got {inertia!r}")
    corners = numpy_corners(corners)
    adj = contact_graph(corners, contact_tolerance, surface)
    if not _rooted(adj).all():
        return math.inf

    try:
        with c_output_silenced():  # pybullet prints its build banner from C on import and connect
            import pybullet as pb  # lazy: only stability() needs the physics engine
    except ImportError as err:  # pragma: no cover - pybullet is a core dependency
        raise ImportError("stability() needs pybullet: pip install pybullet") from err

    # y-up -> z-up by swapping y and z (a mirror); re-orthonormalise the frames to proper rotations
    swapped = corners[..., [0, 2, 1]]
    centres, rot, half = _frames(swapped)
    half = np.maximum(half, 1e-4)
    volume = 8.0 * half.prod(-1)
    groups = _groups(adj)
    worst = 0.0
    with c_output_silenced():
        client = pb.connect(pb.DIRECT)
    try:
        for group in groups:
            pb.resetSimulation(physicsClientId=client)
            pb.setGravity(0, 0, -9.8, physicsClientId=client)
            plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client)
            pb.createMultiBody(0, plane, physicsClientId=client)
            idx = [i for i, _ in group]
            pts = _box_corners(centres[idx], rot[idx], half[idx]).reshape(-1, 3)
            lo, hi = pts.min(0), pts.max(0)
            height = float(hi[2] - lo[2])
            mass = volume[idx]
            centroid = (centres[idx] * mass[:, None]).sum(0) / mass.sum()
            shift = np.array([-centroid[0], -centroid[1], -lo[2]])
            pos = {i: centres[i] + shift for i in idx}
            mats = {i: rot[i].T for i in idx}  # columns = box axes in world
            shapes = {
                i: pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half[i].tolist(), physicsClientId=client)
                for i in idx
            }
            root = idx[0]
            link_of = {root: 0}
            kw = dict(
                linkMasses=[], linkCollisionShapeIndices=[], linkVisualShapeIndices=[], linkPositions=[],
                linkOrientations=[], linkInertialFramePositions=[], linkInertialFrameOrientations=[],
                linkParentIndices=[], linkJointTypes=[], linkJointAxis=[],
            )
            for i, par in group[1:]:
                link_of[i] = len(kw["linkMasses"]) + 1
                rel = mats[par].T @ (pos[i] - pos[par])
                kw["linkMasses"].append(float(volume[i]))
                kw["linkCollisionShapeIndices"].append(shapes[i])
                kw["linkVisualShapeIndices"].append(-1)
                kw["linkPositions"].append(rel.tolist())
                kw["linkOrientations"].append(_quat(mats[par].T @ mats[i]))
                kw["linkInertialFramePositions"].append([0.0, 0.0, 0.0])
                kw["linkInertialFrameOrientations"].append([0.0, 0.0, 0.0, 1.0])
                kw["linkParentIndices"].append(link_of[par])
                kw["linkJointTypes"].append(pb.JOINT_FIXED)
                kw["linkJointAxis"].append([0.0, 0.0, 1.0])
            body = pb.createMultiBody(
                baseMass=float(volume[root]),
                baseCollisionShapeIndex=shapes[root],
                basePosition=pos[root].tolist(),
                baseOrientation=_quat(mats[root]),
                physicsClientId=client,
                **kw,
            )
            if inertia == "identity":
                for link in range(-1, len(group) - 1):
                    pb.changeDynamics(body, link, localInertiaDiagonal=[1.0, 1.0, 1.0], physicsClientId=client)
            start = np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
            base = float(min(hi[0] - lo[0], hi[1] - lo[1]))
            v = float(mass.sum()) * base
            pb.applyExternalForce(body, -1, [0, 0, 1000 * v], start.tolist(), pb.WORLD_FRAME, physicsClientId=client)
            for torque in ([0, 4 * v, 0], [4 * v, 0, 0], [0, 0, 80 * v]):
                pb.applyExternalTorque(body, -1, torque, pb.WORLD_FRAME, physicsClientId=client)
            for _ in range(int(steps)):
                pb.stepSimulation(physicsClientId=client)
            end = np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
            worst = max(worst, abs(float(end[2] - start[2])) / height if height > 0 else math.inf)
        return worst
    finally:
        pb.disconnect(physicsClientId=client)
