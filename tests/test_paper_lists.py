"""Both experiment lists (`python -m csgnet paper --list`, `python -m shapeprog paper --list`): the issue's ids,
allowed statuses, and for every built experiment a result file the docs show."""
from pathlib import Path

import pytest

from csgnet.paper.experiments import EXPERIMENTS as CSG
from shapeio.experiments import STATUSES
from shapeio.results import read_result
from shapeprog.paper import EXPERIMENTS as SHAPEPROG

ROOT = Path(__file__).resolve().parents[1]
SHAPEPROG_IDS = ["sa-t2", "sa-t3", "sa-t4", "sa-t5", "sa-t6", "sa-t7", "sa-novelty", "mod-t1", "mod-t2", "mod-t3",
                 "mod-t5", "mod-f7", "mod-s65", "coder-t2", "coder-t3", "coder-t4-left", "coder-t4-right", "coder-s75",
                 "coder-s76"]


def test_the_shapeprog_list_holds_every_paper_experiment_once_in_order():
    assert [e.id for e in SHAPEPROG] == SHAPEPROG_IDS
    assert all(e.status in STATUSES for e in SHAPEPROG)


@pytest.mark.parametrize("experiments", [CSG, SHAPEPROG], ids=["csgnet", "shapeprog"])
def test_every_built_experiment_has_a_result_file_shown_in_the_docs(experiments):
    docs = "\n".join(p.read_text(encoding="utf-8") for p in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")])
    for e in experiments:
        if e.status == "done":
            assert (ROOT / e.result).is_file(), f"{e.id}: no {e.result}"
            read_result(ROOT / e.result)
            assert f"<!-- result: {e.result} -->" in docs, f"{e.id}: {e.result} is shown on no docs page"
        if e.status in ("not-built", "impossible", "partial"):
            assert e.why, e.id


def test_the_docs_list_of_shapeprog_experiments_is_the_code_list():
    """docs/results/shapeassembly/experiments.json (`python -m shapeprog paper --list --json`) is the current list."""
    rows = read_result(ROOT / "docs" / "results" / "shapeassembly" / "experiments.json")["rows"]
    assert [(r["id"], r["status"], r["description"], r["why"]) for r in rows] == [
        (e.id, e.status, e.description, e.why) for e in SHAPEPROG]


def test_a_step_from_its_words():
    from shapeio.experiments import Step

    assert Step.of("vae novelty --category chair -n 5").argv == (
        "vae", "novelty", "--category", "chair", "-n", "5", "--json", "{out}", "--overwrite")
    assert Step.of("pointcloud make-clouds --out c", result=False, creates="c/x.npz") == Step(
        ("pointcloud", "make-clouds", "--out", "c"), "c/x.npz")
