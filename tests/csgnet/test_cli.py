import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from csgnet.__main__ import main


def test_render_png_scad_npy(tmp_path):
    out = [tmp_path / "a.png", tmp_path / "a.scad", tmp_path / "a.npy"]
    assert main(["render", "c(32,32,28)s(32,32,20)-", *sum((["-o", str(p)] for p in out), [])]) == 0
    assert all(p.exists() and p.stat().st_size > 0 for p in out)
    import csgnet

    assert (np.load(out[2]) == csgnet.render("c(32,32,28)s(32,32,20)-")[0]).all()
    assert "difference()" in out[1].read_text()


def test_render_3d_obj(tmp_path):
    assert main(["render", "sp(32,32,32,20)cu(32,32,32,28)*", "-o", str(tmp_path / "a.obj")]) == 0
    text = (tmp_path / "a.obj").read_text()
    assert text.count("\nv ") > 100 and "\nf " in text


def test_render_bad_program_is_a_clear_error(tmp_path, capsys):
    assert main(["render", "c(32,32,28)q(1,2,3)-", "-o", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err
    assert "unknown 2D primitive 'q'" in err and "at character 11" in err
    assert not (tmp_path / "a.png").exists()


def test_demo_refuses_an_earlier_demo_folder(tmp_path):
    (tmp_path / "preview_2d").mkdir()
    with pytest.raises(SystemExit, match=r"preview_2d exists \(an earlier demo's output\)"):
        main(["demo", "--out", str(tmp_path), "--quiet"])
    assert [p.name for p in tmp_path.iterdir()] == ["preview_2d"]


def test_demo_main_job(tmp_path):
    r = subprocess.run([sys.executable, "-m", "csgnet", "demo", "--out", str(tmp_path), "--quiet", "--workers", "1",
                        "--per-length", "1"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "preview_2d.png").exists() and (tmp_path / "preview_3d.png").exists()
    rows = (tmp_path / "preview_2d" / "programs.tsv").read_text().strip().splitlines()[1:]
    import csgnet

    for row in rows:
        name, text, on = row.split("\t")
        assert int(csgnet.render(text)[0].sum()) == int(on)


def test_parse_refuses_to_write_over_its_input(tmp_path, capsys):
    src = tmp_path / "shape.png"
    assert main(["render", "c(32,32,20)", "-o", str(src)]) == 0
    before = src.read_bytes()
    assert main(["parse", str(src), "--out", str(tmp_path)]) == 2
    assert "shape.png: this output would overwrite an input file" in capsys.readouterr().err
    assert src.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["shape.png"]


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_defect2_same_named_inputs_get_distinct_outputs(tmp_path, capsys):
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        assert main(["render", "c(32,32,20)" if sub == "a" else "s(32,32,20)", "-o", str(tmp_path / sub / "x.png")]) == 0
    (tmp_path / "x_2.npy").write_bytes((tmp_path / "a" / "x.png").read_bytes())  # a bad input named like an output
    out = tmp_path / "out"
    rc = main(["parse", str(tmp_path / "a" / "x.png"), str(tmp_path / "b" / "x.png"), str(tmp_path / "x_2.npy"),
               "--beam", "1", "--out", str(out)])
    assert rc == 2  # x_2.npy is not an array
    names = sorted(p.name for p in out.iterdir())
    assert {"x.txt", "x_3.txt", "x.png", "x_3.png"} <= set(names) and "x_2.txt" not in names


def test_defect2_obj_input_in_the_output_folder_is_protected(tmp_path, capsys):
    src = tmp_path / "table.obj"
    src.write_bytes((EXAMPLES / "table.obj").read_bytes())
    before = src.read_bytes()
    assert main(["parse", str(src), "--out", str(tmp_path)]) == 2
    assert "table.obj: this output would overwrite an input file" in capsys.readouterr().err
    assert src.read_bytes() == before


@pytest.mark.parametrize("option", [["--beam", "0"], ["--beam", "-5"], ["--beam", "100000"],
                                    ["--refine-iters", "-1"]])
def test_defect9_bad_numeric_options_are_refused(tmp_path, option, capsys):
    with pytest.raises(SystemExit) as e:
        main(["parse", str(EXAMPLES / "house.png"), *option, "--out", str(tmp_path)])
    assert e.value.code == 2 and "must be an integer" in capsys.readouterr().err


def test_defect10_render_into_a_missing_folder_is_an_error(tmp_path, capsys):
    assert main(["render", "c(32,32,20)", "-o", str(tmp_path / "no" / "a.png")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_defect10_3d_weights_given_as_weights_2d(tmp_path, capsys):
    from csgnet.inference import PRETRAINED, WEIGHTS

    rc = main(["parse", str(EXAMPLES / "house.png"), "--weights-2d", str(WEIGHTS / PRETRAINED[3]),
               "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2 and "a 3D model, given for 2D inputs (--weights-2d)" in err and "Traceback" not in err


def test_defect10_export_weights_on_a_foreign_file(tmp_path, capsys):
    import pickle

    (tmp_path / "x.ckpt").write_bytes(pickle.dumps({"a": object}, protocol=2))
    assert main(["export-weights", str(tmp_path / "x.ckpt"), "--out", str(tmp_path / "w.pt")]) == 2
    err = capsys.readouterr().err
    assert "not a Lightning training checkpoint" in err and "weights_only" not in err


def test_defect10_parse_into_a_closed_pipe_ends_quietly(tmp_path):
    cmd = (f"{sys.executable} -m csgnet parse {EXAMPLES / 'house.png'} {EXAMPLES / 'ring.png'} --beam 1 "
           f"--out {tmp_path} | head -c 1")
    r = subprocess.run(["bash", "-c", f"set -o pipefail; {cmd}"], capture_output=True, text=True, timeout=300)
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr


def test_defect6_parse_refine_reports_the_program_it_writes(tmp_path, capsys):
    import csgnet
    from csgnet.score import program_scores

    assert main(["parse", str(EXAMPLES / "house.png"), "--beam", "3", "--refine", "--refine-iters", "1",
                 "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    written = csgnet.parse((tmp_path / "house.txt").read_text().strip())
    from csgnet.inference import load_shape

    (i1, c1), = program_scores([written], load_shape(EXAMPLES / "house.png"))
    assert f"after: IoU {100 * i1:.2f}%, chamfer {c1:.3f} px" in out and "before: IoU" in out


def test_parse_refine_refines_a_mesh_by_iou(tmp_path, capsys):
    import re

    import csgnet
    from csgnet.inference import load_shape
    from csgnet.score import program_scores

    assert main(["parse", str(EXAMPLES / "table.obj"), "--beam", "3", "--refine", "--refine-iters", "1",
                 "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "refined (3 beams, by IoU; chosen by IoU - 0.01 per primitive)" in out and "skipped" not in out
    before, after = (float(v) for v in re.search(r"before: IoU ([\d.]+)%, \d+ primitives; after: IoU ([\d.]+)%", out).groups())
    assert after >= before
    written = csgnet.parse((tmp_path / "table.txt").read_text().strip(), dim=3)
    (iou, _), = program_scores([written], load_shape(EXAMPLES / "table.obj"))
    assert f"after: IoU {100 * iou:.2f}%" in out
    assert (tmp_path / "table.obj").exists() and (tmp_path / "table.scad").exists()
    # the comparison sheet: depth views along x, y, z of the input (top row) and of the written program
    # (bottom row), 64 px + 2 px frame each, scaled x3, below a band of column labels and right of one of
    # row labels ("input", "program")
    import numpy as np
    from PIL import Image

    from csgnet.export import LABEL_BAND, depth_view

    page = np.asarray(Image.open(tmp_path / "table_compare.png").convert("L"))
    left = (LABEL_BAND // 2) * (len("program") + 1)
    assert page.shape == (LABEL_BAND + 2 * 66 * 3, left + 3 * 66 * 3)
    assert (page[:LABEL_BAND, left:] < 128).any() and (page[LABEL_BAND:, :left] < 128).any()  # the labels
    sheet = page[LABEL_BAND:, left:]
    vol = csgnet.render(written, dim=3)[0]
    bottom_z = sheet[66 * 3 + 3::3, 2 * 66 * 3 + 3::3][:64, :64]  # the result's view along z, unscaled
    assert np.array_equal(bottom_z, depth_view(vol, 2))


def test_depth_view_shades_the_first_voxel_along_the_axis():
    import numpy as np

    from csgnet.export import depth_view

    vol = np.zeros((64, 64, 64), bool)
    vol[10, 20, 0] = vol[10, 20, 63] = True  # the near voxel hides the far one
    vol[5, 6, 63] = True
    view = depth_view(vol, 2)
    assert view[10, 20] == 30 and view[5, 6] == 200 and view[0, 0] == 255 and view.dtype == np.uint8
    assert (view < 255).sum() == 2


def test_generate_never_replaces_a_dataset(tmp_path, capsys):
    args = ["generate", "--dim", "2", "--scale", "0.0002", "--lengths", "3", "--out", str(tmp_path), "--quiet"]
    assert main(args) == 0
    meta = (tmp_path / "2d" / "meta.json").read_bytes()
    with pytest.raises(SystemExit, match=r"2d holds a dataset already; generate never replaces one"):
        main(args + ["--seed", "1"])
    assert (tmp_path / "2d" / "meta.json").read_bytes() == meta
    assert main(["generate", "--dim", "3", "--scale", "0.0002", "--lengths", "3", "--out", str(tmp_path), "--quiet"]) == 0


def test_a_table_is_never_written_over_its_weights(tmp_path):
    from csgnet.inference import WEIGHTS

    weights = tmp_path / "w.pt"
    weights.write_bytes((WEIGHTS / "csgnet2d.pt").read_bytes())
    before = weights.read_bytes()
    for argv in (["table6", "--weights", str(weights), "--per-length", "1", "--out", str(weights)],
                 ["table4", "--weights", f"mine={weights}", "--images", "1", "--out", str(weights)],
                 ["evaluate", "--dim", "2", "--data", str(tmp_path), "--weights", str(weights), "--out", str(weights)]):
        with pytest.raises(SystemExit, match=r"w\.pt"):  # an input is never replaced, even with --overwrite
            main([*argv, "--overwrite"])
    assert weights.read_bytes() == before


def test_existing_outputs_are_refused_without_overwrite(tmp_path, capsys):
    table, picture = tmp_path / "t.json", tmp_path / "p.png"
    table.write_text("mine")
    picture.write_bytes(b"mine")
    assert main(["evaluate", "--dim", "2", "--data", str(tmp_path), "--out", str(table)]) == 2
    assert main(["render", "c(32,32,20)", "-o", str(picture)]) == 2
    err = capsys.readouterr().err
    assert err.count("exists (1 of the outputs does); give --overwrite") == 2 and str(table) in err and str(picture) in err
    assert table.read_text() == "mine" and picture.read_bytes() == b"mine"
    assert main(["render", "c(32,32,20)", "--out", str(picture), "--overwrite"]) == 0
    assert picture.read_bytes().startswith(b"\x89PNG")
    # a second parse into the same folder: its per-shape files are refused, then replaced with --overwrite
    out = tmp_path / "parsed"
    assert main(["parse", str(picture), "--beam", "1", "--out", str(out)]) == 0
    program = (out / "p.txt").read_text()
    (out / "p.txt").write_text("mine")
    capsys.readouterr()
    assert main(["parse", str(picture), "--beam", "1", "--out", str(out)]) == 2
    assert "exists (" in capsys.readouterr().err and (out / "p.txt").read_text() == "mine"
    assert main(["parse", str(picture), "--beam", "1", "--out", str(out), "--overwrite"]) == 0
    assert (out / "p.txt").read_text() == program


def test_every_command_shows_an_example_that_parses():
    from csgnet.__main__ import EXAMPLES, build_parser

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert set(EXAMPLES) == set(commands) - {"paper"}
    for name, p in commands.items():
        assert "example:" in (p.epilog or ""), name
        if name in EXAMPLES:
            args = parser.parse_args([name, *shlex.split(EXAMPLES[name])])
            assert args.cmd == name


def test_parse_of_a_dotted_name_writes_its_own_names(tmp_path, capsys):
    src = tmp_path / "in" / "a.v1.png"
    src.parent.mkdir()
    assert main(["render", "c(32,32,20)", "-o", str(src)]) == 0
    out = tmp_path / "out"
    out.mkdir()
    (out / "a.png").write_bytes(b"another shape's picture")
    assert main(["parse", str(src), "--beam", "1", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["a.png", "a.v1.png", "a.v1.scad", "a.v1.txt", "a.v1_compare.png",
                                                     "results.json"]
    assert (out / "a.png").read_bytes() == b"another shape's picture"


def test_parse_writes_a_results_file_per_batch_and_never_over_one(tmp_path, capsys):
    import json

    src = tmp_path / "in"
    src.mkdir()
    assert main(["render", "c(32,32,28)c(32,32,12)-", "-o", str(src / "ring.npy")]) == 0
    (src / "bad.png").write_bytes(b"not a picture")
    out = tmp_path / "out"
    assert main(["parse", str(src / "ring.npy"), str(src / "bad.png"), "--beam", "3", "--refine",
                 "--out", str(out)]) == 2
    text = capsys.readouterr().out
    records = json.loads((out / "results.json").read_text())["rows"]
    assert [r["input"] for r in records] == [str(src / "ring.npy"), str(src / "bad.png")]
    ring, bad = records
    assert ring["decoded"] == "c(32,32,28)c(32,32,12)-" and ring["primitives"] == 2 and ring["iou"] == 1.0
    assert ring["refined"] == "c(32,32,28)c(32,32,12)-" and ring["primitives_refined"] == 2 and ring["rule"] == "short"
    assert (out / "ring.txt").read_text().strip() == ring["refined"]
    assert bad["error"].startswith(str(src / "bad.png"))
    assert "2 primitives; after: IoU 100.00%, chamfer 0.000 px, 2 primitives" in text
    (out / "other").mkdir()
    assert main(["render", "c(20,20,8)", "-o", str(src / "dot.png")]) == 0
    assert main(["parse", str(src / "dot.png"), "--beam", "1", "--out", str(out)]) == 0
    assert json.loads((out / "results_2.json").read_text())["rows"][0]["input"] == str(src / "dot.png")
    assert len(json.loads((out / "results.json").read_text())["rows"]) == 2  # the first batch's file is untouched
    from shapeio.results import markdown, read_result
    table = markdown(read_result(out / "results.json"))  # a result file: the docs can show it as a table
    assert "| input | decoded program | IoU (%) |" in table and "python -m csgnet parse" in table


def test_parse_reports_a_bad_weights_file_once_before_any_input(tmp_path, capsys):
    src = tmp_path / "c.png"
    assert main(["render", "c(32,32,20)", "-o", str(src)]) == 0
    capsys.readouterr()
    assert main(["parse", str(src), str(src), "--weights-2d", str(tmp_path / "none.pt"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("none.pt") == 1 and not (tmp_path / "o").exists()


def test_parse_uses_the_named_shipped_model(tmp_path, capsys):
    from csgnet.inference import SHIPPED, WEIGHTS
    texts = {}
    for name, opts in [("default", []), ("stack", ["--model", "csgnetstack"]), ("csgnet", ["--model", "csgnet"]),
                       ("stack_file", ["--weights-2d", str(WEIGHTS / SHIPPED[(2, "csgnetstack", "supervised")])]),
                       ("csgnet_file", ["--weights-2d", str(WEIGHTS / SHIPPED[(2, "csgnet", "supervised")])])]:
        assert main(["parse", str(EXAMPLES / "house.png"), "--beam", "2", *opts, "--out", str(tmp_path / name)]) == 0
        texts[name] = (tmp_path / name / "house.txt").read_text()
    assert texts["default"] == texts["stack"] == texts["stack_file"] != texts["csgnet"] == texts["csgnet_file"]
    with pytest.raises(SystemExit):
        main(["parse", str(EXAMPLES / "house.png"), "--model", "paper"])


def test_parse_writes_a_meshs_outputs_in_its_own_units(tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    box.apply_translation((100.0, -5.0, 3.0))
    src = tmp_path / "box.stl"
    box.export(src)
    out = tmp_path / "out"
    assert main(["parse", str(src), "--beam", "3", "--refine", "--out", str(out)]) == 0
    written = trimesh.load(out / "box.obj", force="mesh")
    pitch = 2.0 / 55
    # the parsed program covers most of the box: its mesh lies over the input, not in the 64-voxel frame
    assert np.all(np.abs(written.bounds - box.bounds) < 8 * pitch), (written.bounds, box.bounds)
    scad = (out / "box.scad").read_text()
    assert "multmatrix([[" in scad and "voxel coordinates to the input's units" in scad


def test_framed_mesh_loading_maps_voxel_centres_onto_the_mesh():
    import tempfile

    import trimesh

    from csgnet.inference import load_shape, load_shape_framed
    for extents, shift in [((2.0, 1.0, 0.5), (100.0, -5.0, 3.0)), ((0.003, 0.001, 0.002), (0.0, 0.0, 0.0)),
                           ((1.0, 3.0, 2.0), (-7.0, 0.5, 1e3))]:
        box = trimesh.creation.box(extents=extents)
        box.apply_translation(shift)
        with tempfile.TemporaryDirectory() as d:
            path = f"{d}/b.ply"
            box.export(path)
            vol, frame = load_shape_framed(path)
            assert np.array_equal(vol, load_shape(path))
        pitch = max(extents) / 55
        centres = np.argwhere(vol) @ frame[:3, :3].T + frame[:3, 3]
        assert np.all(np.abs(centres.min(0) - box.bounds[0]) <= pitch)
        assert np.all(np.abs(centres.max(0) - box.bounds[1]) <= pitch)
    vol, frame = load_shape_framed(EXAMPLES / "house.png")
    assert frame is None and vol.shape == (64, 64)


@pytest.mark.parametrize("argv, message", [
    (["generate", "--scale", "2", "--out", "g"], "argument --scale: must be a number in (0, 1], got '2'"),
    (["generate", "--scale", "nan", "--out", "g"], "argument --scale: must be a number in (0, 1], got 'nan'"),
    (["generate", "--workers", "100000", "--out", "g"], "argument --workers: must be an integer from 1 to 256, got '100000'"),
    (["generate", "--lengths", "3", "99", "--out", "g"], "argument --lengths: must be an integer from 1 to 13, got '99'"),
    (["generate", "--seed", str(2 ** 70), "--out", "g"],
     "argument --seed: must be an integer from 0 to 9223372036854775807, got '11805916207174113034'"),
    (["demo", "--scale", "5"], "argument --scale: must be a number in (0, 1], got '5'"),
    (["demo", "--workers", "0"], "argument --workers: must be an integer from 1 to 256, got '0'"),
    (["demo", "--per-length", "10000000"], "argument --per-length: must be an integer from 0 to 1000000, got '10000000'"),
    (["evaluate", "--data", "d", "--per-length", "10000000"],
     "argument --per-length: must be an integer from 0 to 1000000, got '10000000'"),
    (["evaluate", "--data", "d", "--nn-train", "-2"], "argument --nn-train: must be an integer from -1 to 10000000, got '-2'"),
    (["evaluate", "--data", "d", "--refined", "10000000"],
     "argument --refined: must be an integer from 0 to 1000000, got '10000000'"),
    (["table4", "--images", "10000000"], "argument --images: must be an integer from 0 to 1000000, got '10000000'"),
    (["table6", "--per-length", "10000000"], "argument --per-length: must be an integer from 0 to 1000000, got '10000000'"),
    (["table6", "--lengths", "0"], "argument --lengths: must be an integer from 1 to 13, got '0'"),
    (["parse", "x.png", "--refine-iters", "100001"],
     "argument --refine-iters: must be an integer from 0 to 100000, got '100001'"),
])
def test_defect_csgnet_number_options_have_a_maximum(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(message)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["parse", "nosuch.png", "--out", "afile"], ["parse", "nosuch.png", "--out", "afile/o"],
                                  ["generate", "--out", "afile/d"], ["demo", "--out", "afile"],
                                  ["evaluate", "--data", "nosuch", "--out", "afile/t.json"],
                                  ["export-weights", "nosuch.ckpt", "--out", "afile/w.pt"],
                                  ["table4", "--silhouettes", "nosuch.npz", "--out", "afile/t.md"],
                                  ["table6", "--weights", "nosuch.pt", "--out", "afile/t.md"]])
def test_defect_csgnet_out_errors_come_first_and_name_the_real_path(tmp_path, monkeypatch, capsys, argv):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == f"error: --out {argv[-1]}: 'afile' is a file, not a folder\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
