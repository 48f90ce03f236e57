"""Discovery: a planted macro is found with its parameter relations, f decreases, the result does not
depend on the executor, a killed run resumes, the milp selection, the settings."""
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from shapeprog.errors import ParseError
from shapeprog.macros.discover import discover, prior_rounds, rounds_line
from shapeprog.macros.state import Discovery, Nodes
from shapeprog.macros.config import DEFAULTS, load_config
from shapeprog.macros.grammar import BBOX, AttachLine, CuboidLine, ReflectLine, SqueezeLine, signature
from shapeprog.macros.lang import Linear, Literal, Name
from shapeprog.macros.library import Library
from shapeprog.macros.proposal import Candidate, generalise

ROOT = Path(__file__).resolve().parents[3]


def planted(n=100, seed=0) -> Nodes:
    """Programs generated from leg(s, b, t) = Cuboid(s, bb_y, s, b); squeeze(bbox, bbox, bot, 0.6 s, t);
    reflect(X), then a slab attached on the leg, values rounded to 3 decimals."""
    rng = np.random.default_rng(seed)
    keys, lines, sigs = [], [], []
    for i in range(n):
        bx, by, bz = (round(float(x), 3) for x in rng.uniform(0.6, 1.2, 3))
        s, t = round(float(rng.uniform(0.05, 0.15)), 3), round(float(rng.uniform(0.1, 0.4)), 3)
        b, h = bool(rng.random() < 0.5), round(float(rng.uniform(0.05, 0.2)), 3)
        ls = (CuboidLine(bx, by, bz, True), CuboidLine(s, by, s, b), SqueezeLine(BBOX, BBOX, "bot", round(0.6 * s, 3), t),
              ReflectLine("X"), CuboidLine(bx, h, bz, True), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
        keys.append(f"planted/{i}")
        lines.append([ls])
        sigs.append([signature(ls)])
    return Nodes(keys, lines, sigs)


def small_cfg(**kw):
    base = dict(num_rounds=1, cand_cluster_num=20, abs_shape_num=100, cand_abs_num=5, gen_limit=40, chunk=25)
    base.update(kw)
    return load_config(None, **base)


def _leg(lib: Library):
    for m in lib.macros:
        if lib[m.name].structure == ("Cuboid", "squeeze", "reflect"):
            return lib.expand_macro(m.name)
    raise AssertionError(f"no leg macro in {lib!r}")


def test_planted_macro_is_found_with_its_relations():
    nodes = planted()
    st = discover(nodes, small_cfg(), seed=0, log=None)
    leg = _leg(st.library())
    cub, sq, ref = leg.body
    assert [p.type for p in leg.params] == ["float", "bool", "float"]
    s, b, t = (p.name for p in leg.params)
    assert cub.args == (Linear.var(s), Linear.var("bb_y"), Linear.var(s), Name(b))
    assert sq.args == (Name("bbox"), Name("bbox"), Literal("bot"), Linear.var(s, 0.6), Linear.var(t))
    assert ref.args == (Literal("X"),)
    h = st.history[0]
    assert h["f_after"] < h["f_before"] - 20
    # f before: Cuboid 11.25 + squeeze 26.5 + reflect 8.5 + Cuboid 11.25 + attach 22
    assert h["f_before"] == pytest.approx(79.5)


def test_same_result_whatever_the_executor(tmp_path):
    nodes = planted(60)
    cfg = small_cfg(abs_shape_num=60, chunk=7)
    a = discover(nodes, cfg, seed=3, log=None)
    for pool in (ThreadPoolExecutor, ProcessPoolExecutor):
        with pool(2) as ex:
            b = discover(nodes, cfg, seed=3, executor=ex, log=None)
        assert a.history[0]["f_after"] == b.history[0]["f_after"]
        assert Library(a.macros).to_text() == Library(b.macros).to_text()
        assert a.current == b.current


def test_resume_after_a_kill(tmp_path):
    nodes = planted(60)
    cfg = small_cfg(num_rounds=2, abs_shape_num=60)
    full = discover(nodes, cfg, seed=1, log=None)

    def killer(msg):
        if msg.startswith("round 2/"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        discover(nodes, cfg, seed=1, out=tmp_path, log=killer)
    assert (tmp_path / "state.json").exists()
    msgs = []
    resumed = discover(nodes, cfg, seed=1, out=tmp_path, log=msgs.append)
    assert msgs[0].startswith("resuming after round 1")
    assert resumed.history[1]["f_after"] == full.history[1]["f_after"]
    assert Library(resumed.macros).to_text() == Library(full.macros).to_text()
    with pytest.raises(ParseError, match="another collection"):
        discover(nodes, cfg, seed=2, out=tmp_path, log=None)


def test_milp_selection_not_worse_than_greedy():
    nodes = planted(60)
    g = discover(nodes, small_cfg(abs_shape_num=60), seed=0, log=None)
    m = discover(nodes, small_cfg(abs_shape_num=60, selection="milp", search="exact"), seed=0, log=None)
    assert m.history[0]["f_after"] <= g.history[0]["f_after"] + 1e-9
    _leg(m.library())


def test_config_file_and_errors(tmp_path):
    import yaml
    data = yaml.safe_load((ROOT / "configs/shapemod/default.yaml").read_text())
    assert data == DEFAULTS
    assert load_config(ROOT / "configs/shapemod/default.yaml") == DEFAULTS
    bad = tmp_path / "bad.yaml"
    bad.write_text("cand_cluster_sise: 20\n")
    with pytest.raises(ParseError, match="unknown setting 'cand_cluster_sise'") as e:
        load_config(bad)
    assert str(bad) in str(e.value)
    with pytest.raises(ParseError, match="must be int"):
        load_config(None, num_rounds="5")
    with pytest.raises(ParseError, match="one of"):
        load_config(None, selection="best")
    # errors at the setting's own line; numbers outside their range; bad YAML at its place; bytes not UTF-8
    bad.write_text("num_rounds: 3\n\n  # spacing\nabs_beam_size: 0\n")
    with pytest.raises(ParseError, match=r"'abs_beam_size' must be in 1\.\.1000, got 0") as e:
        load_config(bad)
    assert (e.value.line, e.value.column) == (4, 1)
    bad.write_text("num_rounds: 3\nchunk: [1\n")
    with pytest.raises(ParseError, match="not YAML") as e:
        load_config(bad)
    assert e.value.line >= 2
    bad.write_bytes(b"num_rounds: 3\nprec: \xff\n")
    with pytest.raises(ParseError, match="not UTF-8") as e:
        load_config(bad)
    assert e.value.line == 2
    # an empty file or comments only: the defaults; a scalar, a huge number, deep nesting: our error
    for text in ("", "# nothing set\n"):
        bad.write_text(text)
        assert load_config(bad) == DEFAULTS
    for text, match in (("null\n", "a config is a mapping"), ("0\n", "a config is a mapping"),
                        ("prec: " + "1" * 4301 + "\n", "not a config: ValueError"),
                        ("prec: " + "[" * 2000 + "]" * 2000 + "\n", "not a config: RecursionError"),
                        ("prec: " + "[" * 2000 + "\n", "not YAML: expected the node content")):
        bad.write_text(text)
        with pytest.raises(ParseError, match=match):
            load_config(bad)
    from shapeprog.macros.config import LIMITS
    assert set(LIMITS) == {k for k, v in DEFAULTS.items() if type(v) in (int, float)}
    assert all(lo <= DEFAULTS[k] <= hi for k, (lo, hi) in LIMITS.items())


def test_generalise_snaps_coefficients_and_edits():
    lib = Library()
    text = "def macro(x0: float):\n    n0 = Cuboid(x0, {c} * x0, 0.5, True)\n"
    a = Library.from_text(text.format(c=0.62)).macros[0]
    b = Library.from_text(text.format(c=0.64)).macros[0]
    cands = {"a": Candidate(a, {(0, 0, 1)}), "b": Candidate(b, {(1, 0, 1), (2, 0, 1), (3, 0, 1)})}
    cfg = dict(DEFAULTS)
    out, edges = generalise(cands, lib, cfg)
    # one cluster (|0.62 - 0.64| <= 0.05): weighted mean 0.635, floored to a multiple of 0.05
    snapped = text.format(c=0.6).replace("\n    ", "\n    ")
    assert snapped.replace("macro", "macro") in out
    assert out[snapped].coverage == {(0, 0, 1), (1, 0, 1), (2, 0, 1), (3, 0, 1)}
    # edits: 0.6 * x0, 0.5, True -> 3 single edits and 3 pairs
    assert len(edges) == 6
    assert all(len(out[g].coverage) == 4 for _, g in edges)


@pytest.mark.parametrize("text, match", [
    ("{", "not JSON"), ("[]", "not a shapemod discovery state"),
    ('{"format": "shapemod-discovery/1"}', "damaged"),
    ('{"format": "shapemod-discovery/1", "library": "def f(:\\n", "active": [], "current": [], "history": [], '
     '"counter": 0, "nodes": "", "seed": 0, "config": {}}', "expected a parameter name"),
    ('{"format": "shapemod-discovery/1", "library": "", "active": ["nfunc_0"], "current": [], "history": [], '
     '"counter": 0, "nodes": "", "seed": 0, "config": {}}', "not defined"),
    ('{"format": "shapemod-discovery/1", "library": 5, "active": [], "current": [], "history": [], '
     '"counter": 0, "nodes": "", "seed": 0, "config": {}}', "field 'library'"),
    ('{"format": "shapemod-discovery/1", "library": "", "active": "xyz", "current": [], "history": [], '
     '"counter": 0, "nodes": "", "seed": 0, "config": {}}', "field 'active'"),
    ('{"format": "shapemod-discovery/1", "library": "", "active": [], "current": [[1.5]], "history": [], '
     '"counter": 0, "nodes": "", "seed": 0, "config": {}}', "field 'current'"),
    ('{"format": "shapemod-discovery/1", "library": "", "active": [], "current": [], "history": "abc", '
     '"counter": 0, "nodes": "", "seed": 0, "config": {}}', "field 'history'"),
    ('{"format": "shapemod-discovery/1", "library": "", "active": [], "current": [], "history": [], '
     '"counter": Infinity, "nodes": "", "seed": 0, "config": {}}', "Infinity is not a JSON number"),
    ('{"format": "shapemod-discovery/1", "library": "", "active": [], "current": [], "history": [], '
     '"counter": 0, "nodes": "", "seed": 0, "config": []}', "field 'config'"),
    ("[" * 3000, "nested more than 64 levels"), ("1" * 5000, "not JSON"),
])
def test_damaged_state_is_refused(tmp_path, text, match):
    (tmp_path / "state.json").write_text(text)
    with pytest.raises(ParseError, match=match) as e:
        discover(planted(5), small_cfg(), out=tmp_path, log=None)
    assert "state.json" in str(e.value)


def test_continuing_from_a_library_equals_resuming():
    """With one ordering per node and no macro removed, a library file holds the whole state: continuing from
    it gives the run's next round exactly."""
    nodes = planted(60)
    cfg = small_cfg(num_rounds=2, abs_shape_num=60)
    full = discover(nodes, cfg, seed=1, log=None)
    one = discover(nodes, small_cfg(num_rounds=1, abs_shape_num=60), seed=1, log=None)
    assert [m.name for m in one.macros] == one.active  # nothing removed: the library is the state
    text = rounds_line(one, cfg) + "\n" + one.library().to_text()  # the header line discover-macros writes
    assert prior_rounds(text) == [round(one.history[0]["f_after"], 2)]
    for bad, column in (("abc", 26), ("1.0, nan", 31), ("-2", 26)):
        with pytest.raises(ParseError, match="the '# rounds:' header holds f values") as e:
            prior_rounds(f"# rounds: 1 (subsample): {bad}\n", "lib.txt")
        assert (e.value.file, e.value.line, e.value.column) == ("lib.txt", 1, column)
    start = Discovery.from_library(Library.from_text(text), nodes, prior_rounds(text), "one")
    assert start.counter == 1 + max(int(m.name[6:]) for m in one.macros)
    msgs = []
    cont = discover(nodes, cfg, seed=1, log=msgs.append, start=start)
    assert msgs[0].startswith("starting after round 1 from a library of")
    assert len(cont.history) == 2 and cont.history[0]["from"] == "one"
    assert cont.history[1]["f_after"] == full.history[1]["f_after"]
    assert Library(cont.macros).to_text() == Library(full.macros).to_text()
    assert prior_rounds("def f(x: float):\n    c = Cuboid(x, x, x, True)\n") == []


def test_a_proposal_step_without_a_common_signature_is_counted_as_missed():
    from shapeprog.macros.discover import _index
    from shapeprog.macros.objective import templates
    from shapeprog.macros.proposal import propose_step

    nodes = planted(30)
    cfg = small_cfg()
    current = [[0] for _ in nodes.lines]
    lib = Library()
    tpls = list(templates(lib))
    missed: list = []
    rng = np.random.default_rng(0)
    # 30 programs of one signature, clusters of 20: a step proposes, and misses nothing
    assert propose_step(nodes, current, _index(nodes, current), lib, tpls, cfg, rng, missed=missed)
    assert missed == []
    # every signature below the cluster size: 50 failed draws, nothing proposed, the step counted as missed
    few = [[0] if i < 10 else [] for i in range(len(nodes.lines))]
    assert propose_step(nodes, few, _index(nodes, few), lib, tpls, cfg, rng, missed=missed) == []
    assert missed == [1]


def test_defect_yaml_alias_bomb_is_refused(tmp_path):
    from shapeprog.errors import ParseError
    from shapeprog.macros.config import MAX_CONFIG_BYTES

    levels = ["a: &a [x, x, x, x, x, x, x, x, x]"]
    levels += [f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]"
               for p, c in zip("abcdefgh", "bcdefghi")]
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(levels) + "\n")  # 9**9 strings when expanded
    assert bomb.stat().st_size < 400
    with pytest.raises(ParseError) as e:
        load_config(bomb)
    assert str(e.value) == f"{bomb}:2:8: YAML aliases (*a) are not allowed in a config"
    big = tmp_path / "big.yaml"
    big.write_text("num_rounds: 5\n" + "#" * MAX_CONFIG_BYTES + "\n")
    with pytest.raises(ParseError, match=r"big.yaml:1:1: a config has at most 1048576 bytes \(MAX_CONFIG_BYTES\)"):
        load_config(big)
    long = tmp_path / "long.yaml"
    long.write_text("num_rounds: " + "y" * 100_000 + "\n")
    with pytest.raises(ParseError) as e:
        load_config(long)
    assert str(e.value) == (f"{long}:1:1: setting 'num_rounds' must be int, got '{'y' * 59}... "
                            "(100002 characters)")


def test_defect_discover_stop_after_nan_is_refused(capsys):
    from shapeprog.__main__ import main

    with pytest.raises(ValueError, match="stop_after must be a number of seconds >= 0, got nan"):
        discover(Nodes([], [], []), stop_after=float("nan"))
    with pytest.raises(SystemExit) as e:
        main(["macros", "discover", "--category", "chair", "--stop-after", "nan", "--out", "unused"])
    assert e.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        "argument --stop-after: must be a number in [0, 3.16224e+07], got 'nan'")
