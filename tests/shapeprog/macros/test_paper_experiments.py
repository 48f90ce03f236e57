"""The ShapeMOD paper's experiments: Table 1 as a result with ratios, the Table 5 switches and ablation,
the Fig. 7 result, the cross-category collection, the Table 2 paper rows and the experiment list."""
import numpy as np
import pytest

from shapeio.results import read_result
from shapeprog.__main__ import main
from shapeprog.macros import Library, collection
from shapeprog.macros.ablation import VARIANTS, ablation_result, variant_config
from shapeprog.macros.config import DEFAULTS, SWITCHES, load_config
from shapeprog.macros.discover import discover
from shapeprog.macros.grammar import BBOX, AttachLine, CuboidLine, ReflectLine, SqueezeLine, signature
from shapeprog.macros.objective import templates
from shapeprog.macros.perturb_study import SIGMAS, perturbation_result, perturbation_study
from shapeprog.macros.state import Nodes
from shapeprog.macros.proposal import Candidate, abstract, candidates, cluster, generalise
from shapeprog.macros.table1 import PAPER, table1_result, table1_rows


# ----------------------------------------------------------------------------- Table 1


def test_table1_rows_give_f_as_a_ratio_to_the_same_runs_no_macros():
    rows = table1_rows(["chair"], limit=3, extra={"again": Library()})
    by = {r["method"]: r for r in rows}
    assert list(by) == ["No Macros", "Baseline", "ShapeMOD", "again"]
    base = by["No Macros"]["f"]
    for r in rows:
        assert r["f_ratio"] == pytest.approx(r["f"] / base)
    assert by["No Macros"]["f_ratio"] == 1.0
    # the base library applied again as an extra row: the No Macros figures exactly
    assert by["again"]["f"] == base and by["again"]["paper_f_ratio"] is None
    assert by["ShapeMOD"]["paper_f_ratio"] == pytest.approx(260 / 411)
    assert by["Baseline"]["paper_f_ratio"] == pytest.approx(312 / 411) and by["Baseline"]["paper_L"] == 36
    result = table1_result(rows, "cmd", 3)
    assert [c["key"] for c in result["columns"]][:5] == ["category", "method", "f", "f_ratio", "paper_f_ratio"]
    assert "a random subset of 3 shapes" in result["notes"][0]
    assert f"ours {base:.1f} for chair" in result["notes"][1]
    with pytest.raises(ValueError, match="may not be named 'Baseline'"):
        table1_rows(["chair"], limit=2, extra={"Baseline": Library()})


def test_paper_table1_ratios_are_below_one():
    for cat, rows in PAPER.items():
        assert rows["ShapeMOD"][0] / rows["No Macros"][0] < rows["Baseline"][0] / rows["No Macros"][0] < 1


def test_tables_command_writes_a_result_file(tmp_path, capsys):
    out = tmp_path / "sub" / "t1.json"
    assert main(["macros", "tables", "--category", "storage", "--limit", "2", "--quiet", "--json", str(out)]) == 0
    data = read_result(out)
    assert [r["method"] for r in data["rows"]] == ["No Macros", "Baseline", "ShapeMOD"]
    assert data["rows"][0]["f_ratio"] == 1.0
    assert "f / No Macros" in capsys.readouterr().out


# ----------------------------------------------------------------------------- Table 5 switches


def test_config_switches_default_on_and_load():
    assert all(DEFAULTS[k] is True for k in SWITCHES)
    assert load_config(None, order_filter=False)["order_filter"] is False


def test_cluster_without_distance_weighting_draws_far_members():
    members = [(i, 0) for i in range(4)]
    vectors = np.array([[0.0], [0.0], [0.0], [10.0]])
    far_weighted = far_uniform = 0
    for s in range(40):
        q = int(np.random.default_rng(s).integers(4))  # the seed member cluster() draws first
        w = cluster(members, vectors, 3, np.random.default_rng(s))
        u = cluster(members, vectors, 3, np.random.default_rng(s), weighted=False)
        if q != 3:
            assert w == [0, 1, 2]  # the far member has weight 1e-9 around a near seed
            far_uniform += 3 in u
            far_weighted += 3 in w
    assert far_weighted == 0 and far_uniform > 0


