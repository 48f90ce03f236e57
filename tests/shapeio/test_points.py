"""Tests of shapeio.points: binary PLY and OBJ point clouds."""
import numpy as np
import pytest

from shapeio.points import obj_vertices, read_points, write_points


def test_ply_round_trip_with_and_without_normals(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(30, 3)).astype(np.float32)
    nrm = rng.normal(size=(30, 3)).astype(np.float32)
    write_points(tmp_path / "p.ply", pts, nrm)
    p, n = read_points(tmp_path / "p.ply", return_normals=True)
    assert p.dtype == np.float32 and np.array_equal(p, pts) and np.array_equal(n, nrm)
    write_points(tmp_path / "q.ply", pts.astype(np.float64))
    q, qn = read_points(tmp_path / "q.ply", return_normals=True)
    assert np.array_equal(q, pts) and qn is None
    assert (tmp_path / "q.ply").read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\nelement vertex 30\n")


def test_obj_points():
    assert obj_vertices(["# c", "v 1 2 3", "vn 0 0 1", "v 4 5 6 0.5 0.5 0.5"], "x").tolist() == [[1, 2, 3], [4, 5, 6]]
    with pytest.raises(ValueError, match=r"x: no 'v x y z' line"):
        obj_vertices(["f 1 2 3"], "x")


def test_bad_arrays_name_the_file(tmp_path):
    with pytest.raises(ValueError, match=r"p\.ply: `points` must have shape \(N, 3\)"):
        write_points(tmp_path / "p.ply", np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"p\.ply: `normals` must match"):
        write_points(tmp_path / "p.ply", np.zeros((4, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"p\.ply: `points` contains NaN"):
        write_points(tmp_path / "p.ply", np.full((4, 3), np.nan))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(FileNotFoundError, match=r"none\.ply: no such file"):
        read_points(tmp_path / "none.ply")


@pytest.mark.parametrize("name, content, pattern", [
    ("bad.ply", b"ply\nformat nonsense\n", r"bad\.ply: cannot read PLY"),
    ("x.abc", b"1 2 3\n", r"x\.abc: unsupported point-cloud format"),
    ("c.obj", b"v 1 2 3\nv 1 2 oops\n", r"c\.obj:2: expected 'v x y z'"),
])
def test_unreadable_files_are_located(tmp_path, name, content, pattern):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ValueError, match=pattern):
        read_points(tmp_path / name)
