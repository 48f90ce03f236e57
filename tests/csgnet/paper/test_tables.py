"""The Table 3 / Table 5 evaluation (csgnet.paper.tables): its rows, the nearest-neighbour baseline and the
markdown layout."""
import pytest
import torch

import csgnet
from csgnet.models import CSGNet, preset
from csgnet.paper.tables import evaluate_model, markdown_tables, nearest_neighbour


def tiny(dim=2, stack=False):
    torch.manual_seed(0)
    return CSGNet(preset("small", dim, stack, hidden=16, embed=8, dropout=0.0, enc_dropout=0.0, channels=(2, 2, 2))).eval()


def test_evaluate_rows_and_nearest_neighbour():
    tests = {3: [csgnet.parse(t) for t in ["c(32,32,16)s(24,40,12)+", "t(32,32,20)c(32,32,8)-"]]}
    rows = evaluate_model(tiny(2), tests, beams=(1, 3), name="tiny", batch=2)
    names = [r.method for r in rows]
    assert names == ["tiny k=1 top-1", "tiny k=3 top-1", "tiny k=3 best-of-k (oracle)"]
    assert rows[2].iou[3] >= rows[1].iou[3] and rows[2].chamfer[3] <= rows[1].chamfer[3] + 1e-12
    train = [csgnet.parse("c(40,40,8)")] + tests[3]
    nn = nearest_neighbour(train, tests, 2)
    assert nn.iou[3] == pytest.approx(1.0) and nn.chamfer[3] == pytest.approx(0.0)
    md = markdown_tables([nn] + rows, 2, note="note")
    assert "| nearest neighbour | 100.00 | 100.00 | 0.000 |" in md and "Table 3" in md
