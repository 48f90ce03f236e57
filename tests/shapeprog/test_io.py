"""Tests for shapeprog.io: reference OBJ layout, trimesh round trips, atomic writes (PNG: tests/shapeio)."""
import functools
import os

import numpy as np
import pytest
import torch

import trimesh  # noqa: E402  (a core dependency)

import sa_testutil
from shapeprog import io as sio
from shapeprog.io import read_points, write_glb, write_obj, write_ply, write_points, write_voxels

boxes = functools.partial(sa_testutil.boxes, dtype=torch.float32)  # the reference precision


ONE_CUBOID_OBJ = """v 1.0 2.0 3.0
v 1.0 2.0 0.0
v 1.0 0.0 3.0
v 1.0 0.0 0.0
v 0.0 2.0 3.0
v 0.0 2.0 0.0
v 0.0 0.0 3.0
v 0.0 0.0 0.0
g part_0
f 1 3 2
f 2 3 4
f 1 5 7
f 1 7 3
f 2 4 6
f 4 8 6
f 5 6 8
f 5 8 7
f 2 6 5
f 1 2 5
f 3 7 8
f 3 8 4
"""


def test_obj_exact_text_one_cuboid(tmp_path):
    path = write_obj(tmp_path / "one.obj", boxes([0.5, 1.0, 1.5], [1.0, 2.0, 3.0]))
    assert path.read_bytes() == ONE_CUBOID_OBJ.encode("ascii")


def test_obj_float32_repr_and_leaf_offsets(tmp_path):
    corners = boxes([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]], [[0.2, 0.2, 0.2], [1.0, 1.0, 1.0]])
    text = write_obj(tmp_path / "two.obj", corners).read_text()
    lines = text.splitlines()
    assert len(lines) == 16 + 2 + 24
    # float32(0.1) printed as the double it is
    assert lines[0] == "v 0.10000000149011612 0.10000000149011612 0.10000000149011612"
    assert lines[8] == "v 2.5 0.5 0.5"
    assert lines[16] == "g part_0" and lines[29] == "g part_1"
    assert lines[17] == "f 1 3 2" and lines[30] == "f 9 11 10" and lines[-1] == "f 11 16 12"
    mesh = trimesh.load(tmp_path / "two.obj", process=False)
    np.testing.assert_allclose(mesh.vertices, corners.reshape(-1, 3).numpy(), atol=0)
    # triangles are CCW from outside: positive volume, watertight per box
    assert mesh.volume == pytest.approx(0.008 + 1.0, rel=1e-6)


def test_ply_round_trip(tmp_path):
    corners = boxes([[0.1, 0.2, 0.3], [1.0, 1.0, 1.0]], [[1.0, 0.5, 0.3], [0.2, 0.2, 0.2]])
    write_ply(tmp_path / "m.ply", corners, labels=[4, 7])
    mesh = trimesh.load(tmp_path / "m.ply", process=False)
    np.testing.assert_allclose(mesh.vertices, corners.reshape(-1, 3).numpy(), rtol=0, atol=1e-7)
    expect_faces = np.concatenate([sio.CUBOID_TRIANGLES.numpy(), sio.CUBOID_TRIANGLES.numpy() + 8])
    np.testing.assert_array_equal(mesh.faces, expect_faces)
    colors = mesh.visual.face_colors
    assert (colors[:12] == colors[0]).all() and (colors[12:] == colors[12]).all()
    assert not (colors[0] == colors[12]).all()


def test_glb_round_trip_one_coloured_node_per_part(tmp_path):
    corners = boxes([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], [[0.5, 0.5, 0.5]] * 3)
    write_glb(tmp_path / "m.glb", corners, labels=[0, 1, 0])
    scene = trimesh.load(tmp_path / "m.glb")
    assert isinstance(scene, trimesh.Scene) and len(scene.geometry) == 3
    dumped = {name: scene.geometry[name] for name in scene.geometry}
    for k in range(3):
        g = dumped[f"part_{k}"]
        np.testing.assert_allclose(np.sort(g.vertices, axis=0), np.sort(corners[k].numpy(), axis=0), atol=1e-6)
    col = {k: tuple(dumped[f"part_{k}"].visual.material.baseColorFactor) for k in range(3)}
    assert col[0] == col[2] != col[1]


