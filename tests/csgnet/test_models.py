"""CSGNet / CSGNetStack modules and their decoders."""
import pytest
import torch
import torch.nn.functional as F

import csgnet
from csgnet.decode import beam_search, greedy, sample
from csgnet.models import CSGNet, ModelConfig, preset, widen
from csgnet.renderer import stack_trace
from csgnet.vocab import vocabulary

TINY = dict(hidden=32, channels=(4, 4, 4), enc_dropout=0.0, dropout=0.0)


def tiny(dim=2, stack=False, seed=0, **kw):
    torch.manual_seed(seed)
    cfg = dict(TINY)
    if dim == 3:
        cfg.update(channels=(2, 2, 2), input_pool=4)
    cfg.update(kw)
    return CSGNet(preset("small", dim, stack, **cfg)).eval()


def targets(texts, dim=2):
    return torch.from_numpy(csgnet.render(texts, dim))


def test_paper_parameter_counts_match_the_reference():
    assert CSGNet(preset("paper", 2)).num_parameters() == 31_037_840
    assert CSGNet(preset("paper", 3)).num_parameters() == 36_562_243
    assert preset("paper", 2).feature_size == 2048 and preset("paper", 3).feature_size == 2048


def test_stack_preset_adds_k_input_channels():
    cfg = preset("paper", 2, stack=True)
    assert cfg.stack_k == 7 and cfg.in_channels == 8
    assert preset("paper", 3, stack=True).stack_k == 4
    conv = CSGNet(cfg).encoder.net[0]
    assert conv.in_channels == 8


def test_config_round_trip_and_errors():
    cfg = preset("small", 2, stack=True, hidden=64)
    assert ModelConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match="unknown model config"):
        ModelConfig.from_dict({"dim": 2, "bogus": 1})
    with pytest.raises(ValueError, match="preset"):
        preset("huge", 2)
    with pytest.raises(ValueError, match="dim"):
        ModelConfig(dim=4)


@pytest.mark.parametrize("dim,stack", [(2, False), (2, True), (3, False), (3, True)])
def test_forward_shapes(dim, stack):
    m = tiny(dim, stack)
    V = len(vocabulary(dim))
    B, T = 3, 5
    tgt = torch.zeros((B,) + (64,) * dim, dtype=torch.bool)
    tok = torch.randint(0, V + 1, (B, T))
    st = torch.zeros((T, B, m.config.stack_k) + (64,) * dim, dtype=torch.bool) if stack else None
    out = m(tgt, tok, st)
    assert out.shape == (B, T, V)
    with pytest.raises(ValueError, match="targets"):
        m(torch.zeros((B, 32, 32)), tok, st)
    if stack:
        with pytest.raises(ValueError, match="stack"):
            m(tgt, tok, None)


@pytest.mark.parametrize("stack", [False, True])
def test_logits_are_causal(stack):
    """The output at step t depends on inputs up to t only (what masking after '$' relies on)."""
    m = tiny(2, stack)
    tgt = targets(["c(32,32,16)", "s(24,24,12)"])
    tok = torch.randint(0, 401, (2, 6))
    st = torch.rand((6, 2, m.config.stack_k, 64, 64)) > 0.5 if stack else None
    a = m(tgt, tok, st)
    tok2 = tok.clone()
    tok2[:, 4:] = 7
    st2 = None
    if stack:
        st2 = st.clone()
        st2[4:] = ~st2[4:]
    b = m(tgt, tok2, st2)
    assert torch.equal(a[:, :4], b[:, :4])
    assert not torch.equal(a[:, 4:], b[:, 4:])


@pytest.mark.parametrize("stack", [False, True])
def test_beam_width_one_equals_greedy(stack):
    m = tiny(2, stack, seed=3)
    tgt = targets(["c(32,32,16)", "s(24,24,12)c(32,32,16)+", "t(32,32,20)"])
    g = greedy(m, tgt)
    b = beam_search(m, tgt, 1)
    assert torch.equal(g.tokens, b.tokens)
    assert torch.allclose(g.logprob, b.logprob, atol=1e-5)
    assert torch.equal(g.lengths, b.lengths)


