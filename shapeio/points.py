"""Point clouds: binary PLY (``x y z`` and optional ``nx ny nz``), OBJ ``v x y z`` lines, ``.xyz`` text, ``.npy``.

* :func:`write_points` / :func:`read_points`: the cloud files themselves.
* :func:`read_cloud`: a user's input as a cloud: a cloud file, or a mesh (OBJ or PLY with faces, STL, GLB,
  ...) sampled by area; optionally resampled to a fixed count.

Reading a PLY or a mesh goes through trimesh, imported on first use (it takes most of a second to import).
Every error about a file is an :class:`~shapeio.files.InputError` (or ``FileNotFoundError``) whose message
starts with the file's path, and names the line for text formats.
"""

from __future__ import annotations

import functools
import os
import warnings
from pathlib import Path
from typing import Iterable, Union

import numpy as np

from .arrays import as_numpy
from .files import InputError, atomic_write
from .mesh import MESH_SUFFIXES, _trimesh, load_mesh

__all__ = ["CLOUD_SUFFIXES", "MAX_LINE_CHARS", "MAX_POINTS", "MESH_POINTS", "MIN_POINTS", "obj_vertices", "read_cloud",
           "read_points", "sample_mesh", "write_points"]

PathLike = Union[str, os.PathLike]

#: Point-cloud file types (lower-case suffixes); an ``.obj`` or ``.ply`` with faces is read as a mesh by
#: :func:`read_cloud`.
CLOUD_SUFFIXES = (".obj", ".ply", ".xyz", ".npy")
#: Fewest points :func:`read_cloud` accepts from a cloud file.
MIN_POINTS = 16
#: Most points read from one cloud file (a bound on memory: 20M points are 240 MB of float32).
MAX_POINTS = 20_000_000
#: Points :func:`read_cloud` samples from a mesh when no count is given (the papers' 10,000).
MESH_POINTS = 10_000
#: Characters of one line of a text cloud file (``.obj``, ``.xyz``); a longer line is refused as it is read.
MAX_LINE_CHARS = 4096
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _points_array(x, name: str, path: PathLike) -> np.ndarray:
    arr = as_numpy(x)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{path}: `{name}` must have shape (N, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{path}: `{name}` contains NaN or infinite values")
    return arr.astype(np.float32)


def write_points(path: PathLike, points, normals=None) -> Path:
    """Write a point cloud as a binary little-endian PLY (``x y z`` and optionally ``nx ny nz``, float32).

    Args:
        path: target file.
        points: ``(N, 3) float`` (NumPy or torch).
        normals: optional ``(N, 3) float``.

    Returns:
        The path written.
    """
    pts = _points_array(points, "points", path)
    names = ["x", "y", "z"]
    cols = [pts]
    if normals is not None:
        nrm = _points_array(normals, "normals", path)
        if nrm.shape != pts.shape:
            raise ValueError(f"{path}: `normals` must match `points` {pts.shape}, got {nrm.shape}")
        names += ["nx", "ny", "nz"]
        cols.append(nrm)
    body = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element vertex {pts.shape[0]}\n"
    header += "".join(f"property float {n}\n" for n in names)
    header += "end_header\n"

    def write(f):
        f.write(header.encode("ascii"))
        f.write(body.tobytes())

    return atomic_write(path, write)


def _finite(pts: np.ndarray, where) -> np.ndarray:
    """``pts`` as float32; a NaN or infinite coordinate (also after the cast) names its point."""
    with np.errstate(over="ignore", invalid="ignore"):  # values beyond float32 become inf, reported below
        out = np.ascontiguousarray(pts, dtype=np.float32)
    bad = ~np.isfinite(out).all(axis=1)
    if bad.any():
        raise InputError(f"{where}: point {int(np.argmax(bad)) + 1} has a NaN or infinite coordinate "
                         "(or one beyond the float32 range)")
    return out


def _text_points(lines: Iterable[str], where, form: str, numbers) -> np.ndarray:
    """The points of a text cloud as ``(N, 3) float32``: ``numbers(line)`` gives a line's number fields (the
    first three are the point, further ones are ignored), or None for a line that holds no point; ``form``
    (``'x y z'``) names a point line in the errors, which name ``where:line``."""
    pts = []
    for lineno, line in enumerate(lines, 1):
        parts = numbers(line)
        if parts is None:
            continue
        try:
            if len(parts) < 3:
                raise ValueError
            xyz = [float(parts[0]), float(parts[1]), float(parts[2])]
        except ValueError:
            raise InputError(f"{where}:{lineno}: expected {form!r}, got {line.strip()[:80]!r}") from None
        if not all(abs(v) <= _FLOAT32_MAX for v in xyz):  # False for NaN
            raise InputError(f"{where}:{lineno}: the coordinates {line.strip()[:80]!r} are not finite float32 numbers")
        if len(pts) == MAX_POINTS:
            raise InputError(f"{where}:{lineno}: more than MAX_POINTS = {MAX_POINTS} points")
        pts.append(xyz)
    if not pts:
        raise InputError(f"{where}: no {form!r} line found")
    return np.asarray(pts, dtype=np.float32)


def _obj_numbers(line: str) -> list[str] | None:
    parts = line.split()
    return parts[1:] if parts and parts[0] == "v" else None


def _xyz_numbers(line: str) -> list[str] | None:
    parts = line.split("#", 1)[0].replace(",", " ").split()
    return parts or None


def obj_vertices(lines: Iterable[str], where) -> np.ndarray:
    """The ``v x y z`` points of OBJ text ``lines`` as ``(N, 3) float32``; errors name ``where:line``.

    Raises:
        InputError: a ``v`` line without three numbers, a NaN or infinite coordinate, more than
            :data:`MAX_POINTS` points, or no ``v`` line at all.
    """
    return _text_points(lines, where, "v x y z", _obj_numbers)


def _xyz_points(lines: Iterable[str], where) -> np.ndarray:
    """Points of ``.xyz`` text: one point per line, ``x y z`` and any further columns (normals,
    colours), separated by spaces, tabs or commas; blank lines and ``#`` comments are skipped."""
    return _text_points(lines, where, "x y z", _xyz_numbers)


def _npy_points(path: Path) -> np.ndarray:
    """An ``(N, 3)`` (or ``(N, C >= 3)``: the first three columns) numeric array from a ``.npy`` file."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SyntaxWarning)  # numpy parses a garbled header with `ast`
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except Exception as e:  # numpy raises several types for files that are not .npy
        raise InputError(f"{path}: cannot read the .npy file ({type(e).__name__}: {e})") from None
    if not isinstance(arr, np.ndarray):
        raise InputError(f"{path}: not a single .npy array")
    if arr.ndim != 2 or arr.shape[1] < 3 or arr.dtype.kind not in "iuf":
        raise InputError(f"{path}: expected an (N, 3) array of real numbers, got shape {arr.shape} dtype {arr.dtype}")
    if arr.shape[0] > MAX_POINTS:
        raise InputError(f"{path}: {arr.shape[0]} points; at most MAX_POINTS = {MAX_POINTS} are read")
    try:
        return np.array(arr[:, :3], dtype=np.float64)
    except Exception as e:  # a truncated file shows up when the data are read
        raise InputError(f"{path}: cannot read the .npy file ({type(e).__name__}: {e})") from None


def _load_ply(path: Path):
    try:
        return _trimesh().load(str(path), file_type="ply", process=False)
    except Exception as err:  # trimesh raises many types for bad files
        raise InputError(f"{path}: cannot read PLY ({type(err).__name__}: {err})") from None


def _ply_points(path: Path, loaded) -> tuple[np.ndarray, np.ndarray | None]:
    pts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data") if hasattr(loaded, "metadata") else None
    normals = None
    # binary PLY: a structured array; ASCII PLY: a dict of columns (trimesh keeps each as it was read)
    names = set(raw) if isinstance(raw, dict) else set(getattr(getattr(raw, "dtype", None), "names", None) or ())
    if {"nx", "ny", "nz"} <= names:
        try:
            normals = np.stack([np.asarray(raw[k], dtype=np.float64).reshape(-1) for k in ("nx", "ny", "nz")], axis=1)
        except (TypeError, ValueError) as e:
            raise InputError(f"{path}: unreadable vertex normals ({e})") from None
        if normals.shape != (len(pts), 3):
            raise InputError(f"{path}: {len(normals)} vertex normals for {len(pts)} vertices")
        normals = normals.astype(np.float32)
    if pts.ndim != 2 or pts.shape[0] == 0:
        raise InputError(f"{path}: the PLY holds no vertex")
    if pts.shape[0] > MAX_POINTS:
        raise InputError(f"{path}: {pts.shape[0]} points; at most MAX_POINTS = {MAX_POINTS} are read")
    return pts, normals


def _lines(f, where):
    """The lines of text file ``f``, each read with at most :data:`MAX_LINE_CHARS` characters in memory."""
    lineno = 0
    while True:
        line = f.readline(MAX_LINE_CHARS + 1)
        if not line:
            return
        lineno += 1
        if len(line) > MAX_LINE_CHARS and not line.endswith("\n"):
            raise InputError(f"{where}:{lineno}: a line longer than MAX_LINE_CHARS = {MAX_LINE_CHARS} characters")
        yield line


def _open_text(path: Path):
    return open(path, "r", encoding="utf-8", errors="replace")


def _check_file(path: Path) -> None:
    if path.is_dir():
        raise InputError(f"{path}: a folder, not a point-cloud or mesh file")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: the file is empty")


def _quiet_floats(fn):
    """Run ``fn`` without NumPy floating-point warnings: a file's NaN, infinite or huge values are checked
    and reported as :class:`InputError` instead (the overflow on the way is expected, not news)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with np.errstate(all="ignore"):
            return fn(*args, **kwargs)
    return wrapper


@_quiet_floats
def read_points(path: PathLike, return_normals: bool = False):
    """Read a point cloud file: OBJ ``v x y z`` lines, PLY (via trimesh), ``.xyz`` text or ``.npy``.

    Only the points are read: the faces of an OBJ or PLY mesh are ignored (use :func:`read_cloud` to
    sample a mesh's surface). ``.xyz`` holds one point per line (``x y z`` then any further columns,
    separated by spaces, tabs or commas; ``#`` starts a comment); ``.npy`` an ``(N, 3)`` (or
    ``(N, C >= 3)``, first three columns) array of real numbers.

    Args:
        path: ``.obj``, ``.ply``, ``.xyz`` or ``.npy`` file.
        return_normals: also return the PLY's ``nx ny nz`` (None when absent or for other formats).

    Returns:
        ``(N, 3) float32`` array, or ``(points, normals)`` with ``return_normals``.

    Raises:
        FileNotFoundError: no such file.
        InputError: naming the file (and the line for text formats): an empty or unreadable file, an
            unknown suffix, a line that is not a point, a NaN or infinite coordinate, no point, more
            than :data:`MAX_POINTS` points.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InputError(f"{path}: unsupported point-cloud format {suffix!r} (expected {', '.join(CLOUD_SUFFIXES)})")
    _check_file(path)
    normals = None
    if suffix == ".obj":
        with _open_text(path) as f:
            pts = obj_vertices(_lines(f, path), path)
    elif suffix == ".xyz":
        with _open_text(path) as f:
            pts = _xyz_points(_lines(f, path), path)
    elif suffix == ".npy":
        pts = _npy_points(path)
    else:
        pts, normals = _ply_points(path, _load_ply(path))
    pts = _finite(pts, path)
    if return_normals:
        return pts, None if normals is None else np.ascontiguousarray(normals)
    return pts


def _obj_has_faces(path: Path) -> bool:
    with _open_text(path) as f:
        return any(line.lstrip().startswith(("f ", "f\t")) for line in _lines(f, path))


def sample_mesh(mesh, n: int, seed: int = 0, where: PathLike = "<mesh>") -> tuple[np.ndarray, np.ndarray]:
    """``n`` points drawn uniformly by area on a triangle mesh (``trimesh.sample.sample_surface``), the
    sampler of every mesh :func:`read_cloud` reads.

    Args:
        mesh: a ``trimesh.Trimesh``.
        n: the number of points.
        seed: the sampling seed; the same mesh, count and seed give the same points.
        where: the name error messages start with (a file's path).

    Returns:
        ``points: (n, 3) float64`` and ``faces: (n,) int64``, the triangle each point lies on.

    Raises:
        InputError: the mesh has zero or no finite surface area, or a sampled point is not finite.
    """
    area = float(mesh.area)  # huge coordinates give an infinite area
    if not (np.isfinite(area) and area > 0):
        raise InputError(f"{where}: the mesh has zero or no finite surface area; there is nothing to sample")
    pts, faces = _trimesh().sample.sample_surface(mesh, int(n), seed=np.random.default_rng(seed))
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        raise InputError(f"{where}: sampled point {int(np.argmax(bad)) + 1} has a NaN or infinite coordinate")
    return pts, np.asarray(faces, dtype=np.int64)


def _sample_mesh(mesh, n: int, seed: int, path: Path) -> np.ndarray:
    return _finite(sample_mesh(mesh, n, seed, path)[0], path)  # float32, as every cloud read


def _resample(pts: np.ndarray, n: int, seed: int) -> np.ndarray:
    """Exactly ``n`` of ``pts``: a random subset without replacement, or, when there are fewer, every
    point once plus random repeats."""
    rng = np.random.default_rng(seed)
    if len(pts) >= n:
        idx = rng.choice(len(pts), size=n, replace=False)
    else:
        idx = np.concatenate([rng.permutation(len(pts)), rng.integers(0, len(pts), size=n - len(pts))])
    return np.ascontiguousarray(pts[idx])


@_quiet_floats
def read_cloud(path: PathLike, n_points: int | None = None, seed: int = 0) -> np.ndarray:
    """A user's input as a point cloud: a cloud file, or a mesh sampled uniformly by area.

    * Clouds: ``.xyz``, ``.npy``, and ``.obj`` / ``.ply`` without faces (:func:`read_points`).
    * Meshes: ``.obj`` / ``.ply`` with faces, and ``.stl``, ``.glb``, ``.gltf``, ``.off``
      (:func:`shapeio.mesh.load_mesh`), sampled with ``trimesh.sample.sample_surface`` (area-weighted):
      ``n_points`` points, :data:`MESH_POINTS` when None.

    Args:
        path: the file.
        n_points: the number of points returned. None: every point of a cloud file. A cloud with more
            points is subsampled without replacement; one with fewer keeps every point and repeats
            random ones.
        seed: seed of the mesh sampling and of the resampling; the same file, count and seed give the
            same points.

    Returns:
        ``(N, 3) float32``, in the file's own frame (normalise it with
        :func:`shapeprog.pointcloud.normalize`).

    Raises:
        FileNotFoundError: no such file.
        InputError: naming the file (and line): an empty file, an unknown suffix, a line that fails to
            parse, a NaN or infinite coordinate, a cloud with fewer than :data:`MIN_POINTS` points, an
            unreadable mesh or one with zero area.
        ValueError: ``n_points`` below :data:`MIN_POINTS` or above :data:`MAX_POINTS`.
    """
    path = Path(path)
    if n_points is not None and (isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer))
                                 or not MIN_POINTS <= n_points <= MAX_POINTS):
        raise ValueError(f"`n_points` must be an int in [{MIN_POINTS}, {MAX_POINTS}] or None, got {n_points!r}")
    suffix = path.suffix.lower()
    known = tuple(dict.fromkeys(CLOUD_SUFFIXES + MESH_SUFFIXES))
    if suffix not in known:
        raise InputError(f"{path}: unsupported file type {suffix!r} (clouds: {', '.join(CLOUD_SUFFIXES)}; "
                         f"meshes: {', '.join(MESH_SUFFIXES)})")
    _check_file(path)
    mesh = None
    if suffix == ".ply":
        loaded = _load_ply(path)
        if len(getattr(loaded, "faces", ())) > 0:
            mesh = load_mesh(path)
        else:
            pts = _finite(_ply_points(path, loaded)[0], path)
    elif suffix == ".obj" and _obj_has_faces(path):
        with _open_text(path) as f:
            obj_vertices(_lines(f, path), path)  # every 'v' line is a point: errors with the line number
        mesh = load_mesh(path)
    elif suffix in CLOUD_SUFFIXES:
        pts = read_points(path)
    else:
        mesh = load_mesh(path)
    if mesh is not None:
        return _sample_mesh(mesh, MESH_POINTS if n_points is None else int(n_points), seed, path)
    if len(pts) < MIN_POINTS:
        raise InputError(f"{path}: {len(pts)} point(s); a cloud needs at least MIN_POINTS = {MIN_POINTS}")
    return pts if n_points is None else _resample(pts, int(n_points), seed)