def test_points_round_trip_with_and_without_normals(tmp_path):
    pts = torch.randn(50, 3, generator=torch.Generator().manual_seed(0))
    nrm = torch.nn.functional.normalize(torch.randn(50, 3), dim=1)
    write_points(tmp_path / "p.ply", pts, nrm)
    p, n = read_points(tmp_path / "p.ply", return_normals=True)
    assert torch.equal(p, pts) and torch.equal(n, nrm)
    write_points(tmp_path / "q.ply", pts.double())
    q, qn = read_points(tmp_path / "q.ply", return_normals=True)
    assert torch.equal(q, pts) and qn is None
    # trimesh reads it as a point cloud
    assert len(trimesh.load(tmp_path / "q.ply").vertices) == 50


def test_read_obj_point_cloud(tmp_path):
    f = tmp_path / "pc.obj"
    f.write_text("# comment\nv -0.11436325311660767 -0.017999982461333275 -0.0458947978913784 \nv 1 2 3\n\n")
    p = read_points(f)
    assert p.dtype == torch.float32 and p.shape == (2, 3)
    assert p[1].tolist() == [1.0, 2.0, 3.0]
    f.write_text("v 1 2 3\nv 1 2 oops\n")
    with pytest.raises(ValueError, match=r"pc\.obj:2: expected 'v x y z'"):
        read_points(f)
    f.write_text("f 1 2 3\n")
    with pytest.raises(ValueError, match="pc.obj: no 'v x y z' line"):
        read_points(f)
    with pytest.raises(FileNotFoundError, match="missing.obj"):
        read_points(tmp_path / "missing.obj")
    (tmp_path / "x.abc").write_text("1 2 3\n")
    with pytest.raises(ValueError, match=r"x\.abc: unsupported"):
        read_points(tmp_path / "x.abc")


def test_voxels_npy(tmp_path):
    grid = torch.zeros(3, 4, 5, dtype=torch.bool)
    grid[1, 2, 3] = True
    write_voxels(tmp_path / "v.npy", grid)
    back = np.load(tmp_path / "v.npy")
    assert back.dtype == np.bool_ and back.shape == (3, 4, 5) and back.sum() == 1 and back[1, 2, 3]
    with pytest.raises(ValueError, match="v2.npy"):
        write_voxels(tmp_path / "v2.npy", np.zeros((3, 3)))


def test_bad_input_names_the_file_and_leaves_nothing(tmp_path):
    target = tmp_path / "shape.obj"
    target.write_text("old\n")
    with pytest.raises(ValueError, match=r"shape\.obj.*\(L, 8, 3\)"):
        write_obj(target, torch.zeros(2, 4, 3))
    bad = boxes([0, 0, 0], [1, 1, 1])
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match=r"shape\.obj.*NaN"):
        write_obj(target, bad)
    with pytest.raises(ValueError, match=r"p\.ply.*\(N, 3\)"):
        write_points(tmp_path / "p.ply", torch.zeros(5, 2))
    with pytest.raises(FileNotFoundError, match="nowhere"):
        write_obj(tmp_path / "nowhere" / "a.obj", boxes([0, 0, 0], [1, 1, 1]))
    assert target.read_text() == "old\n"
    assert sorted(os.listdir(tmp_path)) == ["shape.obj"]


def test_obj_groups_are_named_by_program_line(tmp_path):
    """One ``g`` group per part, named by the 1-based program line that made it; a second part of the same
    line (a translate copy) gets ``.2``; trimesh still reads the whole mesh."""
    from shapeprog import execute

    text = ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.2, 0.2, 0.2, True)\n"
            "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.1, 0.0, 0.5)\ntranslate(cube0, X, 2, 0.5)\n")
    shape = execute(text)
    assert shape.line.tolist() == [1, 3, 3]
    out = write_obj(tmp_path / "parts.obj", shape.corners, lines=shape.line).read_text()
    groups = [ln for ln in out.splitlines() if ln.startswith("g ")]
    assert groups == ["g line_2", "g line_4", "g line_4.2"]
    body = out.splitlines()[24:]
    assert [body[13 * k] for k in range(3)] == groups and len(body) == 3 * 13
    mesh = trimesh.load(tmp_path / "parts.obj", process=False, force="mesh")
    assert mesh.faces.shape == (36, 3)


def test_executed_shape_to_trimesh():
    from shapeprog import corpus, execute

    shape = execute(corpus.read("chair", 173))
    mesh = shape.to_trimesh()
    assert isinstance(mesh, trimesh.Trimesh)
    v, f = shape.mesh()
    np.testing.assert_array_equal(mesh.vertices, v.double().numpy())
    np.testing.assert_array_equal(mesh.faces, f.numpy())
    assert mesh.face_attributes["part"].tolist() == [k for k in range(len(shape)) for _ in range(12)]
    assert mesh.metadata["lines"] == shape.line.tolist()
