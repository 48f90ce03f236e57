"""Fuzz target for users' point-cloud and mesh files: :func:`shapeio.points.read_cloud`.

An input is ``<suffix>\\n<file bytes>``: the suffix picks the reader (so the mutator also reaches unknown
suffixes), the rest is written to a file of that suffix and read with ``n_points=32``. Only ``InputError``
may escape; the points must be finite.
"""
from __future__ import annotations

import io
import os
import tempfile

import numpy as np

from shapeio.files import InputError
from shapeio.points import read_cloud

from fuzz.engine import Target

__all__ = ["BOUND_S", "TARGETS", "run", "seeds"]

#: The longest one read may take (on a loaded 2-core machine).
BOUND_S = 3.0

_DIR = tempfile.mkdtemp(prefix="fuzz-clouds-")


def seeds() -> list[bytes]:
    """One valid file per suffix: clouds (.xyz, .npy, .ply, .obj) and meshes (.obj, .ply, .stl, .off, .glb)."""
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    pts = np.random.default_rng(0).normal(size=(20, 3)).astype(np.float32)
    npy = io.BytesIO()
    np.save(npy, pts)
    cloud = trimesh.PointCloud(pts)
    out = [(".xyz", "".join(f"{x} {y} {z}\n" for x, y, z in pts.tolist()).encode()), (".npy", npy.getvalue()),
           (".ply", cloud.export(file_type="ply")), (".obj", "".join(f"v {x} {y} {z}\n" for x, y, z in pts.tolist()).encode())]
    for suffix in ("obj", "ply", "stl", "off", "glb"):
        data = box.export(file_type=suffix)
        out.append((f".{suffix}", data.encode() if isinstance(data, str) else data))
    return [suffix.encode() + b"\n" + data for suffix, data in out]


def run(data: bytes) -> list[float]:
    """Read one input; the points' coordinates."""
    head, _, body = data.partition(b"\n")
    suffix = "." + "".join(c for c in head.decode("ascii", "replace") if c.isalnum())[:8]
    path = os.path.join(_DIR, "input" + suffix)
    with open(path, "wb") as f:
        f.write(body)
    try:
        return read_cloud(path, n_points=32, seed=0).reshape(-1).tolist()
    finally:
        os.unlink(path)


TARGETS = [Target("shapeio/cloud-files", seeds(), run, (InputError,), BOUND_S)]
