"""Tests of shapeio.points: binary and ASCII PLY and OBJ point clouds."""
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


def test_ascii_ply_with_and_without_normals(tmp_path):
    head = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
    (tmp_path / "a.ply").write_text(head + "end_header\n0 0 0\n1 2 3\n")
    p, n = read_points(tmp_path / "a.ply", return_normals=True)
    assert p.tolist() == [[0, 0, 0], [1, 2, 3]] and n is None
    normals = "property float nx\nproperty float ny\nproperty float nz\n"
    (tmp_path / "n.ply").write_text(head + normals + "end_header\n0 0 0 0 0 1\n1 2 3 1 0 0\n")
    p, n = read_points(tmp_path / "n.ply", return_normals=True)
    assert p.tolist() == [[0, 0, 0], [1, 2, 3]] and n.tolist() == [[0, 0, 1], [1, 0, 0]]


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


# ------------------------------------------------------------------------------------------ read_cloud

import io  # noqa: E402

import trimesh  # noqa: E402

from shapeio.files import InputError  # noqa: E402
from shapeio.mesh import write_mesh  # noqa: E402
from shapeio.points import MIN_POINTS, read_cloud  # noqa: E402

BOX = trimesh.creation.box(extents=(2.0, 1.0, 0.5))  # faces of area 0.5 (x), 1 (y), 2 (z)


def _cloud(n=40, seed=0):
    return np.random.default_rng(seed).normal(size=(n, 3)).astype(np.float32)


def test_xyz_and_npy_clouds(tmp_path):
    pts = _cloud()
    lines = ["# x y z nx ny nz", ""] + [f"{x}, {y}, {z}, 0, 0, 1" if i % 2 else f"{x}\t{y} {z}  # ok"
                                        for i, (x, y, z) in enumerate(pts.tolist())]
    (tmp_path / "c.xyz").write_text("\n".join(lines) + "\n")
    assert np.array_equal(read_points(tmp_path / "c.xyz"), pts)
    np.save(tmp_path / "c.npy", np.concatenate([pts, pts], axis=1).astype(np.float64))
    assert np.array_equal(read_points(tmp_path / "c.npy"), pts)
    assert np.array_equal(read_cloud(tmp_path / "c.npy"), pts)


def test_read_cloud_resamples_clouds_to_a_count(tmp_path):
    pts = _cloud(100)
    write_points(tmp_path / "c.ply", pts)
    a = read_cloud(tmp_path / "c.ply", n_points=30, seed=1)
    assert a.shape == (30, 3) and np.array_equal(a, read_cloud(tmp_path / "c.ply", n_points=30, seed=1))
    assert len({tuple(p) for p in a.tolist()}) == 30 and {tuple(p) for p in a.tolist()} <= {tuple(p) for p in pts.tolist()}
    more = read_cloud(tmp_path / "c.ply", n_points=250, seed=1)
    assert more.shape == (250, 3) and {tuple(p) for p in more.tolist()} == {tuple(p) for p in pts.tolist()}
    assert np.array_equal(read_cloud(tmp_path / "c.ply"), pts)
    with pytest.raises(ValueError, match="n_points"):
        read_cloud(tmp_path / "c.ply", n_points=MIN_POINTS - 1)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb", ".off"])
def test_meshes_are_sampled_by_area(tmp_path, suffix):
    path = tmp_path / f"box{suffix}"
    if suffix in (".obj", ".ply", ".glb"):
        write_mesh(path, BOX.vertices, BOX.faces)
    else:
        path.write_bytes(BOX.export(file_type=suffix[1:]).encode() if suffix == ".off" else BOX.export(file_type="stl"))
    pts = read_cloud(path, n_points=7000, seed=2)
    assert pts.shape == (7000, 3) and pts.dtype == np.float32
    assert np.array_equal(pts, read_cloud(path, n_points=7000, seed=2))
    half = np.array([1.0, 0.5, 0.25])
    on = np.isclose(np.abs(pts), half, atol=1e-5)
    assert on.any(axis=1).all()
    shares = on.mean(axis=0)  # both faces normal to each axis
    assert np.allclose(shares, np.array([1.0, 2.0, 4.0]) / 7.0, atol=0.02)
    assert read_cloud(path).shape == (10000, 3)


