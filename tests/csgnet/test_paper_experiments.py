"""The paper's experiment list (`python -m csgnet paper`), the result files of table1/table4/table6, the sweep."""
import json

import numpy as np
import pytest
import torch

from csgnet.__main__ import main
from csgnet.cli.tables import MAX_SWEEP_STEPS_CLI
from csgnet.paper.experiments import EXPERIMENTS
from csgnet.train.sweep import MAX_SWEEP_STEPS, reward_sweep
from shapeio.experiments import STATUSES, Experiment, Step, check_experiments, listing
from shapeio.results import read_result

IDS = ["csg-t1", "csg-t3", "csg-t4", "csg-t4-cad", "csg-t5", "csg-t6", "csg-f6"]


def test_the_list_holds_every_paper_experiment_once(capsys):
    assert [e.id for e in EXPERIMENTS] == IDS
    assert main(["paper", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines] == IDS
    for ln, e in zip(lines, EXPERIMENTS):
        assert ln.split()[1] == e.status in STATUSES
    status = {e.id: e.status for e in EXPERIMENTS}
    assert status["csg-t4-cad"] in ("done", "impossible")
    assert all(status[i] == "done" for i in ("csg-t1", "csg-t3", "csg-t4", "csg-t5", "csg-t6"))


def test_check_experiments_refuses_malformed_lists():
    ok = Experiment("a", "done", "x", result="r.json", steps=(Step(("demo",)),), quick=(Step(("demo",)),))
    check_experiments([ok])
    with pytest.raises(ValueError, match="listed twice"):
        check_experiments([ok, ok])
    with pytest.raises(ValueError, match="unknown status 'finished'"):
        check_experiments([Experiment("b", "finished", "x", why="y")])
    with pytest.raises(ValueError, match="needs a reason"):
        check_experiments([Experiment("b", "impossible", "x")])
    with pytest.raises(ValueError, match="needs steps"):
        check_experiments([Experiment("b", "done", "x")])
    text = listing([ok, Experiment("b", "impossible", "y", why="no data")])
    assert text.splitlines() == ["a  done        x", "b  impossible  y -- no data"]


def test_paper_run_quick_writes_its_result_file(tmp_path, capsys):
    out = tmp_path / "t4.json"
    assert main(["paper", "run", "csg-t4", "--quick", "--out", str(out)]) == 0
    result = read_result(out)
    assert result["command"] == f"python -m csgnet table4 --images 10 --iterations 0 2 --out {out} --overwrite"
    assert [r["protocol"] for r in result["rows"]][0] == "training silhouette, max IoU"
    assert all(r["cd_0"] >= 0 for r in result["rows"])


def test_paper_run_refuses_what_cannot_run(capsys):
    assert main(["paper", "run", "csg-t4-cad"]) == 2
    assert "csg-t4-cad is impossible: the paper's CAD images" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["paper", "run", "csg-t99"])
    assert e.value.code == 2
    assert "unknown experiment 'csg-t99'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["paper", "run"])


def test_dry_run_prints_the_commands_and_runs_nothing(tmp_path, capsys):
    out = tmp_path / "t1.json"
    assert main(["paper", "run", "csg-t1", "--dry-run", "--out", str(out)]) == 0
    assert f"$ python -m csgnet table1 --out {out}" in capsys.readouterr().out
    assert not out.exists()


def test_the_sweep_limit_is_the_same_in_the_command_line():
    assert MAX_SWEEP_STEPS_CLI == MAX_SWEEP_STEPS


def _silhouettes(n=24, seed=0):
    from csgnet.shapes2d import load_silhouettes

    s = load_silhouettes("train")
    return s[np.random.default_rng(seed).choice(len(s), n, replace=False)]


