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


def test_table_result_and_the_refined_row():
    from shapeio.results import markdown, read_result, write_result
    from csgnet.paper.tables import evaluate_refined, table_result

    tests = {3: [csgnet.parse(t) for t in ["c(32,32,16)s(24,40,12)+", "t(32,32,20)c(32,32,8)-"]]}
    nn = nearest_neighbour([csgnet.parse("c(40,40,8)")] + tests[3], tests, 2)
    refined = evaluate_refined(tiny(2), tests, beam=2, name="tiny", per_length=1)
    assert refined.method == "tiny k=2 + refinement (short)" and refined.count == {3: 1}
    # the whole parse: what parse_shape gives for the first target
    got = csgnet.parse_shape(csgnet.render(tests[3][0].text())[0], model=tiny(2), beam=2)
    assert refined.iou[3] == pytest.approx(got.refined.after[0])
    result = table_result([nn, refined], 2, ["a note"], command="python -m csgnet evaluate --dim 2")
    assert [c["key"] for c in result["columns"]] == ["method", "iou_len3", "iou", "chamfer", "ms"]
    assert result["rows"][0]["iou"] == pytest.approx(1.0) and result["notes"][0] == "Test programs per length: len 3: 2."
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory() as d:
        back = read_result(write_result(Path(d) / "t.json", result))
    assert "| nearest neighbour | 100.00 | 100.00 | 0.000 |" in markdown(back)
