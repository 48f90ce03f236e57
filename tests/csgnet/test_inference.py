"""Inference on users' shapes: input loading, weights, infer, the parse and evaluate commands."""
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import csgnet
from csgnet.inference import InputError, fit_to_canvas, infer, load_pretrained, load_shape
from csgnet.models import CSGNet, preset

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def tiny(dim=2, stack=False):
    torch.manual_seed(0)
    extra = dict(channels=(2, 2, 2), input_pool=4) if dim == 3 else dict(channels=(2, 2, 2))
    return CSGNet(preset("small", dim, stack, hidden=16, embed=8, dropout=0.0, enc_dropout=0.0, **extra)).eval()


def test_fit_to_canvas_keeps_aspect_and_centres():
    m = np.zeros((100, 300), bool)
    m[40:60, 50:250] = True  # 20 x 200
    out = fit_to_canvas(m)
    rows, cols = np.nonzero(out)
    assert cols.max() - cols.min() + 1 == 56  # the longest side spans 64 - 2 * 4
    assert rows.max() - rows.min() + 1 in (5, 6)  # 20 * 56 / 200 = 5.6
    assert abs((cols.min() + cols.max()) / 2 - 31.5) <= 0.5 and abs((rows.min() + rows.max()) / 2 - 31.5) <= 1
    same = np.zeros((64, 64), bool)
    same[3:9, 50:60] = True
    assert np.array_equal(fit_to_canvas(same), same)


def test_a_64_pixel_png_round_trips_exactly(tmp_path):
    img = csgnet.render("c(32,32,16)s(24,40,12)+")[0]
    Image.fromarray(np.where(img, 0, 255).astype(np.uint8)).save(tmp_path / "a.png")  # dark on light
    assert np.array_equal(load_shape(tmp_path / "a.png"), img)
    Image.fromarray(np.where(img, 255, 0).astype(np.uint8)).save(tmp_path / "b.png")  # light on dark
    assert np.array_equal(load_shape(tmp_path / "b.png"), img)
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[..., 3] = np.where(img, 255, 0)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "c.png")  # transparency marks the shape
    assert np.array_equal(load_shape(tmp_path / "c.png"), img)


