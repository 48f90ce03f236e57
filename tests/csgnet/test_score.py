"""Scoring rendered programs against targets (csgnet.score): exact values of the 2D/3D IoU and chamfer,
the beams' scores equal scoring each beam's render, and the IoU nearest-neighbour search equals brute force."""
import numpy as np
import pytest
import torch

import csgnet
from csgnet import metrics
from csgnet.decode import Decoded
from csgnet.score import best_iou_matches, score_beams, score_renders
from csgnet.vocab import vocabulary


def test_score_renders_exact_values_2d_and_3d():
    a = torch.zeros(2, 64, 64, dtype=torch.bool)
    b = torch.zeros(2, 64, 64, dtype=torch.bool)
    a[0, 10:20, 10:20] = True  # 100 pixels
    b[0, 10:20, 15:25] = True  # 50 shared, union 150
    iou, cd = score_renders(a, b, 2)
    assert iou[0] == pytest.approx(50 / 150) and iou[1] == 0.0  # both empty: NaN read as 0
    assert cd[0] == pytest.approx(float(metrics.chamfer(a[0], b[0])))
    v = torch.zeros(1, 64, 64, 64, dtype=torch.bool)
    v[0, :2, :2, :2] = True  # 8 voxels, equal: 8 / (8 + 1)
    iou3, cd3 = score_renders(v, v, 3)
    assert iou3[0] == pytest.approx(8 / 9) and np.isnan(cd3[0])


def test_score_beams_scores_every_beam_against_its_target():
    vocab = vocabulary(2)
    texts = [["c(32,32,16)", "s(32,32,16)"], ["t(32,32,20)", "c(32,32,8)"]]
    tokens = torch.full((2, 2, 4), vocab.stop, dtype=torch.long)
    lengths = torch.ones(2, 2, dtype=torch.long)
    for i, row in enumerate(texts):
        for j, t in enumerate(row):
            tokens[i, j, 0] = vocab.index(t)
    dec = Decoded(tokens=tokens, lengths=lengths, logprob=torch.zeros(2, 2), valid=torch.ones(2, 2, dtype=torch.bool),
                  dim=2)
    targets = torch.from_numpy(csgnet.render(["c(32,32,16)", "c(32,32,8)"]))
    renders, iou, cd = score_beams(dec, targets)
    assert renders.shape == (4, 64, 64)
    want = [[score_renders(torch.from_numpy(csgnet.render(t)), targets[i:i + 1], 2) for t in row]
            for i, row in enumerate(texts)]
    assert iou[0, 0] == 1.0 and iou[1, 1] == 1.0
    for i in range(2):
        for j in range(2):
            assert iou[i, j] == pytest.approx(want[i][j][0][0]) and cd[i, j] == pytest.approx(want[i][j][1][0])


@pytest.mark.parametrize("plus", [0.0, 1.0])
def test_best_iou_matches_equals_brute_force_over_chunks(plus):
    g = torch.Generator().manual_seed(0)
    queries = torch.rand(7, 8, 8, generator=g) > 0.6
    cands = torch.rand(23, 8, 8, generator=g) > 0.6
    got = best_iou_matches(queries, ((lo, cands[lo:lo + 5]) for lo in range(0, 23, 5)), plus=plus)
    q, c = queries.reshape(7, -1).float(), cands.reshape(23, -1).float()
    inter = q @ c.T
    union = q.sum(1)[:, None] + c.sum(1)[None] - inter + plus
    want = torch.where(union > 0, inter / union.clamp(min=1e-9), torch.zeros_like(inter)).argmax(1)
    assert torch.equal(got, want)


def test_best_iou_matches_hand_computed_case_and_ties_go_to_the_lowest_index():
    q = torch.zeros(1, 4, 4, dtype=torch.bool)
    q[0, 0, :4] = True  # 4 pixels
    c = torch.zeros(4, 4, 4, dtype=torch.bool)
    c[0, 0, :2] = True  # IoU 2/4
    c[1, 0, :4] = True
    c[1, 1, :4] = True  # IoU 4/8, ties with 0
    c[2, 0, :3] = True  # IoU 3/4: the best
    c[3, 3, :] = True  # disjoint: 0
    assert best_iou_matches(q, [(0, c[:2]), (2, c[2:])]).tolist() == [2]
    assert best_iou_matches(q, [(0, c[:2])]).tolist() == [0]
    assert best_iou_matches(q, [(0, c[3:])], plus=1.0).tolist() == [0]  # all zero: the first candidate
