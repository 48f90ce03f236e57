"""Table 4 and Table 6 protocols: detection AP on hand-made cases, primitive boxes, Table 4 invariants, CLI."""
import numpy as np
import pytest
import torch

import csgnet
from csgnet.decode import Decoded
from csgnet.lang import Draw
from csgnet.primitives import square_bounds
from csgnet.paper.protocols import (average_precision, beam_detections, box_iou, detection_ap, nearest_silhouettes,
                              primitive_boxes, subset, table4, table4_markdown, table6, table6_markdown)
from csgnet.vocab import vocabulary


def test_box_iou_counts_pixels():
    a = [(0, 0, 1, 1)]
    assert box_iou(a, a)[0, 0] == 1.0
    assert box_iou(a, [(0, 1, 1, 2)])[0, 0] == pytest.approx(2 / 6)  # one shared column of 2 pixels
    assert box_iou(a, [(5, 5, 6, 6)])[0, 0] == 0.0
    assert box_iou([(0, 0, 9, 9)], [(0, 0, 4, 9), (0, 0, 9, 9)]).tolist() == [[0.5, 1.0]]


def test_primitive_boxes_are_the_pixel_extent_of_each_primitive():
    c, s, t = Draw("c", (32, 32, 8)), Draw("s", (20, 40, 12)), Draw("t", (40, 24, 16))
    boxes = primitive_boxes([c, s, t])
    assert boxes[c] == (25, 25, 39, 39)  # strict d^2 < r^2: rows and columns y-r+1 .. y+r-1
    r0, r1, c0, c1 = (int(v) for v in square_bounds(20, 40, 12))
    assert boxes[s] == (r0, c0, r1, c1)
    img = csgnet.render("t(40,24,16)")[0]
    rows, cols = np.flatnonzero(img.any(1)), np.flatnonzero(img.any(0))
    assert boxes[t] == (rows[0], cols[0], rows[-1], cols[-1])
    cache = {}
    primitive_boxes([c], cache)
    assert cache == {c: boxes[c]}


def test_average_precision_hand_made_cases():
    gt = {0: [(0, 0, 9, 9)], 1: [(20, 20, 29, 29)]}
    perfect = [(0, 0.9, (0, 0, 9, 9)), (1, 0.5, (20, 20, 29, 29))]
    assert average_precision(perfect, gt) == 1.0
    # TP 0.9, FP 0.8, TP 0.7: precision 1 at recall 1/2, then 2/3 at recall 1
    ranked = [(0, 0.9, (0, 0, 9, 9)), (0, 0.8, (40, 40, 49, 49)), (1, 0.7, (20, 20, 29, 29))]
    assert average_precision(ranked, gt) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    # a second detection of the same object is a false positive
    dup = [(0, 0.9, (0, 0, 9, 9)), (0, 0.8, (0, 0, 9, 9))]
    assert average_precision(dup, gt) == pytest.approx(0.5)
    # IoU threshold: half the box overlaps (IoU exactly 0.5) counts, a little less does not
    assert average_precision([(0, 1.0, (0, 0, 4, 9))], {0: [(0, 0, 9, 9)]}) == 1.0
    assert average_precision([(0, 1.0, (0, 0, 4, 8))], {0: [(0, 0, 9, 9)]}) == 0.0
    assert average_precision([(0, 1.0, (0, 0, 4, 8))], {0: [(0, 0, 9, 9)]}, iou_threshold=0.4) == 1.0
    # detections in the wrong image never match; no ground truth gives NaN
    assert average_precision([(1, 1.0, (0, 0, 9, 9))], {0: [(0, 0, 9, 9)]}) == 0.0
    assert np.isnan(average_precision(perfect, {}))


def test_detection_ap_is_one_for_the_true_primitives_and_types_are_separate():
    progs = [csgnet.parse(t) for t in ("c(32,32,8)s(16,16,8)+", "t(40,40,16)c(24,24,8)-", "s(32,32,16)")]
    truths = [p.draws for p in progs]
    perfect = [{d: 1.0 for d in p.draws} for p in progs]
    ap = detection_ap(perfect, truths)
    assert ap == {"circle": 1.0, "square": 1.0, "triangle": 1.0}
    # the right boxes with the wrong type are false positives of that type and miss the others
    swapped = [{Draw({"c": "s", "s": "t", "t": "c"}[d.kind], d.params): 1.0 for d in p.draws} for p in progs]
    ap = detection_ap(swapped, truths)
    assert all(v < 1.0 for v in ap.values())
    with pytest.raises(ValueError, match="detection sets"):
        detection_ap(perfect[:2], truths)


def test_beam_detections_score_is_the_share_of_beams_containing_the_primitive():
    vocab = vocabulary(2)
    beams = ["c(32,32,8)s(16,16,8)+", "c(32,32,8)", "c(32,32,8)c(32,32,8)+", "t(40,40,16)"]
    T = 4
    tok = torch.full((1, 4, T), vocab.stop)
    for j, b in enumerate(beams):
        ids = vocab.encode(b)
        tok[0, j, : len(ids)] = torch.tensor(ids)
    lengths = (tok != vocab.stop).sum(-1)
    logprob = torch.tensor([[-1.0, -2.0, -3.0, float("-inf")]])  # the last slot never held a hypothesis
    dec = Decoded(tok, lengths, logprob, torch.ones(1, 4, dtype=torch.bool), 2)
    det = beam_detections(dec)[0]
    assert det == {Draw("c", (32, 32, 8)): 0.75, Draw("s", (16, 16, 8)): 0.25}


