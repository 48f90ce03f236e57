"""Tests of csgnet.export: PNG round trip, OBJ meshes, OpenSCAD text, atomic writes."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image

import csgnet
from csgnet import export


def test_png_round_trip(tmp_path):
    canvas = csgnet.render("c(32,32,20)s(16,48,12)+t(48,16,16)-")[0]
    path = export.save_png(canvas, tmp_path / "shape.png", scale=4)
    img = np.asarray(Image.open(path).convert("L"))
    assert img.shape == (256, 256)
    assert set(np.unique(img)) <= {0, 255}
    blocks = img.reshape(64, 4, 64, 4)
    assert (blocks == blocks[:, :1, :, :1]).all()  # nearest neighbour: constant 4x4 blocks
    assert np.array_equal(blocks[:, 0, :, 0] == 0, canvas)  # black = on
    assert os.listdir(tmp_path) == ["shape.png"]  # no temp file left


def test_png_errors(tmp_path):
    with pytest.raises(ValueError, match=r"canvas must have shape \(64, 64\), got \(2, 64, 64\)"):
        export.save_png(np.zeros((2, 64, 64), bool), tmp_path / "x.png")
    with pytest.raises(ValueError, match="scale"):
        export.save_png(np.zeros((64, 64), bool), tmp_path / "x.png", scale=0)


def test_sphere_mesh_is_watertight(tmp_path):
    import trimesh
    vol = csgnet.render("sp(32,32,32,20)", 3)[0]
    verts, faces = export.voxels_to_mesh(vol)
    # vertex coordinates are in the vol[x, y, z] frame: the sphere is centred at (32, 32, 32)
    assert np.allclose(verts.mean(axis=0), 32, atol=0.2)
    path = export.save_obj(vol, tmp_path / "sphere.obj")
    mesh = trimesh.load(path, force="mesh", process=True)
    assert mesh.is_watertight
    assert mesh.volume > 0  # outward faces
    assert mesh.volume == pytest.approx(vol.sum(), rel=0.03)


def test_border_shape_mesh_is_closed():
    import trimesh
    vol = csgnet.render("cu(4,32,60,12)", 3)[0]  # touches x = 0 and z = 63
    assert vol[0].any() and vol[:, :, 63].any()
    verts, faces = export.voxels_to_mesh(vol)
    mesh = trimesh.Trimesh(verts, faces, process=True)
    assert mesh.is_watertight
    assert verts[:, 0].min() == pytest.approx(-0.5) and verts[:, 2].max() == pytest.approx(63.5)
    assert mesh.volume == pytest.approx(vol.sum(), rel=0.05)


def test_mesh_errors():
    with pytest.raises(ValueError, match=r"vol must have shape \(64, 64, 64\), got \(64, 64\)"):
        export.voxels_to_mesh(np.zeros((64, 64), bool))
    v, f = export.voxels_to_mesh(np.zeros((64, 64, 64), bool))
    assert v.shape == (0, 3) and f.shape == (0, 3)


def _strip(text):
    return [line.split("//")[0].strip() for line in text.splitlines() if line.split("//")[0].strip()]


def test_scad_2d_structure():
    text = export.to_scad(csgnet.parse("c(32,32,16)s(32,32,12)-t(16,16,8)+"))
    lines = _strip(text)
    assert lines[:3] == ["mirror([0, 1, 0]) {", "intersection() {", "union() {"]
    assert lines[3] == "difference() {"
    # difference: the circle (earlier) minus the square (later), in that order
    assert lines[4] == "translate([32, 32]) circle(r = 16, $fn = 128);"
    # square s(32,32,12): rows/columns 23..40 inclusive (spec table) -> [22.5, 40.5], 18 pixels wide
    assert lines[5] == "translate([22.5, 22.5]) square([18, 18]);"
    assert lines[6] == "}"
    # triangle t(16,16,8): vertices from csgnet.primitives.triangle_vertices, x = column, y = row
    assert lines[7] == "polygon([[9, 20], [22, 20], [16, 8]]);"
    assert "rows grow downward" in text


def test_scad_square_matches_raster():
    for x, y, r in [(32, 32, 8), (20, 40, 28), (40, 12, 16)]:
        img = csgnet.render(f"s({x},{y},{r})")[0]
        line = _strip(export.to_scad(f"s({x},{y},{r})"))[2]
        tx, ty, w, h = map(float, re.findall(r"-?\d+(?:\.\d+)?", line))
        rows, cols = np.nonzero(img)
        # the SCAD rectangle is exactly the union of the raster's pixel squares
        assert (tx, ty) == (cols.min() - 0.5, rows.min() - 0.5)
        assert (tx + w, ty + h) == (cols.max() + 0.5, rows.max() + 0.5)
        assert w * h == img.sum()


def test_scad_3d():
    text = export.to_scad(csgnet.parse("cu(32,32,32,16)sp(32,32,32,12)-cy(16,16,16,8,12)*", 3))
    lines = _strip(text)
    assert lines[:3] == ["intersection() {", "intersection() {", "difference() {"]
    assert lines[3] == "translate([24.5, 24.5, 24.5]) cube(15);"  # q = 7: 17..47 voxel centres
    assert lines[4] == "translate([32, 32, 32]) sphere(r = 11, $fn = 128);"
    assert lines[6] == "translate([16, 16, 10.5]) cylinder(r = 7, h = 11, $fn = 128);"


def test_scad_errors():
    with pytest.raises(ValueError, match="stack"):
        export.to_scad(csgnet.parse("c(32,32,8)c(10,10,8)", strict=False))


def test_atomic_write_leaves_no_temp_files(tmp_path, monkeypatch):
    p = csgnet.parse("c(32,32,16)s(32,32,12)-")
    path = export.save_scad(p, tmp_path / "prog.scad")
    assert path.read_text() == export.to_scad(p)
    export.save_scad(p, tmp_path / "prog.scad")  # overwrite
    assert sorted(os.listdir(tmp_path)) == ["prog.scad"]
    # a write that fails at the final rename leaves the old file and no temp file
    import shapeio.files as shapeio

    def boom(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(shapeio.os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        export.save_scad(csgnet.parse("c(8,8,8)"), tmp_path / "prog.scad")
    assert sorted(os.listdir(tmp_path)) == ["prog.scad"]
    assert (tmp_path / "prog.scad").read_text() == export.to_scad(p)


@pytest.mark.skipif(shutil.which("openscad") is None, reason="openscad not installed")
def test_openscad_accepts_output(tmp_path):
    for text in ["s(32,32,20)c(20,20,12)+", "c(32,32,24)s(32,32,16)-"]:
        src = export.save_scad(csgnet.parse(text), tmp_path / "p.scad")
        out = tmp_path / "p.svg"
        subprocess.run(["openscad", "-o", str(out), str(src)], check=True, capture_output=True)
        assert out.stat().st_size > 0
