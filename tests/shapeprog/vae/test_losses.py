"""Losses: each term against a hand computation, the weights, the KL without the 1/2, the leaf mean."""
import math

import pytest
import torch
import torch.nn.functional as F

from shapeprog.lang import parse
from shapeprog.vae.losses import LINE_TERMS, LOSS_WEIGHTS, kl_loss, leaf_loss, line_losses, program_loss
from shapeprog.vae.model import VAE
from shapeprog.vae.vectors import program_to_tree

def test_weights_of_the_spec():
    assert LOSS_WEIGHTS == {"cmd": 1, "cub_prm": 50, "xyz_prm": 50, "uv_prm": 50, "sym_prm": 50, "cub": 1,
                            "sym_cub": 1, "sq_cub": 1, "axis": 1, "face": 1, "align": 1, "leaf": 1, "bb": 50,
                            "kl": 0.1}


def test_perfect_prediction_costs_only_the_softmax_floor(two_levels):
    tree = program_to_tree(parse(two_levels))
    tar = tree.target_seq()
    pred = tar * 100.0  # one-hots become confident logits; the continuous entries are copied back
    for part in (slice(40, 49), slice(52, 54), slice(60, 62)):
        pred[:, part] = tar[:, part]
    pred[:, 62] = (tar[:, 62] * 2 - 1) * 100
    terms = line_losses(pred, tar)
    assert set(terms) == set(LINE_TERMS)
    assert all(v.item() == pytest.approx(0.0, abs=1e-6) for v in terms.values())


def test_each_term_against_a_hand_computation(two_levels):
    tree = program_to_tree(parse(two_levels))
    tar = tree.target_seq()  # rows: bbox, Program_1, cube1, attach, squeeze, reflect, stop
    torch.manual_seed(0)
    pred = torch.randn_like(tar)
    t = line_losses(pred, tar)
    ce = lambda rows, part: F.cross_entropy(pred[rows, part], tar[rows, part].argmax(1), reduction="sum")  # noqa: E731
    assert t["cmd"] == pytest.approx(ce(list(range(7)), slice(0, 7)).item())
    assert t["cub_prm"] == pytest.approx((pred[:3, 40:43] - tar[:3, 40:43]).abs().sum().item())
    assert t["xyz_prm"] == pytest.approx((pred[3, 43:49] - tar[3, 43:49]).abs().sum().item())
    assert t["uv_prm"] == pytest.approx((pred[4, 60:62] - tar[4, 60:62]).abs().sum().item())
    assert t["sym_prm"].item() == 0.0  # no translate in the root
    assert t["cub"] == pytest.approx((ce([3], slice(7, 18)) + ce([3], slice(18, 29))).item())
    assert t["sq_cub"] == pytest.approx(sum(ce([4], s) for s in (slice(7, 18), slice(18, 29), slice(29, 40))).item())
    assert t["face"] == pytest.approx(ce([4], slice(54, 60)).item())
    assert t["sym_cub"] == pytest.approx(ce([5], slice(7, 18)).item())
    assert t["axis"] == pytest.approx(ce([5], slice(49, 52)).item())
    # align: Cuboid lines but the first; targets False (Program_1) and True (cube1); positives weigh 0.2
    x1, x2 = pred[1, 62].item(), pred[2, 62].item()
    sp = lambda v: math.log1p(math.exp(v))  # noqa: E731  softplus
    assert t["align"] == pytest.approx(sp(x1) + 0.2 * sp(-x2), rel=1e-5)
    child = tree.children[1].target_seq()  # rows: bbox, cube0, attach, translate, stop
    pc = torch.randn_like(child)
    tc = line_losses(pc, child)
    cc = lambda rows, part: F.cross_entropy(pc[rows, part], child[rows, part].argmax(1), reduction="sum")  # noqa: E731
    # the translate's count and distance (slots 52, 53), its cube and axis; the two Cuboid lines' dims
    assert child[3, 52:54].tolist() == pytest.approx([2.0, 0.8])
    assert tc["sym_prm"] == pytest.approx((pc[3, 52:54] - child[3, 52:54]).abs().sum().item())
    assert tc["sym_cub"] == pytest.approx(cc([3], slice(7, 18)).item())
    assert tc["axis"] == pytest.approx(cc([3], slice(49, 52)).item())
    assert tc["cub_prm"] == pytest.approx((pc[:2, 40:43] - child[:2, 40:43]).abs().sum().item())
    assert tc["uv_prm"].item() == 0.0 and tc["sq_cub"].item() == 0.0 and tc["face"].item() == 0.0


def test_kl_has_no_half_and_leaf_is_a_mean():
    mu, logvar = torch.tensor([1.0, 0.0]), torch.tensor([0.0, math.log(2.0)])
    assert kl_loss(mu, logvar).item() == pytest.approx(1.0 + (2.0 - 1.0 - math.log(2.0)))
    logits, target = torch.tensor([2.0, -1.0, 0.5]), torch.tensor([1.0, 0.0, 1.0])
    expected = (math.log1p(math.exp(-2.0)) + math.log1p(math.exp(-1.0)) + math.log1p(math.exp(-0.5))) / 3
    assert leaf_loss(logits, target).item() == pytest.approx(expected)


def test_program_loss_sums_nodes_and_weights_terms(two_levels):
    torch.manual_seed(0)
    tree = program_to_tree(parse(two_levels))
    vae = VAE(16)
    out = vae(tree, sample=False)
    total, terms = program_loss(out, tree)
    assert set(terms) == set(LOSS_WEIGHTS)
    nodes = [n for n, _ in tree.nodes()]
    for k in LINE_TERMS:
        assert terms[k].item() == pytest.approx(sum(line_losses(o.lines, n.target_seq())[k].item()
                                                    for o, n in zip(out.nodes, nodes)), rel=1e-5)
    # root: bbox leaf, Program_1 not a leaf, cube1 leaf; child: both leaves
    leaf = leaf_loss(out.nodes[0].leaf, torch.tensor([1.0, 0.0, 1.0])) + leaf_loss(out.nodes[1].leaf, torch.ones(2))
    assert terms["leaf"].item() == pytest.approx(leaf.item())
    assert terms["bb"].item() == pytest.approx((out.bbox_dims - torch.tensor([1.2, 1.0, 0.8])).abs().sum().item())
    assert total.item() == pytest.approx(sum(LOSS_WEIGHTS[k] * v.item() for k, v in terms.items()), rel=1e-5)
    total_nokl, t2 = program_loss(out, tree, kl=False, weights={"bb": 1.0})
    assert t2["kl"].item() == 0.0 and total_nokl.item() == pytest.approx(terms["bb"].item())
    with pytest.raises(ValueError, match="the output has 2 nodes, the tree 1"):
        program_loss(out, tree.children[1])
    with pytest.raises(ValueError, match=r"must both be \(T, 63\)"):
        line_losses(torch.zeros(3, 63), torch.zeros(4, 63))