@pytest.mark.parametrize("name, content, pattern", [
    ("e.xyz", b"", r"e\.xyz: the file is empty"),
    ("few.xyz", b"0 0 0\n1 1 1\n", r"few\.xyz: 2 point\(s\); a cloud needs at least MIN_POINTS = 16"),
    ("n.xyz", b"0 0 0\n1 nan 1\n", r"n\.xyz:2: the coordinates '1 nan 1' are not finite"),
    ("b.xyz", b"0 0 0\n\n1 1\n", r"b\.xyz:3: expected 'x y z', got '1 1'"),
    ("o.obj", b"v 0 0 0\nv 1 2 inf\n", r"o\.obj:2: the coordinates"),
    ("w.obj", b"v 1 2 oops\n", r"w\.obj:1: expected 'v x y z'"),
    ("big.xyz", b"1e39 0 0\n", r"big\.xyz:1: the coordinates"),
    ("x.txt", b"1 2 3\n", r"x\.txt: unsupported file type '\.txt'"),
    ("m.stl", b"solid nonsense\nfacet what\n", r"m\.stl: "),
    ("f.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", r"f\.obj: the mesh has zero or no finite surface area"),
    ("t.obj", b"v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", r"t\.obj:2: expected 'v x y z', got 'v 1 0'"),
    ("s.npy", None, r"s\.npy: expected an \(N, 3\) array"),
    ("nan.npy", None, r"nan\.npy: point 3 has a NaN"),
])
def test_bad_inputs_name_the_file(tmp_path, name, content, pattern):
    path = tmp_path / name
    if name == "s.npy":
        np.save(path, np.zeros((5, 2)))
    elif name == "nan.npy":
        arr = np.zeros((20, 3))
        arr[2, 1] = np.inf
        np.save(path, arr)
    else:
        path.write_bytes(content)
    with pytest.raises(InputError, match=pattern):
        read_cloud(path)


def test_missing_file():
    with pytest.raises(FileNotFoundError, match=r"none\.xyz: no such file"):
        read_cloud("none.xyz")


def _valid(suffix: str) -> bytes:
    if suffix == ".xyz":
        return "".join(f"{x} {y} {z}\n" for x, y, z in _cloud(30).tolist()).encode()
    if suffix == ".npy":
        buf = io.BytesIO()
        np.save(buf, _cloud(30))
        return buf.getvalue()
    if suffix == ".obj":
        return "".join([f"v {x} {y} {z}\n" for x, y, z in BOX.vertices] + [f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in BOX.faces]).encode()
    data = BOX.export(file_type=suffix[1:])
    return data.encode() if isinstance(data, str) else data


@pytest.mark.parametrize("suffix", [".xyz", ".npy", ".obj", ".ply", ".stl", ".glb", ".off"])
def test_garbage_gives_only_our_errors(tmp_path, suffix):
    """Truncated, corrupted, spliced and random files: a cloud or an InputError naming the file, nothing else."""
    rng = np.random.default_rng(int.from_bytes(suffix.encode(), "little"))
    data = _valid(suffix)
    for k in range(24):
        d = bytearray(data)
        if k % 4 == 0:
            d = d[:int(rng.integers(0, len(d)))]
        elif k % 4 == 1:
            for _ in range(int(rng.integers(1, 10))):
                d[int(rng.integers(0, len(d)))] = int(rng.integers(0, 256))
        elif k % 4 == 2:
            d = bytes(rng.integers(0, 256, size=int(rng.integers(1, 300)), dtype=np.uint8))
        else:
            i = int(rng.integers(0, len(d)))
            d = d[:i] + bytes(rng.integers(0, 256, size=20, dtype=np.uint8)) + d[i:]
        path = tmp_path / f"g{k}{suffix}"
        path.write_bytes(bytes(d))
        try:
            pts = read_cloud(path, n_points=32)
        except InputError as e:
            assert str(e).startswith(str(path))
        else:
            assert pts.shape == (32, 3) and np.isfinite(pts).all()


def test_sample_mesh_gives_each_point_its_triangle_and_repeats_by_seed():
    from shapeio.points import sample_mesh

    mesh = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    pts, faces = sample_mesh(mesh, 3000, seed=5)
    assert pts.shape == (3000, 3) and pts.dtype == np.float64 and faces.shape == (3000,)
    tri = mesh.triangles[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.abs(((pts - tri[:, 0]) * normal).sum(1)).max() < 1e-12  # in its triangle's plane
    again, faces_again = sample_mesh(mesh, 3000, seed=5)
    assert np.array_equal(pts, again) and np.array_equal(faces, faces_again)
    assert not np.array_equal(pts, sample_mesh(mesh, 3000, seed=6)[0])
    flat = trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=[[0, 1, 2]], process=False)
    with pytest.raises(InputError, match="scan.stl: the mesh has zero"):
        sample_mesh(flat, 10, where="scan.stl")
