"""The decoders' precision choice: float32, bfloat16 autocast, and "auto" (bfloat16 on a CPU with native bf16)."""
import numpy as np
import pytest
import torch

import csgnet
from csgnet import decode as D
from csgnet.cli import common
from csgnet.decode import PRECISIONS, beam_search, greedy, native_bf16, resolve_precision
from csgnet.inference import INFER_PRECISION, infer, load_pretrained, parse_shape
from csgnet.models import CSGNet, preset
from csgnet.synth import sample_programs
from csgnet.vocab import vocabulary


def tiny(stack: bool) -> CSGNet:
    torch.manual_seed(0)
    return CSGNet(preset("small", 2, stack, hidden=16, embed=8, dropout=0.0, enc_dropout=0.0,
                         channels=(2, 2, 2))).eval()


def synthetic_targets(per_length: int = 4, lengths=(3, 5, 7)) -> np.ndarray:
    rng = np.random.default_rng(7)
    texts = [vocabulary(2).text(r) for L in lengths for r in sample_programs(2, L, per_length, rng)]
    return csgnet.render(texts)


def test_the_choices_and_the_cli_mirror():
    assert PRECISIONS == ("auto", "float32", "bfloat16")
    assert common.PRECISIONS == PRECISIONS  # --help lists them without importing torch
    assert INFER_PRECISION in PRECISIONS


@pytest.mark.parametrize("bad", ["float16", "fp32", "", "AUTO", None, 32])
def test_a_bad_precision_is_refused_naming_it_and_the_choices(bad):
    msg = rf"precision must be one of auto, float32, bfloat16, got {bad!r}"
    image = csgnet.render("c(32,32,16)")[0]
    with pytest.raises(ValueError, match=msg.replace("(", r"\(").replace(")", r"\)")):
        resolve_precision(bad)
    with pytest.raises(ValueError, match="precision must be one of"):
        infer(tiny(False), image, beam=2, precision=bad)
    with pytest.raises(ValueError, match="precision must be one of"):
        parse_shape(image, model=tiny(False), beam=2, precision=bad)
    with pytest.raises(ValueError, match="precision must be one of"):
        beam_search(tiny(True), image[None], 2, precision=bad)


def test_auto_follows_the_cpu_check(monkeypatch):
    monkeypatch.setattr(D, "native_bf16", lambda: False)
    assert resolve_precision("auto") == "float32"
    monkeypatch.setattr(D, "native_bf16", lambda: True)
    assert resolve_precision("auto") == "bfloat16"
    assert resolve_precision("auto", "cuda") == "float32"  # GPUs decode in float32 unless asked
    assert resolve_precision("auto", "cpu", 3) == "float32"  # the 3D model gains nothing from bfloat16
    assert resolve_precision("bfloat16", "cpu", 3) == "bfloat16"  # unless asked
    assert resolve_precision("float32") == "float32" and resolve_precision("bfloat16", "cuda") == "bfloat16"


def test_the_native_check_is_guarded(monkeypatch):
    for name in D._NATIVE_BF16_CHECKS:
        monkeypatch.setattr(torch.cpu, name, lambda: False, raising=False)
    assert native_bf16() is False and resolve_precision("auto") == "float32"
    monkeypatch.setattr(torch.cpu, D._NATIVE_BF16_CHECKS[1], lambda: True, raising=False)
    assert native_bf16() is True

    def broken():
        raise RuntimeError("no cpuinfo")

    for name in D._NATIVE_BF16_CHECKS:
        monkeypatch.setattr(torch.cpu, name, broken, raising=False)
    assert native_bf16() is False
    for name in D._NATIVE_BF16_CHECKS:  # a torch without the checks
        monkeypatch.delattr(torch.cpu, name, raising=False)
    assert native_bf16() is False and resolve_precision("auto") == "float32"