def test_reward_sweep_runs_differ_only_in_gamma():
    from csgnet.inference import WEIGHTS

    train = _silhouettes()
    a = reward_sweep(str(WEIGHTS / "csgnet2d.pt"), [1.0, 20.0, 1.0], 2, train, batch_size=8, seed=3)
    assert [label for label, _ in a] == ["supervised start (no REINFORCE)", "REINFORCE, gamma = 1",
                                         "REINFORCE, gamma = 20", "REINFORCE, gamma = 1"]
    sd = [dict(m.state_dict()) for _, m in a]
    # the same gamma on the same batches gives the same weights; another gamma or no tuning does not
    assert all(torch.equal(sd[1][k], sd[3][k]) for k in sd[1])
    assert any(not torch.equal(sd[1][k], sd[2][k]) for k in sd[1])
    assert any(not torch.equal(sd[0][k], sd[1][k]) for k in sd[1])
    with pytest.raises(ValueError, match="gamma must be a positive number"):
        reward_sweep(str(WEIGHTS / "csgnet2d.pt"), [0.0], 2, train)
    with pytest.raises(ValueError, match="steps must lie in"):
        reward_sweep(str(WEIGHTS / "csgnet2d.pt"), [1.0], 0, train)


def test_table1_writes_a_result_with_the_start_and_one_block_per_gamma(tmp_path, capsys):
    out = tmp_path / "t1.json"
    assert main(["table1", "--steps", "1", "--batch", "4", "--accumulate", "1", "--train-images", "8", "--images",
                 "3", "--beams", "1", "--gammas", "2", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert [r["method"] for r in result["rows"]] == ["supervised start (no REINFORCE)", "REINFORCE, gamma = 2"]
    assert result["title"].startswith("Table 1 layout")
    assert all(r["cd_0"] >= 0 for r in result["rows"])


@pytest.fixture(scope="module")
def small2d(tmp_path_factory):
    """A small 2D synthetic set (scale 0.001) written by csgnet's generator."""
    from csgnet.data import generate_dataset

    out = tmp_path_factory.mktemp("synth2d")
    generate_dataset(out, dim=2, scale=0.001, seed=0, workers=1)
    return out


def test_train_fraction_keeps_the_first_share_of_each_length(small2d):
    from csgnet.train.supervised import CSGDataModule

    full = CSGDataModule(dim=2, data_dir=str(small2d), batch_size=12)
    part = CSGDataModule(dim=2, data_dir=str(small2d), batch_size=12, train_fraction=0.1)
    full.setup("fit")
    part.setup("fit")
    for n, t in full.train_tables.items():
        k = -(-len(t) // 10)
        assert torch.equal(part.train_tables[n], t[:k])
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="train_fraction must lie in"):
            CSGDataModule(dim=2, data_dir=str(small2d), train_fraction=bad)
    with pytest.raises(ValueError, match="train_fraction needs a data_dir"):
        CSGDataModule(dim=2, data_dir=None, train_fraction=0.5)


def test_datasize_writes_one_block_per_share(tmp_path, small2d):
    import math

    from csgnet.data import load_dataset
    from csgnet.train.datasize import MAX_DATASIZE_STEPS

    assert MAX_DATASIZE_STEPS == MAX_SWEEP_STEPS_CLI
    out = tmp_path / "ds.json"
    assert main(["datasize", "--data", str(small2d), "--steps", "2", "--batch", "12", "--fractions", "0.1",
                 "1", "--per-length", "1", "--beams", "1", "--out", str(out)]) == 0
    rows = read_result(out)["rows"]
    counts = [len(p) for p in load_dataset(small2d, 2, "train").values()]
    tenth = sum(max(1, math.ceil(0.1 * c)) for c in counts)
    assert [r["method"] for r in rows] == [f"{tenth} training programs (10 %) k=1 top-1",
                                           f"{sum(counts)} training programs (100 %) k=1 top-1"]


def test_the_docs_list_of_experiments_is_the_code_list():
    """docs/results/csgnet/experiments.json (`paper --list --json`) holds exactly the current list."""
    rows = read_result("docs/results/csgnet/experiments.json")["rows"]
    assert [(r["id"], r["status"], r["description"], r["why"]) for r in rows] == [
        (e.id, e.status, e.description, e.why) for e in EXPERIMENTS]