def teacher_forced_logprob(m, tgt, tokens, length):
    """Sum of log-probabilities of tokens[:length] and the following '$' under teacher forcing."""
    stop = m.stop
    seq = torch.cat([tokens[:length], torch.tensor([stop])])
    tok_in = torch.cat([torch.tensor([m.start]), seq[:-1]])[None]
    st = None
    if m.config.stack:
        st = stack_trace(seq[None, :-1], 2, k=m.config.stack_k) if length else \
            torch.zeros((1, 1, m.config.stack_k, 64, 64), dtype=torch.bool)
    lp = F.log_softmax(m(tgt[None], tok_in, st), -1)[0]
    return float(lp.gather(1, seq[:, None]).sum())


@pytest.mark.parametrize("stack", [False, True])
def test_beam_scores_are_sorted_and_equal_teacher_forced_logprobs(stack):
    m = tiny(2, stack, seed=1)
    tgt = targets(["c(32,32,16)", "s(24,24,12)c(32,32,16)+"])
    d = beam_search(m, tgt, 4, max_len=5, constrained=True)
    assert (d.logprob[:, :-1] >= d.logprob[:, 1:] - 1e-6).all()
    assert d.valid.all()
    for i in range(2):
        for j in range(4):
            assert (d.tokens[i, j, int(d.lengths[i, j]):] == m.stop).all()  # only '$' after the program
    # unconstrained: the beam score equals the teacher-forced log-probability of program + '$' (a larger
    # '$' bias makes beams end before max_len, so the comparison runs; it is counted)
    with torch.no_grad():
        m.head[-1].bias[m.stop] += 1.0
    d = beam_search(m, tgt, 3, max_len=5)
    compared = 0
    for i in range(2):
        for j in range(3):
            n = int(d.lengths[i, j])
            if n < 5:
                got = teacher_forced_logprob(m, tgt[i], d.tokens[i, j], n)
                assert got == pytest.approx(float(d.logprob[i, j]), abs=1e-3)
                compared += 1
    assert compared >= 3


def test_finished_beams_stop_and_reference_mode_keeps_decoding():
    m = tiny(2, False, seed=2)
    # make '$' overwhelmingly likely at every step: the best beam is '$' at step 1, the two others take
    # one primitive at step 1 and '$' at step 2, and decoding stops there
    with torch.no_grad():
        m.head[-1].bias[m.stop] = 50.0
    tgt = targets(["c(32,32,16)"])
    d = beam_search(m, tgt, 3, max_len=6)
    assert d.tokens.shape[2] == 2 and d.lengths.tolist() == [[0, 1, 1]]
    assert (d.tokens[0, 1:, 1] == m.stop).all()
    # improved: the '$'-only hypothesis is kept once, its score is its own log-probability
    assert torch.isfinite(d.logprob[0, 0])
    r = beam_search(m, tgt, 3, max_len=6, mode="reference")
    assert r.tokens.shape[2] == 6  # decodes all steps
    assert r.logprob[0, 0] <= d.logprob[0, 0] + 1e-6  # later tokens keep adding (negative) log-probabilities


def test_constrained_decoding_only_yields_valid_programs():
    for stack in (False, True):
        m = tiny(2, stack, seed=5)
        tgt = targets(["c(32,32,16)", "t(32,32,20)s(32,32,12)-"])
        for max_len in (3, 7, 13):
            d = beam_search(m, tgt, 3, max_len=max_len, constrained=True)
            assert d.valid.all()
            for i in range(2):
                for j in range(3):
                    p = d.program(i, j)
                    assert csgnet.is_valid(p) and len(p) <= max_len