def test_subset_is_sorted_deterministic_and_bounded():
    a = subset(100, 10, seed=3)
    assert len(a) == 10 and len(set(a)) == 10 and (np.diff(a) > 0).all() and a.max() < 100
    assert np.array_equal(a, subset(100, 10, seed=3)) and not np.array_equal(a, subset(100, 10, seed=4))
    assert np.array_equal(subset(5, None), np.arange(5)) and np.array_equal(subset(5, 50), np.arange(5))


def test_nearest_silhouette_finds_an_identical_image():
    imgs = csgnet.render(["c(32,32,16)", "s(24,40,12)", "t(40,24,16)", "c(20,20,8)"])
    train = imgs[[3, 0, 2]]
    assert nearest_silhouettes(train, imgs[[0, 2]], chunk=2).tolist() == [1, 2]


def test_table4_on_three_images_runs_and_refinement_never_worsens():
    from csgnet.inference import load_pretrained
    from csgnet.shapes2d import load_silhouettes

    test = load_silhouettes("test")[:3]
    train = np.concatenate([load_silhouettes("train")[:50], test[1:2]])  # test image 1 is its own neighbour
    model = load_pretrained(2)
    rows = table4([("shipped", model)], test, train, beams=(1, 3), iterations=(0, 1, 2, None))
    nn, k1, k3 = rows
    assert nn.method == "nearest neighbour" and nn.per_image[0][1] == 0.0 and list(nn.chamfer) == [0]
    assert k1.protocol == "k=1" and k3.protocol.startswith("k=3 best-of-k")
    for row in (k1, k3):
        assert list(row.chamfer) == [0, 1, 2, None]
        cds = np.stack([row.per_image[i] for i in (0, 1, 2, None)])
        assert cds.shape == (4, 3)
        assert (np.diff(cds, axis=0) <= 0).all()  # more iterations never give a worse program
        assert row.chamfer[0] == pytest.approx(cds[0].mean())
        assert row.decode_seconds > 0 and set(row.refine_seconds) == {1, 2, None}
    # unrefined best-of-k equals the chamfer distance of the chosen beam, computed from scratch
    from csgnet.decode import beam_search
    from csgnet.renderer import render_tokens

    dec = beam_search(model, torch.from_numpy(test), 3)
    pred = render_tokens(dec.flat_tokens(), 2, dec.lengths.flatten())
    cd = np.asarray(csgnet.metrics.chamfer(pred, np.repeat(test, 3, 0))).reshape(3, 3)
    assert np.array_equal(k3.per_image[0], cd.min(1))
    md = table4_markdown(rows, "note", (0, 1, 2, None))
    assert "| shipped | k=1 |" in md and "CD ∞ it." in md and "1.38" in md and md.rstrip().endswith("note")


def test_table6_runs_on_a_few_programs():
    from csgnet.inference import load_pretrained

    progs = [csgnet.parse(t) for t in ("c(32,32,16)", "s(24,40,12)t(40,24,16)+", "c(32,32,24)s(32,32,16)-")]
    rows = table6(load_pretrained(2), progs, beams=(2, 4))
    assert [r.k for r in rows] == [2, 4]
    for r in rows:
        assert r.images == 3 and r.images_per_second > 0
        assert set(r.ap) == {"circle", "square", "triangle"}
        assert all(0.0 <= v <= 1.0 for v in r.ap.values())
    md = table6_markdown(rows)
    assert "| 2 |" in md and "paper mAP" in md
    with pytest.raises(ValueError, match="at least one"):
        table6(load_pretrained(2), [], beams=(2,))


def test_cli_writes_both_tables(tmp_path, capsys):
    from csgnet.__main__ import main

    out4, out6 = tmp_path / "t4.md", tmp_path / "t6.md"
    assert main(["table4", "--images", "2", "--beams", "1", "--iterations", "0", "1", "--no-nn",
                 "--out", str(out4)]) == 0
    text = out4.read_text()
    # no --weights: the four shipped 2D models, supervised and RL-tuned
    for label in ("CSGNet supervised", "CSGNet RL", "CSGNetStack supervised", "CSGNetStack RL"):
        assert f"| {label} | k=1 |" in text
    assert "2 of 1386 test silhouettes" in text
    assert "python -m csgnet table4 --images 2" in text
    assert main(["table6", "--per-length", "2", "--lengths", "3", "--beams", "2", "--out", str(out6)]) == 0
    text = out6.read_text()
    assert "| 2 |" in text and "sampled with seed 0" in text
    # where and when the times were measured
    import datetime
    import os

    today = datetime.date.today()
    days = {(today - datetime.timedelta(days=k)).isoformat() for k in (0, 1)}  # a run across midnight
    for t in (text, out4.read_text()):
        assert "times measured on " in t and f"{os.cpu_count()} CPUs" in t and any(d in t for d in days)
