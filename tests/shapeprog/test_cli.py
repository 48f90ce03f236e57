"""Command line: run a corpus id or a file, export, report parse errors."""
import subprocess
import sys

import pytest

from shapeprog.__main__ import main


def test_run_corpus_id_writes_obj_and_png(tmp_path, capsys):
    obj, png = tmp_path / "chair.obj", tmp_path / "chair.png"
    assert main(["run", "chair/173", "-o", str(obj), "--png", str(png), "--size", "64"]) == 0
    lines = obj.read_text().splitlines()
    assert sum(ln.startswith("v ") for ln in lines) == 6 * 8 and sum(ln.startswith("f ") for ln in lines) == 6 * 12
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "chair/173: 2 blocks, 6 leaf cuboids" in capsys.readouterr().out


def test_run_file_and_parse_error(tmp_path, capsys):
    good = tmp_path / "p.txt"
    good.write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.5, 0.5, True)\n"
                    "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n")
    assert main(["run", str(good), "-o", str(tmp_path / "p.ply")]) == 0
    assert (tmp_path / "p.ply").stat().st_size > 0
    bad = tmp_path / "bad.txt"
    bad.write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = cubiod(1.0, 1.0, 1.0, True)\n")
    assert main(["run", str(bad)]) == 2
    assert f"{bad}:2:9: unknown command 'cubiod'" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="neither a file nor a corpus id"):
        main(["run", "sofa/1"])


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
        main(["run", str(prog), "--png", str(prog)])
    assert prog.read_text() == "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"