def test_stack_input_equals_the_renderer_stack_trace():
    """What CSGNetStack's encoder sees while decoding is the stack trace of the decoded prefix."""
    m = tiny(2, True, seed=4)
    seen = []
    orig = m.encode

    def spy(target, stack=None):
        seen.append(stack.clone())
        return orig(target, stack)

    m.encode = spy
    tgt = targets(["c(32,32,16)", "s(24,24,12)c(32,32,16)+", "t(32,32,20)c(32,40,8)-"])
    d = greedy(m, tgt, max_len=7, constrained=True)
    toks = d.tokens[:, 0]
    trace = stack_trace(toks, 2, k=m.config.stack_k, lengths=d.lengths[:, 0])
    for t, st in enumerate(seen):
        assert torch.equal(st, trace[t]), t
    assert len(seen) >= 3 and seen[0].sum() == 0  # the empty stack first


def test_beam_stack_follows_parents():
    """With beams, each row's stack is the trace of that row's own prefix after reordering."""
    m = tiny(2, True, seed=6)
    last = {}
    orig = m.encode

    def spy(target, stack=None):
        last["stack"] = stack.clone()
        return orig(target, stack)

    m.encode = spy
    tgt = targets(["s(24,24,12)c(32,32,16)+"])
    d = beam_search(m, tgt, 4, max_len=3, constrained=True)
    # the last encoder call saw the stacks after two tokens of each (pre-selection) beam; check by recomputing
    # every final beam's 2-token prefix trace is among the recorded states
    trace = stack_trace(d.tokens[0, :, :2], 2, k=m.config.stack_k)[2]
    rec = last["stack"]
    for j in range(4):
        assert any(torch.equal(trace[j], rec[r]) for r in range(rec.shape[0]))


def test_sample_keeps_gradients_and_counts_steps():
    m = tiny(2, True, seed=7)
    m.train()
    tgt = targets(["c(32,32,16)", "s(24,24,12)"])
    g = torch.Generator().manual_seed(0)
    s = sample(m, tgt, max_len=5, generator=g)
    assert s.log_probs.requires_grad
    loss = -(s.log_probs * s.counted).sum()
    loss.backward()
    assert m.head[-1].weight.grad is not None
    for i in range(2):
        n = int(s.lengths[i])
        c = int(s.counted[i].sum())
        assert c == (n + 1 if n < s.tokens.shape[1] else n)


def test_tiny_model_overfits_a_few_programs():
    """A few programs learned to exact greedy match in a couple of seconds."""
    torch.manual_seed(0)
    m = CSGNet(preset("small", 2, False, hidden=128, channels=(8, 8, 8), enc_dropout=0.0, dropout=0.0))
    vocab = vocabulary(2)
    texts = ["c(32,32,16)", "s(24,24,12)c(40,40,12)+", "t(32,32,20)c(32,40,8)-", "s(32,32,28)c(32,32,16)-"]
    L = 3
    tok = torch.full((4, L + 1), vocab.stop)
    lengths = torch.tensor([len(vocab.encode(t)) for t in texts])
    for i, t in enumerate(texts):
        e = vocab.encode(t)
        tok[i, : len(e)] = torch.tensor(e)
    tgt = targets(texts)
    tok_in = torch.cat([torch.full((4, 1), m.start), tok[:, :-1]], 1)
    steps = torch.arange(L + 1)[None] <= lengths[:, None]
    opt = torch.optim.Adam(m.parameters(), lr=3e-3)
    for _ in range(150):
        nll = F.cross_entropy(m(tgt, tok_in).transpose(1, 2), tok, reduction="none")
        loss = (nll * steps).sum() / 4
        opt.zero_grad()
        loss.backward()
        opt.step()
    m.eval()
    d = greedy(m, tgt, max_len=3)
    assert [d.text(i) for i in range(4)] == [vocab.text(vocab.encode(t)) for t in texts]


