import subprocess
import sys

import numpy as np

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
