"""Fuzz targets for users' point-cloud and mesh files (:func:`shapeio.points.read_cloud`) and for the clouds
given to :func:`shapeprog.pointcloud.infer`.

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
from shapeprog.errors import PointCloudError

from fuzz.engine import Target

__all__ = ["BOUND_S", "TARGETS", "infer_seeds", "run", "run_infer", "seeds"]

#: The longest one read may take (on a loaded 2-core machine).
BOUND_S = 3.0

_DIR = tempfile.mkdtemp(prefix="fuzz-clouds-")


def seeds() -> list[bytes]:
    """One valid file per suffix: clouds (.xyz, .npy, binary and ASCII .ply, .obj) and meshes (.obj, .ply, .stl, .off, .glb)."""
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    pts = np.random.default_rng(0).normal(size=(20, 3)).astype(np.float32)
    npy = io.BytesIO()
    np.save(npy, pts)
    cloud = trimesh.PointCloud(pts)
    out = [(".xyz", "".join(f"{x} {y} {z}\n" for x, y, z in pts.tolist()).encode()), (".npy", npy.getvalue()),
           (".ply", cloud.export(file_type="ply")), (".ply", cloud.export(file_type="ply", encoding="ascii")),
           (".obj", "".join(f"v {x} {y} {z}\n" for x, y, z in pts.tolist()).encode())]
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


_MODEL = None


def _tiny_model():
    """A small untrained model (the chair VAE's decoder, an encoder of 16 / 8 centres): made once."""
    global _MODEL
    if _MODEL is None:
        import torch

        from shapeprog.pointcloud.encoder import PointNet2SSG
        from shapeprog.pointcloud.infer import CloudModel
        from shapeprog.vae.pretrained import load_pretrained

        torch.manual_seed(0)
        enc = PointNet2SSG(out_dim=256, npoints=[16, 8], nsamples=[8, 8],
                           widths=[[8, 8, 16], [16, 16, 32], [32, 32, 64]])
        _MODEL = CloudModel(enc, load_pretrained("chair"), "chair", "latent")
    return _MODEL


def infer_seeds() -> list[bytes]:
    """Clouds as float64 bytes: a box surface, a line, and a cloud far from the origin at a large scale."""
    rng = np.random.default_rng(0)
    box = rng.uniform(-1, 1, size=(64, 3))
    box[np.arange(64), rng.integers(0, 3, 64)] = rng.choice([-1.0, 1.0], 64)
    line = np.stack([np.linspace(0, 1, 32)] * 3, 1)
    far = box * 1e4 + 1e6
    return [x.astype(np.float64).tobytes() for x in (box, line, far)]


def run_infer(data: bytes) -> list[float]:
    """Infer a program for the bytes read as float64 triples (the tail that is not a whole triple dropped)."""
    from shapeprog.pointcloud.infer import infer

    n = len(data) // 24
    x = np.frombuffer(data[: 24 * n], dtype=np.float64).reshape(n, 3)
    r = infer(x, model=_tiny_model(), physics=False, retrieval=_small_index(), method="robust")
    return r.corners().reshape(-1).tolist()


_INDEX = None


def _small_index():
    """The robust method's retrieval index over 8 training chairs (the default index samples the whole train
    split once per machine, about a minute): made once."""
    global _INDEX
    if _INDEX is None:
        from shapeprog.pointcloud.data import corpus_splits
        from shapeprog.pointcloud.retrieval import RetrievalIndex

        _INDEX = RetrievalIndex.from_corpus("chair", ids=corpus_splits("chair")["train"][:8], cache=False)
    return _INDEX


TARGETS = [Target("shapeio/cloud-files", seeds(), run, (InputError,), BOUND_S),
           Target("pointcloud/infer", infer_seeds(), run_infer, (PointCloudError,), BOUND_S)]
