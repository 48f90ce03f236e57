"""The recognition network: value-rank tokens and their round trip, forward shapes and masks, a small overfit,
sampling under the type masks, checkpoints, and the wake with a network recovering planted SymRef / SymTrans."""
import concurrent.futures as cf
import multiprocessing

import pytest

import torch  # noqa: E402

from shapeprog.coder.dream import dream  # noqa: E402
from shapeprog.coder.execute import execute  # noqa: E402
from shapeprog.coder.objective import match  # noqa: E402
from shapeprog.coder.lang import Call, Library, ProgramError, parse, parse_abstraction, to_text, walk  # noqa: E402
from shapeprog.coder.recnet import NetConfig, RecognitionNet, load_checkpoint, sample, save_checkpoint  # noqa: E402
from shapeprog.coder.vocab import MAX_TOKENS, Vocab, decode_tokens, encode_scene, encode_target  # noqa: E402
from shapeprog.coder.train import BUCKET_GROUP, TrainConfig, batch_loss, batches, tensorize, train  # noqa: E402

LEGS = "SymRef(Move(Cuboid(0.06,0.5,0.06),-0.3,-0.25,-0.3),AX)"
SLATS = "SymTrans(Move(Cuboid(0.1,0.3,0.04),-0.3,0.4,0.3),AX,INT#3#,0.6)"


def _small(vocab, **kw):
    return RecognitionNet(NetConfig(len(vocab), token_dim=48, value_dim=16, heads=4, dropout=0.0, **kw))