def test_bad_inputs_get_clear_errors(tmp_path):
    Image.new("L", (80, 80), 200).save(tmp_path / "blank.png")
    with pytest.raises(InputError, match="blank.png.*single colour"):
        load_shape(tmp_path / "blank.png")
    (tmp_path / "broken.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="broken.png.*cannot read"):
        load_shape(tmp_path / "broken.png")
    with pytest.raises(InputError, match="no such file"):
        load_shape(tmp_path / "missing.png")
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(InputError, match="unknown file type"):
        load_shape(tmp_path / "x.txt")
    np.save(tmp_path / "z.npy", np.zeros((64, 64, 64)))
    with pytest.raises(InputError, match="empty"):
        load_shape(tmp_path / "z.npy")
    np.save(tmp_path / "w.npy", np.ones((2, 2, 2, 2)))
    with pytest.raises(InputError, match="shape"):
        load_shape(tmp_path / "w.npy")


def test_meshes_are_voxelised_and_flat_ones_refused(tmp_path):
    import trimesh

    trimesh.creation.box([2.0, 1.0, 1.0]).export(tmp_path / "box.stl")
    vol = load_shape(tmp_path / "box.stl")
    assert vol.shape == (64, 64, 64)
    xs, ys, zs = (np.nonzero(vol.any(axis=a)) for a in ((1, 2), (0, 2), (0, 1)))
    ext = [len(xs[0]), len(ys[0]), len(zs[0])]
    assert ext[0] in (56, 57) and abs(ext[1] - ext[0] / 2) <= 2 and abs(ext[2] - ext[0] / 2) <= 2
    assert vol.sum() >= 0.9 * ext[0] * ext[1] * ext[2]  # filled, not a shell
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    flat.export(tmp_path / "flat.obj")
    with pytest.raises(InputError, match="no (volume|triangles)"):
        load_shape(tmp_path / "flat.obj")
    (tmp_path / "bad.stl").write_text("solid nonsense\nfacet garbage\n")
    with pytest.raises(InputError, match="bad.stl"):
        load_shape(tmp_path / "bad.stl")


def test_npy_volume_passes_through(tmp_path):
    vol = csgnet.render("cu(32,32,32,20)", 3)[0]
    np.save(tmp_path / "v.npy", vol)
    assert np.array_equal(load_shape(tmp_path / "v.npy"), vol)


@pytest.mark.parametrize("stack", [False, True])
def test_infer_returns_scored_programs(stack):
    m = tiny(2, stack)
    shapes = csgnet.render(["c(32,32,16)", "s(32,32,20)"])
    res = infer(m, shapes, beam=3)
    assert len(res) == 2
    for r, s in zip(res, shapes):
        assert r.valid and csgnet.is_valid(r.program) and r.beams[0] == r.text
        pred = csgnet.render(r.text)[0]
        assert r.iou == pytest.approx(csgnet.metrics.iou(pred, s))
        assert r.chamfer == pytest.approx(csgnet.metrics.chamfer(pred, s))
    match = infer(m, shapes, beam=3, select="match")
    for r, s in zip(match, shapes):
        cds = [csgnet.metrics.chamfer(csgnet.render(b)[0], s) for b in r.beams]
        assert r.chamfer == pytest.approx(min(cds))
    with pytest.raises(ValueError, match="shapes"):
        infer(m, np.zeros((1, 32, 32), bool))


def test_infer_3d():
    m = tiny(3)
    shape = csgnet.render(["sp(32,32,32,16)"], 3)[0]
    res = infer(m, shape, beam=2)
    assert len(res) == 1 and np.isnan(res[0].chamfer) and len(res[0].beams) == 2
    r = res[0]
    assert r.valid  # grammar-constrained decoding by default
    pred = csgnet.render(r.text, 3)[0]
    assert r.iou == pytest.approx(float(csgnet.metrics.iou_3d(pred, shape)))  # |A∧B| / (|A∨B| + 1)


@pytest.mark.parametrize("dim", [2, 3])
def test_shipped_weights_load(dim):
    m = load_pretrained(dim)
    assert m.config.dim == dim and not m.training
    path = csgnet.inference.WEIGHTS / csgnet.inference.PRETRAINED[dim]
    assert path.stat().st_size < 8 * 2**20


def test_parse_cli_on_shipped_examples(tmp_path, capsys):
    from csgnet.__main__ import main

    rc = main(["parse", str(EXAMPLES / "house.png"), str(EXAMPLES / "table.obj"), "--beam", "3",
               "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "house.png:" in out and "IoU" in out and "chamfer" in out
    for name in ("house.png", "house.txt", "table.obj", "table.txt"):
        assert (tmp_path / name).is_file(), name
    text = (tmp_path / "house.txt").read_text().strip()
    assert csgnet.is_valid(csgnet.parse(text))


def test_parse_cli_reports_bad_input(tmp_path, capsys):
    from csgnet.__main__ import main

    (tmp_path / "bad.png").write_bytes(b"xx")
    assert main(["parse", str(tmp_path / "bad.png"), "--out", str(tmp_path)]) == 2
    assert "bad.png" in capsys.readouterr().err


def _corrupt_files(tmp_path):
    """One file per kind of corrupt input seen in the field, with the text its error must carry."""
    import zlib

    good = tmp_path / "good.png"
    Image.new("L", (40, 40), 0).save(good)
    data = good.read_bytes()
    files = {"truncated.png": (data[: len(data) // 2], "truncated.png: not a readable PNG image"),
             "badchunk.png": (data[:8] + b"\x00\x00\x00\x0dIHDX" + data[16:], "badchunk.png: not a readable"),
             "header.npy": (b"\x93NUMPY\x01\x00\x10\x00{'descr': '<f8'   \n", "header.npy: not a readable .npy"),
             "short.npy": (b"\x93NUMPY", "short.npy: not a readable .npy")}
    # a 20000 x 20000 PNG header over a tiny compressed body: refused before decoding
    ihdr = b"IHDR" + (20000).to_bytes(4, "big") * 2 + bytes([1, 0, 0, 0, 0])
    idat = b"IDAT" + zlib.compress(b"\x00" * 64)

    def chunk(body):
        return (len(body) - 4).to_bytes(4, "big") + body + zlib.crc32(body).to_bytes(4, "big")

    bomb = b"\x89PNG\r\n\x1a\n" + chunk(ihdr) + chunk(idat) + chunk(b"IEND")
    files["bomb.png"] = (bomb, "bomb.png: the image is")
    for name, (content, _) in files.items():
        (tmp_path / name).write_bytes(content)
    return {name: msg for name, (_, msg) in files.items()}


def test_defect5_corrupt_images_and_arrays_are_input_errors(tmp_path):
    for name, message in _corrupt_files(tmp_path).items():
        with pytest.raises(InputError) as e:
            load_shape(tmp_path / name)
        assert message in str(e.value), (name, str(e.value))


@pytest.mark.parametrize("array, message", [
    (np.full((8, 8), np.nan), "NaN or infinite"),
    (np.ones((8, 8)), "every cell is non-zero"),
    (np.ones((8, 8), dtype=np.complex64), "complex64 values"),
    (np.array([["a", "b"], ["c", "d"]]), "<U1 values"),
    (np.zeros((300, 300, 300), dtype=bool), "at most MAX_GRID_CELLS"),
])
def test_defect5_degenerate_npy_inputs_are_refused(tmp_path, array, message):
    np.save(tmp_path / "a.npy", array)
    with pytest.raises(InputError, match=re.escape(message)):
        load_shape(tmp_path / "a.npy")


def test_defect5_mesh_with_a_nan_vertex_is_refused(tmp_path):
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 nan\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    with pytest.raises(InputError, match=r"nan\.obj: vertex 4 has a NaN"):
        load_shape(tmp_path / "nan.obj")


def test_defect5_a_bad_file_in_a_batch_is_reported_and_the_rest_parsed(tmp_path, capsys):
    from csgnet.__main__ import main

    names = sorted(_corrupt_files(tmp_path))
    rc = main(["parse", *(str(tmp_path / n) for n in names), str(EXAMPLES / "house.png"), "--beam", "1",
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2
    for n in names:
        assert f"error: {tmp_path / n}: " in err
    assert (tmp_path / "out" / "house.txt").is_file()


@pytest.mark.parametrize("beam", [0, -5, 100000, 2.5, True])
def test_defect9_beam_width_is_checked(beam):
    model = CSGNet(preset("small", 2, False))
    with pytest.raises(ValueError, match="beam must be an integer from 1 to 256"):
        infer(model, np.zeros((64, 64), bool), beam=beam)


def test_parse_shape_is_the_clis_parse_in_one_call(tmp_path):
    from csgnet.__main__ import main
    from csgnet.inference import Parsed, load_pretrained, parse_shape
    examples = Path(__file__).resolve().parents[2] / "examples"
    assert main(["parse", str(examples / "house.png"), str(examples / "snowman.stl"), "--beam", "4",
                 "--select", "match", "--refine", "--out", str(tmp_path)]) == 0
    for name in ("house.png", "snowman.stl"):
        got = csgnet.parse_shape(examples / name, beam=4)
        assert isinstance(got, Parsed) and got.text == (tmp_path / f"{Path(name).stem}.txt").read_text().strip()
        assert got.refined.after[0] >= got.decoded.iou - 0.025 * 8  # the short rule trades at most its price
    mesh = csgnet.parse_shape(examples / "snowman.stl", beam=2, refine=False)
    assert mesh.frame is not None and mesh.refined is None and mesh.program == mesh.decoded.program
    image = csgnet.render("c(32,32,20)")[0]
    got = parse_shape(image, model=load_pretrained(2, kind="csgnet"), beam=2)
    assert got.frame is None and got.shape.shape == (64, 64)
    with pytest.raises(ValueError, match="3D model cannot parse a 2D shape"):
        parse_shape(image, model=load_pretrained(3))
    with pytest.raises(ValueError, match=r"\(64, 64\) image or a \(64, 64, 64\) volume"):
        parse_shape(np.ones((3, 3), bool))


def test_parse_of_a_shape_file_name_says_which_call_reads_shapes():
    with pytest.raises(csgnet.ParseError, match=r"csgnet.parse_shape\('house.png'\)"):
        csgnet.parse("house.png")
    with pytest.raises(csgnet.ParseError, match="shape file"):
        csgnet.parse("chair.STL", dim=3)
    assert csgnet.parse("c(32,32,8)").text() == "c(32,32,8)"