def test_auto_without_native_bf16_decodes_exactly_as_float32(monkeypatch):
    monkeypatch.setattr(D, "native_bf16", lambda: False)
    m, shapes = tiny(True), synthetic_targets(2)
    a, b = infer(m, shapes, beam=3, precision="auto"), infer(m, shapes, beam=3, precision="float32")
    assert [r.beams for r in a] == [r.beams for r in b] and [r.score for r in a] == [r.score for r in b]


@pytest.mark.parametrize("stack", [False, True])
def test_bfloat16_scores_and_state_are_float32(stack):
    m, shapes = tiny(stack), torch.from_numpy(synthetic_targets(2))
    for dec in (beam_search(m, shapes, 3, precision="bfloat16", constrained=True),
                greedy(m, shapes, precision="bfloat16", constrained=True)):
        assert dec.logprob.dtype == torch.float32
        assert bool(torch.isfinite(dec.logprob).all()) and bool((dec.logprob <= 0).all())
        assert bool(dec.valid.all())
    rows = D._Rows(m, shapes.bool(), 1, 5, precision="bfloat16")
    logits, h = rows.logits()
    assert logits.dtype == torch.float32 and h.dtype == torch.float32
    assert next(m.parameters()).dtype == torch.float32  # autocast leaves the weights alone


def test_bfloat16_parses_as_well_as_float32_with_the_shipped_default():
    model, shapes = load_pretrained(2), synthetic_targets(4)
    got = {p: infer(model, shapes, beam=5, select="match", precision=p) for p in ("float32", "bfloat16")}
    for r in got["bfloat16"]:
        assert r.valid and csgnet.is_valid(r.program) and isinstance(r.score, float) and r.score <= 0
    iou = {p: float(np.mean([r.iou for r in rs])) for p, rs in got.items()}
    assert iou["float32"] > 0.9  # the shipped model parses these well ...
    assert abs(iou["bfloat16"] - iou["float32"]) < 0.03  # ... and bfloat16 as well as float32
    # the chosen beams' IoU is the IoU of their render: scoring is float32 in both
    for r, s in zip(got["bfloat16"], shapes):
        assert r.iou == pytest.approx(csgnet.metrics.iou(csgnet.render(r.text)[0], s))


def test_the_commands_precision_options():
    from csgnet.__main__ import build_parser

    ap = build_parser()
    assert ap.parse_args(["evaluate", "--data", "d"]).precision == "float32"  # the tables' protocol
    assert ap.parse_args(["evaluate", "--data", "d", "--precision", "bfloat16"]).precision == "bfloat16"
    assert ap.parse_args(["parse", "x.png"]).precision is None  # parse_shape's default, INFER_PRECISION
    assert ap.parse_args(["parse", "x.png", "--precision", "float32"]).precision == "float32"
    with pytest.raises(SystemExit):
        ap.parse_args(["parse", "x.png", "--precision", "half"])


def test_the_paper_experiments_decode_in_float32():
    from csgnet.__main__ import build_parser
    from csgnet.paper.experiments import EXPERIMENTS

    ap, evaluated = build_parser(), 0
    for e in EXPERIMENTS:
        for step in (e.steps or ()) + (e.quick or ()):
            args = ap.parse_args([a.replace("{out}", "t.json") for a in step.argv])
            assert getattr(args, "precision", "float32") == "float32", (e.id, step.argv)
            evaluated += args.cmd == "evaluate"
    assert evaluated >= 4  # Tables 3 and 5, full and quick


def test_the_stack_encoder_input_is_written_in_the_autocast_dtype_exactly():
    m = tiny(True)
    t = torch.from_numpy(synthetic_targets(1))
    stack = (torch.rand((t.shape[0], m.config.stack_k, 64, 64), generator=torch.Generator().manual_seed(0)) > 0.5)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        got = m.encode(t, stack.float())
        x = torch.cat([t[:, None].float(), stack.float()], 1).contiguous(memory_format=torch.channels_last)
        want = m.encoder(x)  # float32 input, cast by the first convolution
    assert got.dtype == torch.bfloat16 and torch.equal(got, want)
    with torch.no_grad():
        assert m.encode(t, stack.float()).dtype == torch.float32  # without autocast: the weights' dtype
