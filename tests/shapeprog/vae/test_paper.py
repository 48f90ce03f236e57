"""The ShapeAssembly paper's experiment list (`python -m shapeprog paper`): ids, statuses, result files and docs."""
from pathlib import Path

from shapeio.experiments import STATUSES
from shapeio.results import read_result
from shapeprog.__main__ import main
from shapeprog.vae.paper import EXPERIMENTS

IDS = ["sa-t2", "sa-t3", "sa-t4", "sa-t5", "sa-t6", "sa-t7", "sa-novelty"]
ROOT = Path(__file__).resolve().parents[3]


def test_the_list_holds_every_shapeassembly_experiment_once(capsys):
    assert [e.id for e in EXPERIMENTS] == IDS
    assert main(["paper", "--list"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("sa-")]
    assert [ln.split()[0] for ln in lines] == IDS
    for ln, e in zip(lines, EXPERIMENTS):
        assert ln.split()[1] == e.status in STATUSES
    status = {e.id: e.status for e in EXPERIMENTS}
    assert status["sa-t2"] in ("done", "partial")  # the training ablations need retrained models
    assert "training ablations" in next(e.why for e in EXPERIMENTS if e.id == "sa-t2")


def test_every_done_experiment_has_its_result_file_and_docs_block():
    docs = "\n".join(p.read_text(encoding="utf-8") for p in (ROOT / "docs").glob("*.md"))
    for e in EXPERIMENTS:
        if e.status in ("done", "partial"):
            # a partial experiment may wait for its full run: its file, when there, is shown and readable
            if e.status == "done" or (ROOT / e.result).is_file():
                assert (ROOT / e.result).is_file(), e.id
                assert f"<!-- result: {e.result} -->" in docs, e.id
                assert read_result(ROOT / e.result)["command"].startswith("python -m shapeprog "), e.id
            assert all(s.argv[0] in ("vae", "pointcloud") for s in (*e.steps, *e.quick)), e.id
            assert any("{out}" in s.argv for s in e.steps) and any("{out}" in s.argv for s in e.quick), e.id


def test_paper_run_quick_writes_the_novelty_result(tmp_path, capsys):
    out = tmp_path / "novelty.json"
    assert main(["paper", "run", "sa-novelty", "--quick", "--out", str(out)]) == 0
    rows = read_result(out)["rows"]
    assert [(r["category"], r["programs"]) for r in rows] == [("storage", 50), ("storage", 116)]
    assert all(0 < r["structure"] < 100 and r["text"] == 100.0 for r in rows)


def test_dry_run_of_the_generation_tables(tmp_path, capsys):
    out = tmp_path / "g.json"
    assert main(["paper", "run", "sa-t2", "--dry-run", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "vae evaluate --category chair table storage" in text and "--max-tries 10 1 --paper-decoding" in text
    assert not out.exists()
