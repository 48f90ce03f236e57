"""Fuzz targets of the CSG side: program text (2D, 3D), users' shape files (image, ``.npy``, mesh) and
dataset files. Each feeds one mutated input to the parser or loader and returns the numbers its
execution produced (IoU and chamfer of the render against a fixed target)."""

from __future__ import annotations

import atexit
import io
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

import csgnet
from csgnet.data import generate_dataset, load_dataset
from csgnet.inference import load_shape
from csgnet.lang import ParseError
from csgnet.metrics import chamfer, iou, iou_3d
from shapeio import InputError

from fuzz.engine import Target

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
_TARGET_2D = csgnet.render("c(32,32,20)s(32,32,12)-")[0]
_TARGET_3D = csgnet.render("sp(32,32,32,20)", 3)[0]
_TMP = Path(tempfile.mkdtemp(prefix="csg-fuzz-"))  # the inputs under test are written here
atexit.register(shutil.rmtree, _TMP, ignore_errors=True)

TEXTS_2D = ["c(32,32,28)c(32,32,24)-s(32,32,28)s(32,32,20)-+t(32,32,20)+", "c(32,32,16)s(24,40,12)+",
            "t(32,24,20)s(32,44,12)+c(16,16,8)*", "s(-4,70,12)", "c(32, 32, 8) $ junk"]
TEXTS_3D = ["sp(32,32,32,20)cu(32,32,32,28)*", "cy(32,32,32,16,24)sp(32,32,48,12)+", "p(8,8,8,8)u(56,56,56,12)-"]
CUBE_OBJ = ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
            "f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\n"
            "f 4 1 5\nf 4 5 8\n")


def _scores(img: np.ndarray) -> list[float]:
    if img.ndim == 3:
        return [float(iou_3d(img, _TARGET_3D))]
    return [float(iou(img, _TARGET_2D)), float(chamfer(img, _TARGET_2D))]  # the target is not empty: no NaN


def _text(dim: int):
    def run(data: bytes) -> list[float]:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            return []  # the parser takes str; the dataset target covers undecodable bytes
        program = csgnet.parse(text, dim)
        return _scores(csgnet.render(program, dim)[0])
    return run


def _file(suffix: str):
    def run(data: bytes) -> list[float]:
        path = _TMP / f"input{suffix}"
        path.write_bytes(data)
        return _scores(load_shape(path))
    return run


def _npy(arr) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=False)
    return buf.getvalue()


def _dataset_root() -> Path:
    root = _TMP / "dataset"
    if not (root / "2d" / "meta.json").exists():
        generate_dataset(root, dim=2, scale=0.0002, seed=0, lengths=[3], progress=False)
    return root


def _dataset(data: bytes) -> list[float]:
    root = _dataset_root()
    (root / "2d" / "len_03" / "test.txt").write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # bad lines are reported as a warning; the rest must load
        programs = load_dataset(root, 2, "test")[3]
    return _scores(csgnet.render(programs[0])[0]) if programs else []


def _seeds_dataset() -> list[bytes]:
    return [(_dataset_root() / "2d" / "len_03" / "test.txt").read_bytes(), b"c(8,8,8)\n\nc(8,8,8)c(16,16,8)+\n"]


TARGETS = [
    Target("csg/text-2d", [t.encode() for t in TEXTS_2D], _text(2), (ParseError,), 1.0),
    Target("csg/text-3d", [t.encode() for t in TEXTS_3D], _text(3), (ParseError,), 1.0),
    Target("csg/image-png", [(EXAMPLES / n).read_bytes() for n in ("house.png", "ring.png")], _file(".png"),
           (InputError,), 2.0),
    Target("csg/npy", [_npy(_TARGET_2D), _npy(np.eye(12, dtype=np.float32)), _npy(_TARGET_3D[::4, ::4, ::4])],
           _file(".npy"), (InputError,), 2.0),
    Target("csg/mesh-obj", [CUBE_OBJ.encode()], _file(".obj"), (InputError,), 3.0),
    Target("csg/dataset", _seeds_dataset(), _dataset, (), 2.0),
]