def _members(n=20):
    return [(CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(0.1, 1.0, 0.1, True),
             SqueezeLine(BBOX, BBOX, "top", 0.05 + 0.01 * k, 0.5), ReflectLine("X")) for k in range(n)]


def test_candidates_without_the_valid_macro_rules_keep_every_prefix():
    lib = Library()
    steps = abstract(_members(), 1, lib, templates(lib), DEFAULTS)
    assert [s.func for s in steps] == ["Cuboid", "squeeze", "reflect"]
    ids = [(i, 0) for i in range(20)]
    # rule (ii) with at most one line: only the one-line prefix (a Cuboid with constants)
    assert len(candidates(steps, lib, ids, 0, max_lines=1)) == 1
    # without the rules: every prefix the language accepts (1, 2 and 3 lines)
    assert len(candidates(steps, lib, ids, 0, max_lines=1, rules=False)) == 3
    # rule (iv): the two-line prefix starting at the squeeze ends in no Cuboid, is recorded with the rules too
    assert len(candidates(steps, lib, ids, 0, max_lines=4)) == 3


def test_generalise_switched_off_returns_the_candidates_as_they_are():
    text = "def macro(x0: float):\n    n0 = Cuboid(x0, 0.62 * x0, 0.5, True)\n"
    a = Library.from_text(text).macros[0]
    cands = {"a": Candidate(a, {(0, 0, 1)})}
    on, edges_on = generalise(cands, Library(), dict(DEFAULTS))
    off, edges_off = generalise(cands, Library(), {**DEFAULTS, "generalise": False})
    assert list(off) == ["a"] and edges_off == [] and off["a"].coverage == {(0, 0, 1)}
    assert len(on) > 1 and edges_on


