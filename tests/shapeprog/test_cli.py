"""Command line: run a corpus id or a file, export, report parse errors."""
import subprocess
import sys

import pytest
import torch

from shapeprog.__main__ import main


def test_run_corpus_id_writes_obj_and_png(tmp_path, capsys):
    obj, png = tmp_path / "chair.obj", tmp_path / "chair.png"
    assert main(["assembly", "run", "chair/173", "-o", str(obj), "--png", str(png), "--size", "64"]) == 0
    lines = obj.read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == 6 * 8 and sum(ln.startswith("f ") for ln in lines) == 6 * 12
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "chair/173: 2 blocks, 6 leaf cuboids" in capsys.readouterr().out


def test_run_file_and_parse_error(tmp_path, capsys):
    good = tmp_path / "p.txt"
    good.write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.5, 0.5, True)\n"
                    "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n")
    assert main(["assembly", "run", str(good), "-o", str(tmp_path / "p.ply")]) == 0
    import trimesh

    mesh = trimesh.load(tmp_path / "p.ply", process=False)  # the one leaf cuboid: 8 vertices, 12 triangles
    assert (len(mesh.vertices), len(mesh.faces)) == (8, 12)
    assert mesh.bounds.ravel().tolist() == pytest.approx([-0.25, -0.5, -0.25, 0.25, 0.0, 0.25])
    bad = tmp_path / "bad.txt"
    bad.write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = cubiod(1.0, 1.0, 1.0, True)\n")
    assert main(["assembly", "run", str(bad)]) == 2
    assert f"{bad}:2:9: unknown command 'cubiod'" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="neither a file nor a corpus id"):
        main(["assembly", "run", "sofa/1"])