@pytest.mark.parametrize("stack", [False, True])
def test_3d_decoding(stack):
    m = tiny(3, stack, seed=0)
    tgt = targets(["sp(32,32,32,16)", "cu(32,32,32,20)sp(32,32,32,12)-"], dim=3)
    d = beam_search(m, tgt, 2, constrained=True)
    assert d.tokens.shape[:2] == (2, 2) and d.valid.all()
    assert all(csgnet.is_valid(csgnet.parse(t, 3)) for row in d.texts() for t in row)


# ---------------------------------------------------------------------------------------------
# the lite 3D encoder and the factored output layer

def test_token_attributes_share_types_centres_and_parameters():
    from csgnet.models import token_attributes
    vocab = vocabulary(3)
    index, n = token_attributes(3)
    assert index.shape[0] == len(vocab) and int(index.max()) == n
    row = lambda text: set(index[vocab.index(text)].tolist()) - {n}
    a, b = row("p(16,16,16,12)"), row("u(16,24,16,12)")
    # type, 3 centre values and 4 parameter values for a sphere; x and z centre values shared with the cube
    assert len(a) == 8 and len(a & b) == 2
    assert len(row("y(16,16,16,12,12)")) == 9
    ops = [row(t) for t in "+*-$"]
    assert all(len(r) == 1 for r in ops) and len(set().union(*ops)) == 4
    assert not any(r & a for r in ops)


@pytest.mark.parametrize("dim", [2, 3])
def test_factored_layer_starts_as_linear_and_applies_its_folded_weights(dim):
    from csgnet.models import FactoredLinear, token_attributes
    torch.manual_seed(0)
    layer = FactoredLinear(8, dim)
    x = torch.randn(5, 8)
    torch.testing.assert_close(layer(x), F.linear(x, layer.weight, layer.bias))
    with torch.no_grad():
        layer.attr_weight.normal_()
        layer.attr_bias.normal_()
    index, n = token_attributes(dim)
    t = 7
    attrs = [a for a in index[t].tolist() if a != n]
    w = layer.weight[t] + layer.attr_weight[attrs].sum(0)
    b = layer.bias[t] + layer.attr_bias[attrs].sum()
    torch.testing.assert_close(layer(x)[:, t], x @ w + b)
    with torch.no_grad():  # the cached fold follows an in-place change of a parameter
        first = layer(x).clone()
        layer.attr_bias[attrs[0]] += 1.0
        torch.testing.assert_close(layer(x)[:, t], first[:, t] + 1.0)


def test_factored_layer_gradients_match_finite_differences():
    from csgnet.models import FactoredLinear
    torch.manual_seed(1)
    layer = FactoredLinear(3, 3).double()
    x = torch.randn(2, 3, dtype=torch.float64)
    names = ("weight", "bias", "attr_weight", "attr_bias")

    def f(*params):
        return torch.func.functional_call(layer, dict(zip(names, params)), (x,)).sin().sum()

    params = tuple(getattr(layer, k).detach().clone().normal_().requires_grad_() for k in names)
    assert torch.autograd.gradcheck(f, params, fast_mode=True)


def test_lite_preset_decodes_like_any_model_and_keeps_the_side():
    cfg = preset("lite", 3)
    assert cfg.encoder == "lite" and cfg.head == "factored" and cfg.feature_side == 2
    assert cfg.feature_size == 64 * 8
    torch.manual_seed(0)
    m = CSGNet(preset("lite", 3, hidden=32, channels=(2, 2, 2, 2))).eval()
    t = targets(["sp(32,32,32,16)", "cu(24,24,24,12)"], dim=3)
    tokens_in = torch.tensor([[m.start, 5, 700], [m.start, 2000, 6631]])
    logits = m(t, tokens_in)
    proj, h, w = m.project_features(m.encode(t)), None, m.token_input_weight()
    for step in range(3):  # the decoders' projected step gives the teacher-forced logits
        out, h = m.step_projected(proj, tokens_in[:, step], h, w)
        torch.testing.assert_close(out, logits[:, step], atol=1e-5, rtol=1e-5)
    assert greedy(m, t).tokens.shape[:2] == (2, 1)
    with pytest.raises(ValueError, match="3D only"):
        ModelConfig(dim=2, encoder="lite")
    with pytest.raises(ValueError, match="head must be"):
        ModelConfig(dim=3, head="tied")


