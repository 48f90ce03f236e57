"""Tests of shapeio.mesh: the one mesh writer (OBJ, PLY, GLB) and reading users' meshes."""
import numpy as np
import pytest

from shapeio import InputError
from shapeio.mesh import load_mesh, obj_text, read_mesh, write_mesh, write_parts

import trimesh  # noqa: E402  (a core dependency)

# a unit tetrahedron, faces outward
VERTS = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_obj_text_layout():
    text = obj_text(VERTS[:3] + 0.1, FACES[:1], comment="hello", digits=3)
    assert text == "# hello\nv 0.1 0.1 0.1\nv 1.1 0.1 0.1\nv 0.1 1.1 0.1\nf 1 3 2\n"
    exact = obj_text(np.float32([[0.1, 0, 0], [1, 0, 0], [0, 1, 0]]), FACES[:1])
    assert exact.splitlines()[0] == "v 0.10000000149011612 0.0 0.0"  # float32 as the double it is


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb"])
def test_round_trip_through_trimesh(tmp_path, suffix):
    path = write_mesh(tmp_path / f"t{suffix}", VERTS, FACES)
    mesh = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_allclose(mesh.vertices, VERTS, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, FACES)
    assert mesh.volume == pytest.approx(1 / 6)
    v, f = read_mesh(path)
    assert v.dtype == np.float64 and f.dtype == np.int64 and len(f) == 4


def test_colours(tmp_path):
    fc = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]], np.uint8)
    mesh = trimesh.load(write_mesh(tmp_path / "c.ply", VERTS, FACES, face_colors=fc), process=False)
    np.testing.assert_array_equal(mesh.visual.face_colors[:, :3], fc)
    vc = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 1.0]])
    text = write_mesh(tmp_path / "c.obj", VERTS, FACES, vertex_colors=vc).read_text()
    assert text.splitlines()[0] == "v 0.0 0.0 0.0 1 0 0"
    back = trimesh.load(tmp_path / "c.obj", process=False)
    np.testing.assert_array_equal(back.visual.vertex_colors[:, :3], (vc * 255).astype(np.uint8))
    glb = write_mesh(tmp_path / "c.glb", VERTS, FACES, vertex_colors=vc)
    np.testing.assert_array_equal(trimesh.load(glb, force="mesh").visual.vertex_colors[:, :3],
                                  (vc * 255).astype(np.uint8))


def test_parts_scene(tmp_path):
    parts = [(VERTS, FACES, np.array([255, 0, 0], np.uint8)), (VERTS + 2, FACES, np.array([0, 0, 255], np.uint8))]
    scene = trimesh.load(write_parts(tmp_path / "p.glb", parts, names=["a", "b"]))
    assert sorted(scene.geometry) == ["a", "b"]
    assert tuple(scene.geometry["b"].visual.material.baseColorFactor) == (0, 0, 255, 255)


def test_bad_input_names_the_file(tmp_path):
    with pytest.raises(ValueError, match=r"m\.obj: `vertices` must be \(V, 3\)"):
        write_mesh(tmp_path / "m.obj", VERTS[:, :2], FACES)
    with pytest.raises(ValueError, match=r"m\.obj: `faces` index vertices 0\.\.3, got 1\.\.4"):
        write_mesh(tmp_path / "m.obj", VERTS, FACES + 1)
    with pytest.raises(ValueError, match=r"m\.obj: OBJ files hold no per-face colours"):
        write_mesh(tmp_path / "m.obj", VERTS, FACES, face_colors=np.zeros((4, 3), np.uint8))
    with pytest.raises(ValueError, match=r"m\.stl: unknown mesh format 'stl'"):
        write_mesh(tmp_path / "m.stl", VERTS, FACES)
    with pytest.raises(ValueError, match=r"m\.ply: `face_colors` must be \(4, 3\) or \(4, 4\)"):
        write_mesh(tmp_path / "m.ply", VERTS, FACES, face_colors=np.zeros((3, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "bad.stl").write_text("solid nonsense\nfacet garbage\n")
    with pytest.raises(InputError, match=r"bad\.stl"):
        load_mesh(tmp_path / "bad.stl")
    (tmp_path / "pts.obj").write_text("v 0 0 0\nv 1 0 0\n")
    with pytest.raises(InputError, match=r"pts\.obj: the file holds no triangles"):
        load_mesh(tmp_path / "pts.obj")
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n")  # a 'v' line with two numbers
    with pytest.raises(InputError, match=r"flat\.obj: the vertices are not 3D points"):
        load_mesh(tmp_path / "flat.obj")
    with pytest.raises(FileNotFoundError, match=r"none\.obj: no such file"):
        load_mesh(tmp_path / "none.obj")