def test_fit_command_writes_program(tmp_path):
    out = tmp_path / "fitted.txt"
    r = subprocess.run([sys.executable, "-m", "shapeprog", "fit", "table/33075", "--steps", "2", "-o", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "chamfer" in r.stdout and "F-score" in r.stdout
    assert out.read_text().startswith("Assembly Program_0 {\n\tbbox = Cuboid(")


def test_outputs_never_overwrite_inputs(tmp_path):
    prog = tmp_path / "p.txt"
    prog.write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\n")
    with pytest.raises(SystemExit, match=r"p\.txt: this output would overwrite an input file"):
        main(["assembly", "run", str(prog), "--png", str(prog)])
    assert prog.read_text() == "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"


def test_defect10_missing_corpus_id_and_missing_output_folder(tmp_path):
    with pytest.raises(SystemExit, match=r"^error: no program chair/999999999 in the corpus$"):
        main(["assembly", "run", "chair/999999999"])
    missing = tmp_path / "no" / "x.obj"
    with pytest.raises(SystemExit, match=r"x\.obj: folder .* does not exist"):
        main(["assembly", "run", "chair/173", "-o", str(missing)])
    with pytest.raises(SystemExit, match=r"unknown mesh format '\.stl'"):
        main(["assembly", "run", "chair/173", "-o", str(tmp_path / "x.stl")])
    assert list(tmp_path.iterdir()) == []


def test_defect8_non_utf8_program_file_and_defect3_non_finite_execution(tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_bytes(b"bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.5, 0.5, True)\xff\n")
    assert main(["assembly", "run", str(bad)]) == 2
    assert f"error: {bad}:2:36: not UTF-8 text" in capsys.readouterr().err
    huge = tmp_path / "huge.txt"
    huge.write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(1e308, 0.5, 0.5, True)\n")
    assert main(["assembly", "run", str(huge), "-o", str(tmp_path / "huge.obj")]) == 2
    assert f"error: {huge}:2:16: number 1e308 is out of range" in capsys.readouterr().err
    zero = tmp_path / "zero.txt"
    zero.write_text("bbox = Cuboid(0.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.5, 0.5, True)\n"
                    "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n")
    assert main(["assembly", "run", str(zero), "-o", str(tmp_path / "zero.obj")]) == 2
    assert f"error: {zero}:2: execution gives a non-finite cuboid" in capsys.readouterr().err
    assert not (tmp_path / "zero.obj").exists() and not (tmp_path / "huge.obj").exists()


def test_unreadable_point_cloud_is_an_error_naming_it(tmp_path, capsys):
    assert main(["assembly", "fit", "chair/173", "--points", str(tmp_path / "none.obj"), "--steps", "0"]) == 1
    assert f"{tmp_path / 'none.obj'}: no such file" in capsys.readouterr().err


@pytest.mark.parametrize("cmd,options", [
    ("run", ["program", "--out", ".obj", ".ply", ".glb", "--png", "--size", "--float64"]),
    ("fit", ["program", "--points", ".obj", ".ply", "example", "--steps", "--lr", "--reg", "--decimals", "--seed",
             "--out", "--json", "--overwrite", "--mesh", ".glb"]),
    ("silhouettes", ["--out", ".npz", "--size", "--margin", "--limit", "--quiet"]),
    ("volumes", ["--out", ".npz", "--category", "--size", "--margin", "--limit", "--workers", "--quiet"]),
])
def test_help_lists_every_option_and_format(cmd, options, capsys):
    with pytest.raises(SystemExit):
        main(["assembly", cmd, "--help"])
    out = capsys.readouterr().out
    for option in options:
        assert option in out


def _argument_error(capsys, argv) -> str:
    """The last stderr line of an argument error (exit status 2), before any work."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    return capsys.readouterr().err.splitlines()[-1]


def test_defect_sizes_without_maximum_are_refused(tmp_path, capsys):
    from shapeprog.picture import MAX_SIZE, render_grid, render_png
    from shapeprog.silhouettes import silhouette

    assert _argument_error(capsys, ["assembly", "silhouettes", "--size", "100000", "--out", str(tmp_path / "s.npz")]).endswith(
        "argument --size: must be an integer from 1 to 256, got '100000'")
    assert _argument_error(capsys, ["assembly", "run", "chair/173", "--png", str(tmp_path / "x.png"), "--size", "20000"]).endswith(
        "argument --size: must be an integer from 8 to 2048, got '20000'")
    assert _argument_error(capsys, ["pointcloud", "make-clouds", "--category", "chair", "--points", "30000000", "--out",
                                    str(tmp_path / "c")]).endswith(
        "argument --points: must be an integer from 1 to 20000000, got '30000000'")
    assert _argument_error(capsys, ["macros", "refactor-corpus", "--category", "chair", "--library", "chair", "--workers",
                                    "100000", "--out", str(tmp_path / "r")]).endswith(
        "argument --workers: must be an integer from 1 to 256, got '100000'")
    with pytest.raises(SystemExit, match=r"error: --png: a grid of 5000 pictures of 192 pixels has 184320000 pixels; "
                                         r"at most 67108864 \(MAX_GRID_PIXELS\)"):
        main(["vae", "sample", "--category", "chair", "-n", "5000", "--png", str(tmp_path / "g.png")])
    assert list(tmp_path.iterdir()) == []
    box = torch.tensor([[[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]], dtype=torch.float32)
    with pytest.raises(ValueError, match=r"`size` must be an int from 8 to 2048 \(MAX_SIZE\), got 2049"):
        render_png(box, size=MAX_SIZE + 1)
    with pytest.raises(ValueError, match=r"has 83886080 pixels; at most 67108864 \(MAX_GRID_PIXELS\)"):
        render_grid([box] * 20, cols=4, size=2048)
    with pytest.raises(ValueError, match=r"need an int size from 1 to 256 \(MAX_SIZE\), got size=257"):
        silhouette(box, "front", size=257)


def test_defect_sample_ten_million_is_refused_at_once(capsys):
    from shapeprog.vae import load_pretrained, sample

    assert _argument_error(capsys, ["vae", "sample", "--category", "chair", "-n", "10000000"]).endswith(
        "argument -n: must be an integer from 1 to 100000, got '10000000'")
    with pytest.raises(ValueError, match="n must be at most 100000, got 10000000"):
        sample(load_pretrained("chair"), 10_000_000)


@pytest.mark.parametrize("argv, message", [
    (["assembly", "fit", "chair/173", "--lr", "nan"], "argument --lr: must be a number in (0, 1], got 'nan'"),
    (["assembly", "fit", "chair/173", "--lr", "1e30"], "argument --lr: must be a number in (0, 1], got '1e30'"),
    (["vae", "sample", "--category", "chair", "--seed", str(2 ** 77)],
     "argument --seed: must be an integer from 0 to 9223372036854775807, got '15111572745182864683'"),
    (["pointcloud", "infer", "good.xyz", "--seed", "-1", "--out", "o"],
     "argument --seed: must be an integer from 0 to 9223372036854775807, got '-1'"),
    (["coder", "infer", "coder-chair:1", "--library", "chair", "--passes", "0"],
     "argument --passes: must be an integer from 1 to 100, got '0'"),
])
def test_defect_bad_option_values_are_argument_errors_not_tracebacks(capsys, argv, message):
    assert _argument_error(capsys, argv).endswith(message)


def test_defect_bad_option_values_are_refused_by_the_library():
    from shapeprog import corpus, parse
    from shapeprog.fit import fit

    program = parse(corpus.read("chair", 173))
    points = torch.rand(100, 3)
    for kwargs, match in (({"lr": float("nan")}, r"`lr` must be a number in \(0, 1\] \(MAX_LR\), got nan"),
                          ({"lr": 1e30}, r"`lr` must be a number in \(0, 1\] \(MAX_LR\), got 1e\+30"),
                          ({"reg": -1.0}, r"`reg` must be a number in \[0, 1e\+06\] \(MAX_REG\), got -1.0"),
                          ({"decimals": 400}, r"`decimals` must be an integer from 0 to 12 \(MAX_DECIMALS\), got 400")):
        with pytest.raises(ValueError, match=match):
            fit(program, points, steps=1, **kwargs)


def test_defect_reconstruct_with_another_categorys_weights_is_refused(tmp_path, capsys):
    from shapeprog.vae.pretrained import WEIGHTS

    table = WEIGHTS / "vae_table.pt"
    out = tmp_path / "r.txt"
    with pytest.raises(SystemExit) as e:
        main(["vae", "reconstruct", "chair/173", "--weights", str(table), "-o", str(out)])
    assert str(e.value) == (f"error: {table}: a table model, but the input is a chair program (give --category table "
                            "to use this model anyway)")
    assert not out.exists()
    assert main(["vae", "reconstruct", "chair/173", "--weights", str(table), "--category", "table", "-o", str(out)]) == 0


def test_defect_abstract_infer_names_a_missing_file_or_a_folder(tmp_path, capsys):
    with pytest.raises(SystemExit, match=r"^error: nosuch\.txt: no such file \(nor a PN_<category>\.txt line or "
                                         r"an id coder-<category>:<line>\)$"):
        main(["coder", "infer", "nosuch.txt", "--library", "chair"])
    with pytest.raises(SystemExit, match=r"is a folder, not a shape file$"):
        main(["coder", "infer", str(tmp_path), "--library", "chair"])


def test_coder_shape_ids_are_not_corpus_ids():
    # chair/401 names a ShapeAssembly corpus program; ShapeCoder's line 401 of PN_chair.txt is coder-chair:401
    with pytest.raises(SystemExit) as e:
        main(["coder", "infer", "chair/401", "--library", "chair"])
    assert e.value.code == ("error: chair/401: a ShapeAssembly corpus id, which ShapeCoder does not read; its "
                            "shapes are lines of its own data set: coder-chair:401 is line 401 of PN_chair.txt "
                            "(another shape)")
    with pytest.raises(SystemExit, match=r"^error: coder-chair:0: PN_chair\.txt has lines 1 to \d+$"):
        main(["coder", "infer", "coder-chair:0", "--library", "chair"])
    with pytest.raises(SystemExit, match=r"^error: coder-sofa:3: unknown category 'sofa'"):
        main(["coder", "infer", "coder-sofa:3", "--library", "chair"])


# the commands with an output option, their inputs missing: the --out error must come before the work starts
_OUT_COMMANDS = [
    (["assembly", "silhouettes", "--out", "{file}/s.npz"], "file"),
    (["pointcloud", "infer", "nosuch.xyz", "--out", "{file}"], "folder"),
    (["pointcloud", "infer", "nosuch.xyz", "--out", "{file}/sub"], "folder"),
    (["pointcloud", "tables", "--clouds", "nosuch", "--out", "{file}/t.md"], "file"),
    (["pointcloud", "make-clouds", "--category", "chair", "--out", "{file}/c"], "folder"),
    (["vae", "sample", "--category", "chair", "--out", "{file}"], "folder"),
    (["vae", "interpolate", "nosuch1.txt", "nosuch2.txt", "--out", "{file}/i"], "folder"),
    (["export-weights", "nosuch.ckpt", "--out", "{file}/w.pt"], "file"),
    (["vae", "evaluate", "--category", "chair", "--out", "{file}/t.md"], "file"),
    (["vae", "train-classifier", "--out", "{file}/c.pt"], "file"),
    (["coder", "discover", "--category", "chair", "--out", "{file}"], "folder"),
    (["macros", "discover", "--category", "chair", "--out", "{file}/m"], "folder"),
    (["macros", "refactor-corpus", "--category", "chair", "--library", "nosuch", "--out", "{file}"], "folder"),
    (["macros", "tables", "--out", "{file}/t.md"], "file"),
    (["coder", "tables", "--out", "{file}/t.md"], "file"),
    (["assembly", "run", "nosuch.txt", "-o", "{file}/x.obj"], "file"),
    (["macros", "refactor", "nosuch.txt", "--library", "nosuch", "-o", "{file}/x.txt"], "file"),
]


@pytest.mark.parametrize("argv, kind", _OUT_COMMANDS, ids=[a[0] + "-" + a[-1] for a, _ in _OUT_COMMANDS])
def test_defect_out_errors_come_first_and_name_the_real_path(tmp_path, capsys, monkeypatch, argv, kind):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    argv = [a.format(file="afile") for a in argv]
    with pytest.raises(SystemExit) as e:
        main(argv)
    err = str(e.value.code)
    assert "\n" not in err and err.startswith("error: --out afile")
    assert err.endswith("'afile' is a file, not a folder"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_defect_out_in_an_unwritable_folder_is_named_before_the_work(tmp_path, capsys, monkeypatch):
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(kwargs.get("dir")) + "/.x.atomic-1-abc.tmp")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(SystemExit) as e:
        main(["pointcloud", "infer", "nosuch.xyz", "--out", str(tmp_path / "new" / "out")])
    assert e.value.code == (f"error: --out {tmp_path / 'new' / 'out'}: cannot write in folder {str(tmp_path)!r} "
                            "(Permission denied)")
    with pytest.raises(SystemExit) as e:
        main(["macros", "tables", "--out", str(tmp_path / "t.md")])
    assert e.value.code == f"error: --out {tmp_path / 't.md'}: cannot write in folder {str(tmp_path)!r} (Permission denied)"
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------- the earlier one-word commands (aliases)


@pytest.mark.parametrize("argv, expected", [
    (["sample", "chair", "-n", "2"], ["vae", "sample", "--category", "chair", "-n", "2"]),
    (["sample", "-n", "2", "table", "--quiet"], ["vae", "sample", "-n", "2", "--category", "table", "--quiet"]),
    (["run", "chair/173", "--output", "x.obj"], ["assembly", "run", "chair/173", "--out", "x.obj"]),
    (["fit", "chair/173", "--output=f.txt"], ["assembly", "fit", "chair/173", "--out=f.txt"]),
    (["edit", "--sample", "chair", "--seed", "3"], ["assembly", "edit", "--sample", "--category", "chair", "--seed", "3"]),
    (["table1", "--categories", "chair", "table"], ["macros", "tables", "--category", "chair", "table"]),
    (["table2-coder", "--categories", "storage"], ["coder", "tables", "--category", "storage"]),
    (["discover-abstractions", "chair", "--start-from", "table", "--out", "r"],
     ["coder", "discover", "--category", "chair", "--start-from", "table", "--out", "r"]),
    (["abstract-infer", "chair/401", "--library", "chair"], ["coder", "infer", "coder-chair:401", "--library", "chair"]),
    (["pointcloud-tables", "--clouds", "c"], ["pointcloud", "tables", "--clouds", "c"]),
    (["export-weights", "nosuch.ckpt", "--out", "w.pt"], ["vae", "export-weights", "nosuch.ckpt", "--out", "w.pt"]),
    (["vae", "sample", "chair"], ["vae", "sample", "chair"]),  # the new form is taken as written
])
def test_aliases_rewrite_the_earlier_argument_forms(argv, expected, capsys):
    from shapeprog.__main__ import resolve_alias

    assert resolve_alias(argv) == expected
    err = capsys.readouterr().err
    assert err == ("" if argv[0] == "vae" else f"note: '{argv[0]}' is now '{expected[0]} {expected[1]}'\n")


def _alias_run(capsys, argv) -> tuple[str, str]:
    assert main(argv) == 0
    out, err = capsys.readouterr()
    return out, err


def test_the_assembly_aliases_run_and_name_the_new_form(tmp_path, capsys):
    out, err = _alias_run(capsys, ["run", "chair/173", "--output", str(tmp_path / "a.obj")])
    assert err == "note: 'run' is now 'assembly run'\n" and out.startswith("chair/173: ")
    main(["assembly", "run", "chair/173", "-o", str(tmp_path / "b.obj")])
    assert (tmp_path / "a.obj").read_bytes() == (tmp_path / "b.obj").read_bytes()
    # an output that exists is refused unless --overwrite (through the alias too)
    with pytest.raises(SystemExit, match="a.obj: exists .* give --overwrite"):
        main(["run", "chair/173", "-o", str(tmp_path / "a.obj")])
    assert main(["assembly", "run", "chair/173", "-o", str(tmp_path / "a.obj"), "--overwrite"]) == 0


def test_the_pointcloud_aliases_run_and_name_the_new_form(tmp_path, capsys):
    argv = ["--category", "storage", "--limit", "1", "--points", "32", "--workers", "1", "--quiet"]
    _, err = _alias_run(capsys, ["make-clouds", *argv, "--out", str(tmp_path / "a")])
    assert err == "note: 'make-clouds' is now 'pointcloud make-clouds'\n"
    _alias_run(capsys, ["pointcloud", "make-clouds", *argv, "--out", str(tmp_path / "b")])
    assert (tmp_path / "a" / "storage_split.json").read_text() == (tmp_path / "b" / "storage_split.json").read_text()


def test_the_macros_aliases_run_and_name_the_new_form(tmp_path, capsys):
    old, err = _alias_run(capsys, ["refactor", "chair/173", "--library", "chair", "--output", str(tmp_path / "a.txt")])
    assert err == "note: 'refactor' is now 'macros refactor'\n"
    new, _ = _alias_run(capsys, ["macros", "refactor", "chair/173", "--library", "chair", "-o", str(tmp_path / "b.txt"),
                                 "--json", str(tmp_path / "f.json")])
    assert (tmp_path / "a.txt").read_text() == (tmp_path / "b.txt").read_text()
    assert old.replace("a.txt", "b.txt") == new.split(f"wrote {tmp_path / 'f.json'}")[0]
    from shapeio.results import read_result

    rows = read_result(tmp_path / "f.json")["rows"]
    total = next(line for line in new.splitlines() if line.startswith("total: f "))
    assert f"total: f {rows[-1]['f_base']:.2f} -> {rows[-1]['f']:.2f};" in total and rows[-1]["block"] == "total"


def test_the_coder_aliases_run_and_name_the_new_form(capsys):
    old, err = _alias_run(capsys, ["abstract-infer", "chair/401", "--library", "chair", "--passes", "1"])
    assert err == "note: 'abstract-infer' is now 'coder infer'\n"
    new, err = _alias_run(capsys, ["coder", "infer", "coder-chair:401", "--library", "chair", "--passes", "1"])
    assert old == new and old.startswith("program:  ") and err == ""


def test_a_command_takes_its_help_description_and_example_from_its_docstring():
    import argparse

    from shapeprog.cli import add_command

    def cmd_demo(args):
        """count the demo's shapes

        Count every shape of the demo
        and print the count.

        Example: demo count --category chair"""

    def cmd_bare(args):
        """count, undocumented"""

    sub = argparse.ArgumentParser().add_subparsers()
    parser = add_command(sub, "count", cmd_demo, outputs={"json": "file"})
    assert parser.description == "Count every shape of the demo and print the count."
    assert [a.help for a in sub._choices_actions] == ["count the demo's shapes"]
    assert (parser.get_default("example"), parser.get_default("outputs")) == ("demo count --category chair",
                                                                               {"json": "file"})
    assert parser.epilog == "example:\n  python -m shapeprog demo count --category chair"
    with pytest.raises(ValueError, match="command 'bare': .*cmd_bare needs a docstring of a summary line"):
        add_command(sub, "bare", cmd_bare)
    given = add_command(sub, "given", cmd_bare, description="Counts.", example="demo given")
    assert (given.description, given.get_default("example")) == ("Counts.", "demo given")


def test_a_worker_pool_of_one_is_this_process_and_a_larger_one_is_shut_down_on_leaving():
    from shapeprog.cli import worker_pool

    with worker_pool(1) as none:
        assert none is None
    with worker_pool(2) as pool:
        assert list(pool.map(abs, [-1, -2, 3])) == [1, 2, 3]
    with pytest.raises(RuntimeError, match="after shutdown"):
        pool.submit(abs, -4)


def test_markdown_result_keeps_escaped_pipes_inside_a_cell():
    from shapeio.results import markdown
    from shapeprog.cli import markdown_result

    text = "**T**\n\n| row | F | \\|L\\| | Num |\n|---|---:|---:|---:|\n| a \\| b | 1.5 | 27 | 9 |\n"
    r = markdown_result(text, "x", "cmd")
    assert [c["label"] for c in r["columns"]] == ["table", "row", "F", "|L|", "Num"]
    assert r["rows"] == [{"table": "T", "row": "a | b", "f": 1.5, "l": 27, "num": 9}]
    table = markdown(r).splitlines()
    assert table[2] == "| table | row | F | \\|L\\| | Num |" and table[4] == "| T | a \\| b | 1.5 | 27 | 9 |"
    # a label already written escaped is not escaped twice
    r["columns"][3]["label"] = "\\|L\\|"
    assert markdown(r).splitlines()[2] == "| table | row | F | \\|L\\| | Num |"