@pytest.mark.parametrize("dim", [2, 3])
def test_stack_decoders_skip_finished_rows_and_repeated_first_steps_exactly(dim, monkeypatch):
    """CSGNetStack decoding encodes a target's rows once at the first step and skips finished rows: the
    programs and scores equal those of encoding every row at every step."""
    from csgnet import decode
    from csgnet.renderer import unpack
    m = tiny(dim, stack=True, seed=3)
    texts = (["c(32,32,16)", "s(20,20,12)c(40,40,12)+", "c(32,32,24)s(32,32,12)-t(32,20,8)+"] if dim == 2 else
             ["sp(32,32,32,16)", "cu(24,24,24,12)sp(40,40,40,12)+"])
    t = targets(texts, dim)
    with torch.no_grad():
        m.head[-1].bias[m.stop] += 4.0  # programs end as soon as they may (constrained), at other steps in other beams
    fast = [decode.beam_search(m, t, 4, constrained=True), decode.greedy(m, t, constrained=True)]

    def every_row(self):
        return self.model.encode(self.targets, unpack(self.machine.top(self.model.config.stack_k), self.dim))

    monkeypatch.setattr(decode._Rows, "_stack_features", every_row)
    slow = [decode.beam_search(m, t, 4, constrained=True), decode.greedy(m, t, constrained=True)]
    for a, b in zip(fast, slow):
        assert torch.equal(a.tokens, b.tokens) and torch.equal(a.logprob, b.logprob)
        assert torch.equal(a.lengths, b.lengths) and torch.equal(a.valid, b.valid)
    assert (fast[0].lengths < fast[0].tokens.shape[-1]).any()  # some rows finished early


@pytest.mark.parametrize("dim,size,stack", [(3, "lite", False), (2, "small", True), (3, "small", False)])
def test_widen_keeps_every_output_and_trains_the_new_units(dim, size, stack):
    torch.manual_seed(0)
    small = CSGNet(preset(size, dim, stack, hidden=32, embed=16))
    channels = [c + 4 for c in small.config.channels]
    big = widen(small, preset(size, dim, stack, hidden=48, embed=16, channels=channels))
    assert big.config.hidden == 48 and big.config.channels == tuple(channels)
    small.eval(), big.eval()
    target = (torch.rand((3,) + (64,) * dim) > 0.7).float()
    tokens = torch.randint(0, small.config.vocab_size, (3, 5))
    st = None
    if stack:
        st = (torch.rand((5, 3, small.config.stack_k) + (64,) * dim) > 0.5).float()
    with torch.no_grad():
        assert torch.allclose(small(target, tokens, st), big(target, tokens, st), atol=1e-5)  # summation order only
    # the new hidden units' output weights start at zero and take a gradient at once
    big.train()
    head = big.head[-1]
    assert torch.count_nonzero(head.weight[:, 32:]) == 0
    big(target, tokens, st).logsumexp(-1).sum().backward()
    assert head.weight.grad[:, 32:].abs().sum() > 0


def test_widen_refuses_other_changes():
    small = CSGNet(preset("lite", 3, hidden=32))
    with pytest.raises(ValueError, match="only hidden and channels"):
        widen(small, preset("lite", 3, hidden=64, embed=64))
    with pytest.raises(ValueError, match="none narrower"):
        widen(small, preset("lite", 3, hidden=64, channels=(8, 16, 32)))  # a block fewer
    with pytest.raises(ValueError, match="none narrower"):
        widen(small, preset("lite", 3, hidden=16))