def test_scene_ranks_are_indices_into_the_sorted_distinct_values():
    prims = [(0.1, 0.5, 0.1, -0.4, 0.0, 0.2, 0.0, 0.0, 0.0), (0.3, 0.5, 0.1, 0.4, 0.0, 0.2, 0.0, 0.0, 0.0)]
    sc = encode_scene(prims)
    assert sc.values == (-0.4, 0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
    assert sc.ranks.tolist() == [2, 6, 2, 0, 1, 3, 1, 1, 1, 4, 6, 2, 5, 1, 3, 1, 1, 1]
    assert sc.fields.tolist() == list(range(9)) * 2
    assert [sc.values[r] for r in sc.ranks] == [v for p in prims for v in p]


def test_tokens_round_trip_on_dreams():
    lib = Library().add(parse_abstraction("T(w: Float, d: Float) = SymTrans(Move(Cuboid(w,0.2,w),-0.5,0.0,0.0),"
                                          "AX,INT#2#,d)"))
    vocab = Vocab.of(lib)
    d = dream(lib, n=20, seed=5)
    n_sub = n_exact = 0
    for p in d.pairs:
        toks, ranks = encode_target(p.target, p.scene, vocab, lib)
        assert len(toks) == len(ranks) <= MAX_TOKENS - 1
        assert all((r >= 0) == (t == 1) for t, r in zip(toks, ranks))
        back = decode_tokens(toks, ranks, p.scene, vocab)
        if not p.moved:
            # every literal is a scene value, except SymTrans distances written Sub(last, first) (within 0.01)
            got, want = execute(back, lib), execute(p.target, lib)
            assert len(got) == len(want) and match(got, want, threshold=0.05).valid
            n_sub += vocab.index("Sub") in toks
            values = encode_scene(p.scene).values
            exact = all(n.value in values for n in walk(p.target) if type(n).__name__ == "Num")
            n_exact += exact
            if exact:  # every literal is exactly a scene value
                assert back == p.target
    assert n_sub > 0 and n_exact > 0
    with pytest.raises(ProgramError, match="ends inside"):
        decode_tokens(toks[:-1], ranks[:-1], d.pairs[-1].scene, vocab)
    with pytest.raises(ProgramError, match="not in the vocabulary"):
        encode_target(parse("Foo(0.1)", Library().add(parse_abstraction("Foo(a: Float) = Cuboid(a,a,a)"))),
                      d.pairs[0].scene, vocab)


def test_forward_shapes_causality_and_padding():
    vocab = Vocab.of(Library())
    torch.manual_seed(0)
    model = _small(vocab).eval()
    pairs = dream(Library(), n=3, seed=1).pairs[:3]
    b = tensorize(pairs, vocab, model.cfg.inputs)
    tl, vl = model(b.ranks, b.fields, b.cmask, b.tokens, b.tok_ranks)
    assert tl.shape == (3, MAX_TOKENS, len(vocab)) and vl.shape == (3, MAX_TOKENS, 144)
    # a later token does not change earlier outputs
    tok2 = b.tokens.clone()
    tok2[:, 5] = (tok2[:, 5] + 1) % len(vocab)
    tl2, _ = model(b.ranks, b.fields, b.cmask, tok2, b.tok_ranks)
    assert torch.allclose(tl[:, :5], tl2[:, :5], atol=1e-5) and not torch.allclose(tl[:, 5:], tl2[:, 5:])
    # padded slots do not matter
    r2 = b.ranks.clone()
    r2[~b.cmask] = 7
    tl3, _ = model(r2, b.fields, b.cmask, b.tokens, b.tok_ranks)
    assert torch.allclose(tl, tl3, atol=1e-5)
    with pytest.raises(ValueError, match="at most"):
        model(torch.zeros(1, 200, dtype=torch.long), torch.zeros(1, 200, dtype=torch.long),
              torch.ones(1, 200, dtype=torch.bool), b.tokens[:1], b.tok_ranks[:1])


def test_incremental_decoding_equals_decoding_the_whole_sequence():
    vocab = Vocab.of(Library())
    torch.manual_seed(0)
    model = _small(vocab).eval()
    scene = execute(parse(f"Union({LEGS},{SLATS})"))
    sc = encode_scene(scene)
    ranks, fields = torch.as_tensor(sc.ranks)[None], torch.as_tensor(sc.fields)[None]
    cmask = torch.ones_like(ranks, dtype=torch.bool)
    n, t = 3, 12
    g = torch.Generator().manual_seed(0)
    tokens = torch.randint(1, len(vocab), (n, t), generator=g)
    tokens[:, 0] = 0
    tok_ranks = torch.randint(0, len(sc.values), (n, t), generator=g)
    with torch.no_grad():
        conds = model.encode(ranks, fields, cmask)
        tl, vl = model.decode([c.expand(n, -1, -1) for c in conds], cmask.expand(n, -1), tokens, tok_ranks)
        cache = model.start(conds, n)
        for k in range(t):
            stl, svl = model.step(cache, k, tokens[:, k], tok_ranks[:, k])
            assert torch.allclose(stl, tl[:, k], atol=1e-5) and torch.allclose(svl, vl[:, k], atol=1e-5)
        with pytest.raises(ValueError, match="at most"):
            model.step(cache, model.cfg.max_tokens, tokens[:, 0], tok_ranks[:, 0])
    # sampling with the cache and by decoding the whole sequence at every step: the same samples
    a = sample(model, vocab, scene, n=16, generator=torch.Generator().manual_seed(4))
    b = sample(model, vocab, scene, n=16, generator=torch.Generator().manual_seed(4), incremental=False)
    assert [to_text(x) for x in a] == [to_text(x) for x in b] and len(a) == 16


def test_the_loss_cut_to_the_longest_scene_equals_the_padded_loss():
    vocab = Vocab.of(Library())
    torch.manual_seed(0)
    model = _small(vocab).eval()
    b = tensorize(dream(Library(), n=6, seed=2).pairs[:8], vocab, model.cfg.inputs)
    assert int(b.cmask.sum(1).max()) < model.cfg.inputs  # there is padding to cut
    t = int((b.targets != -100).sum(1).max())
    tl, vl = model(b.ranks, b.fields, b.cmask, b.tokens[:, :t], b.tok_ranks[:, :t])
    vl = vl.masked_fill(~(torch.arange(vl.shape[-1])[None] < b.n_values[:, None])[:, None, :], -1e9)
    ce = torch.nn.functional.cross_entropy
    full = ce(tl.reshape(-1, tl.shape[-1]), b.targets[:, :t].reshape(-1), ignore_index=-100) + ce(
        vl.reshape(-1, vl.shape[-1]), b.target_ranks[:, :t].reshape(-1), ignore_index=-100)
    assert torch.allclose(batch_loss(model, b), full, atol=1e-5)


def test_bucketed_batches_cover_every_pair_once_and_group_similar_lengths():
    g = torch.Generator().manual_seed(3)
    lengths = torch.randint(1, 145, (1000,), generator=g)
    for bucket in (True, False):
        bs = batches(lengths, 8, torch.Generator().manual_seed(1), bucket)
        got = torch.cat(bs)
        assert sorted(got.tolist()) == list(range(1000)) and all(len(b) <= 8 for b in bs)
        spread = sum(int(lengths[b].max() - lengths[b].min()) for b in bs) / len(bs)
        if bucket:  # sorted within groups of BUCKET_GROUP batches: a batch spans a few lengths only
            assert spread < 144 / BUCKET_GROUP * 2
        else:
            assert spread > 80
    a = batches(lengths, 8, torch.Generator().manual_seed(1))
    b = batches(lengths, 8, torch.Generator().manual_seed(1))
    assert all(torch.equal(x, y) for x, y in zip(a, b))  # determined by the generator


def test_a_handful_of_pairs_is_overfit_and_sampled_back(tmp_path):
    vocab = Vocab.of(Library())
    scene = execute(parse(f"Union({LEGS},{SLATS})"))
    pairs = [(scene, parse(LEGS)), (execute(parse(LEGS)), parse(LEGS)), (execute(parse(SLATS)), parse(SLATS))]
    torch.manual_seed(0)
    model = _small(vocab)
    b = tensorize(pairs, vocab, model.cfg.inputs)
    start = batch_loss(model, b).item()
    log = train(model, b, vocab, TrainConfig(lr=3e-3, batch=8, epochs=150, holdout=0.0, max_seconds=None),
                torch.Generator().manual_seed(0))
    assert log.train_loss[-1] < 0.05 < start
    greedy = sample(model, vocab, execute(parse(SLATS)), n=1)
    assert to_text(greedy[0]) == to_text(parse("SymTrans(Move(Cuboid(0.1,0.3,0.04),-0.3,0.4,0.3),AX,INT#3#,"
                                              "Sub(0.3,-0.3))"))
    # checkpoints round trip, and refuse another library's vocabulary
    save_checkpoint(tmp_path / "n.pt", model, vocab, {"k": 1})
    m2, v2, extra = load_checkpoint(tmp_path / "n.pt", Library())
    assert extra == {"k": 1} and v2 == vocab
    assert to_text(sample(m2.eval(), v2, execute(parse(SLATS)), n=1)[0]) == to_text(greedy[0])
    with pytest.raises(ValueError, match="vocabulary"):
        load_checkpoint(tmp_path / "n.pt", Library().add(parse_abstraction("Foo(a: Float) = Cuboid(a,a,a)")))


def test_samples_are_well_typed_and_floats_contain_a_variable():
    vocab = Vocab.of(Library())
    torch.manual_seed(1)
    model = _small(vocab).eval()
    scene = execute(parse(LEGS))
    values = set(encode_scene(scene).values)
    got = sample(model, vocab, scene, n=64, generator=torch.Generator().manual_seed(0))
    assert len(got) == 64
    for e in got:
        assert len(list(walk(e))) <= MAX_TOKENS - 1
        ops = ("Add", "Sub", "Mul", "Div", "Inv")
        for n in walk(e):  # every float expression filling a slot of a shape function
            if isinstance(n, Call) and n.fn not in ops:
                for a in n.args:
                    if isinstance(a, Call) and a.fn in ops:
                        leaves = [x for x in walk(a) if not isinstance(x, Call)]
                        assert len(leaves) <= 3 and any(getattr(x, "value", None) in values for x in leaves)


def _planted_model():
    vocab = Vocab.of(Library())
    scene = execute(parse(f"Union({LEGS},{SLATS})"))
    pairs = [(scene, parse(LEGS)), (scene, parse(SLATS)), (execute(parse(LEGS)), parse(LEGS)),
             (execute(parse(SLATS)), parse(SLATS))]
    torch.manual_seed(0)
    model = _small(vocab)
    train(model, pairs, vocab, TrainConfig(lr=3e-3, batch=8, epochs=150, holdout=0.0, max_seconds=None),
          torch.Generator().manual_seed(0))
    return model, vocab, scene


def test_wake_with_a_network_recovers_planted_symref_and_symtrans():
    from shapeprog.coder.config import Config
    from shapeprog.coder.wake import wake, wake_network
    from shapeprog.coder.search import search_shape

    model, vocab, scene = _planted_model()
    found = search_shape(scene, Library(), model, vocab, batch=16, batches=2, seconds=None, seed=0)
    assert sorted(f.expr.fn for f in found) == ["SymRef", "SymTrans"] and all(f.from_network for f in found)
    assert sorted(i for f in found for i in f.covered) == list(range(len(scene)))
    cfg = Config(wake_batch=16, wake_batches=2, wake_seconds=None)
    progs, costs, errors, stores, sources = wake_network([scene], None, Library(), model, vocab, None, cfg, seed=0)
    fns = {n.fn for n in walk(progs[0]) if isinstance(n, Call)}
    assert {"SymRef", "SymTrans"} <= fns and errors == [0.0] and sources == ["network"]
    assert execute(progs[0]) == scene
    ref_progs, ref_costs, _ = wake([scene], None, Library(), cfg)
    assert costs[0] < ref_costs[0]  # the rewrites never introduce a SymTrans
    assert any("SymTrans" in t for t in stores[0].values())
    # the executor path gives the same as in process (spawned workers: forking after torch ran can hang)
    with cf.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        got = wake_network([scene, scene], None, Library(), model, vocab, None, cfg, executor=ex, seed=0)
    assert [to_text(p) for p in got[0]] == [to_text(progs[0])] * 2 and got[1][0] == costs[0]
    # a second wake keeps the store and starts from the programs
    again = wake_network([scene], progs, Library(), model, vocab, stores, cfg, seed=1)
    assert again[1][0] <= costs[0] + 1e-9


def test_store_combines_pieces():
    from shapeprog.coder.search import Store, naive_piece, union

    scene = execute(parse(f"Union({LEGS},{SLATS})"))
    naive = union([naive_piece(p) for p in scene])
    store = Store(scene, Library())
    parts = store.add_program(naive)
    assert len(parts) == len(scene)
    legs = parse(LEGS)
    cov = tuple(i for i, p in enumerate(scene) if p in execute(legs))
    store.add(legs, cov)
    rebuilt = store.rebuild()
    assert execute(rebuilt) == scene and to_text(legs) in to_text(rebuilt)
    again = Store(scene, Library(), store.to_dict())
    assert again.to_dict() == store.to_dict()
    assert Store(scene, Library(), {"0": "Nope(1.0)", "x": "Cuboid(1.0,1.0,1.0)"}).items == {}


def test_discovery_with_the_network_wake_writes_and_reuses_its_checkpoint(tmp_path):
    import json

    from shapeprog.coder.discover import discover
    from shapeprog.coder.config import Config

    shapes = [execute(parse(f"Union({LEGS},{SLATS})")), execute(parse(LEGS))]
    cfg = Config(rounds=0, wake="network", n_dreams=8, train_epochs=1, wake_batch=8, wake_batches=1,
                 wake_seconds=None, device="cpu")
    lines = []
    r = discover(shapes, cfg, out=tmp_path, log=lines.append)
    assert (tmp_path / "recnet_round0.pt").is_file()
    st = json.loads((tmp_path / "state.json").read_text())
    assert st["phase"] == "done" and len(st["stores"]) == 2 and st["config"]["wake"] == "network"
    assert any(ln.startswith("dreams: SymRef: 8 dreams") for ln in lines)
    assert all(e == 0.0 for e in r.errors)
    # a run started again on a state before the wake reloads the round's network instead of training one
    st["phase"], st["round"] = "wake", 0
    (tmp_path / "state.json").write_text(json.dumps(st))
    lines.clear()
    r2 = discover(shapes, cfg, out=tmp_path, log=lines.append)
    assert any(ln.startswith("network: loaded") for ln in lines) and not any(ln.startswith("dreams") for ln in lines)
    assert r2.summary().F <= r.summary().F + 1e-9
    with pytest.raises(ValueError, match="wake"):
        Config(wake="dreams")


def test_discovery_defaults_train_with_the_papers_settings():
    # config.Config keeps torch-free copies of TrainConfig's defaults; they must stay the paper's
    from shapeprog.coder.config import Config
    from shapeprog.coder.train import PAPER

    assert Config().train_config() == PAPER


def test_post_hoc_inference_with_the_shipped_network_is_never_dearer_and_re_covers_the_shape():
    from shapeprog.coder import data, tables
    from shapeprog.coder.wake import evaluate
    from shapeprog.coder.infer import infer, load_library, load_network, shipped_networks

    assert "chair" in shipped_networks()
    lib, net = load_library("chair"), load_network("chair")
    rec = data.load("chair", "heldout")[1]
    plain = infer(rec.prims, lib)
    with_net = infer(rec.prims, lib, network=net, seed=0)
    assert with_net.cost <= plain.cost + 1e-9
    got = evaluate(parse(with_net.text, lib), lib, rec.prims)
    assert got is not None and abs(got[0] - with_net.cost) < 1e-9
    # Table 3's row with the network: never above the refactor-only row
    row = tables.phi("validation-PHI", [rec], lib, network=net)
    assert row.F <= tables.phi("x", [rec], lib).F + 1e-9 and row.shapes == 1
    with pytest.raises(ValueError, match="no shipped recognition network for 'sofa'"):
        load_network("sofa")


def test_the_post_hoc_search_budget_reaches_the_network_search_and_bad_budgets_are_refused(monkeypatch, capsys):
    import importlib

    from shapeprog.__main__ import main
    from shapeprog.coder import data, tables
    from shapeprog.coder.infer import infer, load_library, load_network
    from shapeprog.coder.search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS, WAKE_STEP_BUDGET

    coder_infer = importlib.import_module("shapeprog.coder.infer")  # the attribute infer is the function
    seen = []
    real = coder_infer.network_best

    def spy(current, library, prims, payload, limits, search=None, seed=0):
        seen.append(dict(search))
        return real(current, library, prims, payload, limits, search={**search, "batches": 1}, seed=seed)

    monkeypatch.setattr(coder_infer, "network_best", spy)
    lib, net = load_library("chair"), load_network("chair")
    rec = data.load("chair", "heldout")[1]
    infer(rec.prims, lib, network=net)
    infer(rec.prims, lib, network=net, search_seconds=3.5, search_batches=40, search_step_budget=300)
    assert seen == [{"batch": WAKE_BATCH, "batches": WAKE_BATCHES, "step_budget": WAKE_STEP_BUDGET,
                     "seconds": WAKE_SECONDS},
                    {"batch": WAKE_BATCH, "batches": 40, "step_budget": 300, "seconds": 3.5}]
    for bad in ({"search_seconds": 0}, {"search_seconds": float("nan")}, {"search_batches": 0},
                {"search_batches": 2.0}, {"search_seconds": True}, {"search_step_budget": 0}):
        with pytest.raises(ValueError, match="search_"):
            infer(rec.prims, lib, network=net, **bad)
    # Table 3 labels a larger budget as ours
    row = tables.phi("validation-PHI", [rec], lib, network=net, search_seconds=200.0, search_batches=20)
    assert seen[-1] == {"batch": WAKE_BATCH, "batches": 20, "step_budget": WAKE_STEP_BUDGET, "seconds": 200.0}
    assert row.shapes == 1
    run = tables.shipped("chair")
    text = tables.format_tables(run, tables.table2(run), [row], network=True, search_seconds=200.0, search_batches=20)
    assert (f"the search's budget {WAKE_STEP_BUDGET} units / at most 20 batches of 64 per step: ours, not the "
            "wake's, safety cap 200 s per step") in text
    assert "the wake's, standing for the paper's 1 s" in tables.format_tables(run, tables.table2(run), [row],
                                                                             network=True)
    # the commands pass it on, and refuse it without the network
    assert main(["coder", "infer", "coder-chair:402", "--library", "chair", "--network", "--search-seconds", "2.5",
                 "--search-batches", "8", "--search-step-budget", "50"]) == 0
    assert seen[-1] == {"batch": WAKE_BATCH, "batches": 8, "step_budget": 50, "seconds": 2.5}
    with pytest.raises(SystemExit, match="need --network"):
        main(["coder", "infer", "coder-chair:402", "--library", "chair", "--search-seconds", "2"])
    with pytest.raises(SystemExit, match="need --phi-network"):
        main(["coder", "tables", "--category", "chair", "--phi-search-batches", "4", "--train", "1", "--heldout", "1"])
    with pytest.raises(SystemExit):
        main(["coder", "infer", "coder-chair:402", "--library", "chair", "--network", "--search-seconds", "-1"])
    capsys.readouterr()


def test_network_from_a_later_round_and_repeated_wakes_resume_where_they_stopped(tmp_path):
    import json

    from shapeprog.coder.discover import discover
    from shapeprog.coder.config import Config

    shapes = [execute(parse(f"Union({LEGS},{SLATS})")), execute(parse(LEGS))]
    cfg = Config(rounds=1, n_proposals=50, n_abstractions=2, wake="network", network_from=1, wake_repeats=2,
                 n_dreams=8, train_epochs=1, wake_batch=8, wake_batches=1, wake_seconds=None, device="cpu")
    lines = []
    r = discover(shapes, cfg, out=tmp_path, log=lines.append)
    # round 0 used the refactor-only wake (no network), round 1 trained one network and woke twice with it
    assert not (tmp_path / "recnet_round0.pt").exists() and (tmp_path / "recnet_round1.pt").is_file()
    assert [(e["round"], e["phase"]) for e in r.log] == [(0, "wake"), (0, "integrate"), (1, "wake"), (1, "wake")]
    assert r.log[3]["F"] <= r.log[2]["F"] + 1e-9
    assert sum(ln.startswith("dreams:") for ln in lines) >= 1
    assert any(" wake 1/2:" in ln for ln in lines) and any(" wake 2/2:" in ln for ln in lines)
    st = json.loads((tmp_path / "state.json").read_text())
    assert st["phase"] == "done" and st["repeat"] == 0 and st["config"]["wake_repeats"] == 2
    # a state saved after the first of the two wakes resumes with the second only, with the saved network
    st.update(phase="wake", round=1, repeat=1, log=st["log"][:3])
    (tmp_path / "state.json").write_text(json.dumps(st))
    lines.clear()
    r2 = discover(shapes, cfg, out=tmp_path, log=lines.append)
    assert any(ln.startswith("network: loaded") for ln in lines)
    assert any(" wake 2/2:" in ln for ln in lines) and not any(" wake 1/2:" in ln for ln in lines)
    assert [(e["round"], e["phase"]) for e in r2.log] == [(0, "wake"), (0, "integrate"), (1, "wake"), (1, "wake")]
    assert all(e == 0.0 for e in r2.errors)
    for bad in ({"wake_repeats": 0}, {"network_from": -1}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            Config(**bad)


def test_targets_left_out_of_training_are_counted_by_kind():
    import pickle
    from collections import Counter

    from shapeprog.coder.vocab import TargetError

    vocab = Vocab.of(Library())
    prims = [(1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)]
    ok = parse("Cuboid(1.0,1.0,1.0)", Library())
    long_ = "Cuboid(1.0,1.0,1.0)"
    for _ in range(12):  # each Move adds 4 tokens: 49 in all, over MAX_TOKENS
        long_ = f"Move({long_},0.0,0.0,0.0)"
    other = Library().add(parse_abstraction("Foo(a: Float) = Cuboid(a,a,a)"))
    unknown = parse("Foo(1.0)", other)
    skipped = Counter()
    b = tensorize([(prims, ok), (prims, parse(long_, Library())), (prims, parse(long_, Library())),
                   (prims, unknown)], vocab, 64, None, skipped)
    assert len(b.ranks) == 1
    assert skipped == Counter({"target over MAX_TOKENS": 2, "token not in the vocabulary": 1})
    e = pickle.loads(pickle.dumps(TargetError("m", "target over MAX_TOKENS")))
    assert isinstance(e, ProgramError) and str(e) == "m" and e.reason == "target over MAX_TOKENS"