def _two_orderings(n=40) -> Nodes:
    """Sub-programs with two 'orderings': the lines, and the lines with an extra slab (8 + its interface more
    in f, far above order_thresh)."""
    rng = np.random.default_rng(0)
    keys, lines, sigs = [], [], []
    for i in range(n):
        s = round(float(rng.uniform(0.05, 0.15)), 3)
        a = (CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(s, 1.0, s, True),
             SqueezeLine(BBOX, BBOX, "top", round(0.6 * s, 3), 0.5), ReflectLine("X"))
        b = a + (CuboidLine(1.0, 0.1, 1.0, True), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
        keys.append(f"two/{i}")
        lines.append([a, b])
        sigs.append([signature(a), signature(b)])
    return Nodes(keys, lines, sigs)


def test_order_filter_switched_off_keeps_every_ordering():
    nodes = _two_orderings()
    cfg = load_config(None, num_rounds=1, cand_cluster_num=10, abs_shape_num=60, cand_abs_num=3, gen_limit=20)
    on = discover(nodes, cfg, log=None)
    off = discover(nodes, {**cfg, "order_filter": False}, log=None)
    assert on.history[0]["orders_dropped"] == 40 and on.current == [[0]] * 40
    assert off.history[0]["orders_dropped"] == 0 and off.current == [[0, 1]] * 40


def test_ablation_variants_change_one_setting_each():
    assert variant_config("full") == DEFAULTS
    for name, change in VARIANTS.items():
        cfg = variant_config(name, {"num_rounds": 2})
        assert cfg["num_rounds"] == 2
        assert {k for k in DEFAULTS if cfg[k] != DEFAULTS[k]} == set(change) | {"num_rounds"}
    assert variant_config("no beam")["abs_beam_size"] == 1
    with pytest.raises(ValueError, match="unknown ablation variant 'no rounds'"):
        variant_config("no rounds")


def test_ablation_result_differences_to_the_full_method():
    rows = [{"variant": "full", "rounds": [100.0, 98.5], "f_subsample": 98.5, "L": 9, "f_all": 98.0,
             "candidates": 10, "seconds": 3.0},
            {"variant": "no beam", "rounds": [101.0], "f_subsample": 101.0, "L": 7, "f_all": 100.25,
             "candidates": 8, "seconds": 2.0}]
    res = ablation_result(rows, "cmd", "scale")
    assert [r["vs_full"] for r in res["rows"]] == [0.0, 2.25]
    assert res["rows"][1]["round2"] is None and res["rows"][0]["round2"] == 98.5
    assert res["notes"][0].startswith("scale.")


def test_ablation_command(tmp_path):
    out = tmp_path / "t5.json"
    assert main(["macros", "ablation", "--limit", "20", "--rounds", "1", "--proposal-steps", "5", "--variants",
                 "full", "no generalize", "--quiet", "--json", str(out)]) == 0
    rows = read_result(out)["rows"]
    assert [r["variant"] for r in rows] == ["full", "no generalize"] and rows[0]["vs_full"] == 0.0
    with pytest.raises(SystemExit, match="unknown variant 'none'"):
        main(["macros", "ablation", "--variants", "none", "--quiet"])


# ----------------------------------------------------------------------------- Fig. 7


def test_perturbation_result_rows():
    study = {"category": "chair", "library": "chair", "n": 4, "drawn": 5, "seed": 0, "repeats": 2,
             "sigmas": [0.0, 0.1], "fd": {"No Macros": [[10.0], [30.0, 50.0]], "ShapeMOD": [[11.0], [20.0, 24.0]]},
             "blown_up": {"No Macros": [[0], [1, 2]], "ShapeMOD": [[0], [0, 1]]},
             "fd_unperturbed_corpus": 9.5, "continuous_per_shape": {"No Macros": 70.0, "ShapeMOD": 50.0},
             "left_out": [(7, "x")], "val_shapes": 3, "seconds": 1.0}
    res = perturbation_result(study, "cmd")
    r = res["rows"][1]
    assert (r["sigma"], r["fd_base"], r["fd_base_min"], r["fd_base_max"]) == (0.1, 40.0, 30.0, 50.0)
    assert (r["fd_macros"], r["blown_base"], r["blown_macros"]) == (22.0, "1 / 2", "0 / 1")
    assert "4 train shapes (of 5 drawn" in res["notes"][0]


def test_perturbation_arguments_are_checked():
    with pytest.raises(ValueError, match="n and repeats must be at least 1"):
        perturbation_study("chair", Library(), "base", n=0)
    with pytest.raises(ValueError, match="sigmas must be finite numbers >= 0"):
        perturbation_study("chair", Library(), "base", sigmas=[0.1, -1.0])


def test_the_commands_copies_of_the_defaults_agree():
    from shapeprog.macros import commands

    assert commands.SIGMAS == SIGMAS
    assert commands.ABLATION_VARIANTS == tuple(VARIANTS)


# ----------------------------------------------------------------------------- cross-category discovery


def test_discover_merges_the_programs_of_several_categories():
    from shapeprog.macros.commands import merged_collection

    nodes, ids = merged_collection(["chair", "storage"], limit=3)
    chair, chair_ids = collection("chair", limit=3)
    storage, storage_ids = collection("storage", limit=3)
    assert nodes.keys == chair.keys + storage.keys and nodes.sigs == chair.sigs + storage.sigs
    assert ids == [f"chair/{i}" for i in chair_ids] + [f"storage/{i}" for i in storage_ids]
    with pytest.raises(SystemExit, match="named twice"):
        merged_collection(["chair", "chair"], limit=3)


def test_tables_note_option_and_extra_library(tmp_path, capsys):
    out = tmp_path / "t.json"
    assert main(["macros", "tables", "--category", "storage", "--limit", "2", "--extra", "chair lib=chair",
                 "--note", "a note", "--quiet", "--json", str(out)]) == 0
    data = read_result(out)
    assert [r["method"] for r in data["rows"]][-1] == "chair lib" and data["notes"][-1] == "a note"
    with pytest.raises(SystemExit, match="--extra 'x': expected NAME=FILE"):
        main(["macros", "tables", "--category", "storage", "--limit", "2", "--extra", "x", "--quiet"])


# ----------------------------------------------------------------------------- Tables 2 and 3


def test_table2_paper_rows_are_the_shapemod_papers():
    from shapeprog.macros.table2 import paper_rows
    from shapeprog.vae.gentable import GenerationRow, format_table

    rows = paper_rows("chair")
    assert rows == {"paper (ShapeMOD Table 2): No Macros": {"fool": 21.2, "fd": 17.8, "leaf_parts": 7.6,
                                                            "rooted": 93.9, "stable": 82.3},
                    "paper (ShapeMOD Table 2): ShapeMOD": {"fool": 25.6, "fd": 16.7, "leaf_parts": 8.6,
                                                           "rooted": 92.7, "stable": 79.5}}
    assert paper_rows("table") == {}
    text = format_table([GenerationRow("m", 3, 3, rooted=100.0)], "chair", paper="shapemod")
    assert "| paper: ShapeMOD Table 2, ShapeMOD | 92.7 | — | 79.5 | 25.60 | 16.70 | 8.60 |" in text
    assert "paper: ShapeAssembly" not in text
    assert "| paper: ShapeAssembly | 94.5 |" in format_table([], "chair")


def test_table2_result_rows():
    from shapeprog.macros.table2 import table2_result
    from shapeprog.vae.gentable import GenerationRow

    rows = [GenerationRow("No Macros", 10, 9, rooted=90.0, stable=80.0, stable_paper=82.0, fool=20.0, fd=30.0,
                          leaf_parts=7.0),
            GenerationRow("ShapeMOD", 10, 10, rooted=95.0, stable=85.0, fool=25.0, fd=28.0, leaf_parts=8.0)]
    res = table2_result("chair", rows, {"meta": {}, "sha": "ab" * 32, "sampling": ["x"], "fool_epochs": 12,
                                        "stability": True}, 10, 0, "cmd")
    assert [r["method"] for r in res["rows"]] == ["No Macros", "ShapeMOD", "paper (ShapeMOD Table 2): No Macros",
                                                  "paper (ShapeMOD Table 2): ShapeMOD", "Baseline Macros"]
    assert res["rows"][0]["samples"] == "9 of 10" and res["rows"][3]["fd"] == 16.7
    # the paper's stability is under its 10 % rule: its column, not the code rule's
    assert res["rows"][3]["stable_paper"] == 79.5 and res["rows"][3]["stable"] is None
    assert res["rows"][0]["stable"] == 80.0 and [c["label"] for c in res["columns"]][3:5] == [
        "% stable (code rule, 2.5 %)", "% stable (paper rule, 10 %)"]
    assert res["rows"][4]["rooted"] is None
    res = table2_result("storage", rows, {"meta": {}, "sha": None, "sampling": [], "fool_epochs": 12,
                                          "stability": False}, 10, 0, "cmd")
    assert len(res["rows"]) == 3 and "storage: not in the specification" in res["notes"][1]
    # with a Baseline Macros model measured, its row is the measured one and the note says how it was made
    from shapeprog.macros.table2 import BASELINE_NOTE
    rows.insert(1, GenerationRow("Baseline Macros", 10, 8, rooted=85.0, stable=70.0, fool=15.0, fd=40.0,
                                 leaf_parts=6.0))
    res = table2_result("chair", rows, {"meta": {}, "sha": "ab" * 32, "sampling": ["x"], "fool_epochs": 12,
                                        "stability": True}, 10, 0, "cmd")
    assert [r["method"] for r in res["rows"]] == ["No Macros", "Baseline Macros", "ShapeMOD",
                                                  "paper (ShapeMOD Table 2): No Macros",
                                                  "paper (ShapeMOD Table 2): ShapeMOD"]
    assert res["rows"][1]["samples"] == "8 of 10" and res["rows"][1]["fd"] == 40.0
    assert BASELINE_NOTE in res["notes"]
    # each model's training, from its weights file's meta, is a note
    from shapeprog.macros.table2 import training_summary
    assert training_summary({"training": "40 epochs", "epoch": 39}) == "40 epochs"
    assert training_summary({"epoch": 44}) == "kept at epoch 44 of one run" and training_summary({}) == "not recorded"
    res = table2_result("chair", rows, {"meta": {}, "sha": "ab" * 32, "sampling": ["x"], "fool_epochs": 12,
                                        "stability": True, "training": {"No Macros": "170 epochs",
                                                                        "ShapeMOD": "kept at epoch 44 of one run"}},
                        10, 0, "cmd")
    assert ("Training of each model (its weights file's meta): No Macros: 170 epochs; ShapeMOD: kept at epoch 44 "
            "of one run.") in res["notes"]


def test_table3_result_and_weights():
    from shapeprog.macros.table3 import shipped_weights, table3_result

    w = shipped_weights("table")
    assert w["No Macros"].endswith("pointcloud_e2e_table.pt") and w["ShapeMOD"].endswith("pointcloud_e2e_table_macros.pt")
    rows = [{"category": "chair", "method": "No Macros", "cd": 50.0, "fscore": 60.0, "rooted": 90.0, "stable": 80.0,
             "shapes": 5, "failed": 0}]
    res = table3_result(rows, "cmd", 5, 0)
    assert res["rows"] == rows and "the first 5 test shapes" in res["notes"][0]


def test_table3_notes_say_which_split_each_library_was_discovered_on(monkeypatch):
    from shapeprog.macros import api
    from shapeprog.macros.table3 import table3_result

    for c in api.LIBRARY_CATEGORIES:  # the shipped headers name a split
        assert api.library_split(c) in ("train", "all")
    headers = {"chair": "# shapes: 3339 of split 'train' (seed 0)\n", "table": "# shapes: 10 of split 'all' (seed 0)\n",
               "storage": "# no shapes line\n"}
    monkeypatch.setattr(api, "library_text", lambda c: headers[c])
    assert [api.library_split(c) for c in ("chair", "table", "storage")] == ["train", "all", None]
    rows = [{"category": c, "method": "No Macros", "cd": 1.0, "fscore": 2.0, "rooted": 3.0, "stable": 4.0, "shapes": 5,
             "failed": 0} for c in ("table", "chair", "storage")]
    note = table3_result(rows, "cmd", None, 0)["notes"][1]
    assert "the chair library was discovered on the train split, without these test shapes; " in note
    assert "the table library was discovered on split all, so these test shapes took part in discovery" in note
    assert "the storage library was discovered on a split that the header does not record" in note
    note = table3_result(rows[1:2], "cmd", None, 0)["notes"][1]
    assert "the chair library was discovered on the train split" in note and "table" not in note


def test_pointcloud_command_refuses_a_missing_cache(tmp_path):
    with pytest.raises(SystemExit, match="no such folder"):
        main(["macros", "pointcloud", "--clouds", f"chair={tmp_path / 'none'}", "--quiet"])
    with pytest.raises(SystemExit, match="unknown category"):
        main(["macros", "pointcloud", "--clouds", f"sofa={tmp_path}", "--quiet"])


def test_experiment_list_entries():
    from shapeprog.macros.paper import EXPERIMENTS

    by = {e.id: e for e in EXPERIMENTS}
    assert set(by) == {"mod-t1", "mod-t2", "mod-t3", "mod-t5", "mod-f7", "mod-s65"}
    for e in EXPERIMENTS:
        if e.status in ("done", "partial"):
            assert e.result.startswith("docs/results/shapemod/") and e.steps and e.quick and e.scale
            assert all(a == "{out}" for s in e.steps for a in s.argv if "{out}" in a)
    # Table 2 has its Baseline Macros row: the steps' command measures the shipped Baseline Macros model too
    assert by["mod-t2"].status == "done" and "Baseline Macros" in by["mod-t2"].description
