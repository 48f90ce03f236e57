"""Validation values gathered per epoch and logged with sync_dist; image grids of targets beside predictions."""
import numpy as np
import torch

from csgnet.train.logs import EpochValues, image_grid, log_means, log_pairs


class _Module:
    """What the helpers use of a LightningModule: ``log``, ``logger`` and ``global_step``."""

    global_step = 7

    def __init__(self, logger=None):
        self.logger, self.logged = logger, []

    def log(self, name, value, **kw):
        self.logged.append((name, value, kw))


class _TensorBoard:
    def __init__(self):
        self.images = []

    def add_image(self, tag, image, step):
        self.images.append((tag, tuple(image.shape), step))


def test_epoch_values_concatenate_batches_and_keep_the_first_pairs():
    v = EpochValues(images=3)
    assert not v
    a, b = torch.zeros(2, 64, 64, dtype=torch.bool), torch.ones(2, 64, 64, dtype=torch.bool)
    v.add(a, b, iou=np.array([0.5, 1.0]), loss=3.0)
    v.add(b, a, iou=np.array([0.0, 0.25]), loss=1.0)
    assert v
    cat = v.arrays()
    assert cat["iou"].tolist() == [0.5, 1.0, 0.0, 0.25] and cat["loss"].tolist() == [3.0, 1.0]
    assert torch.equal(v.grid[0], a) and torch.equal(v.grid[1], b)  # the first batch's pairs only
    assert EpochValues(images=0).grid is None


def test_means_are_logged_with_sync_dist():
    m = _Module()
    log_means(m, {"val/reward": np.float64(0.5), "val/length": 4}, prog_bar=("val/reward",))
    assert m.logged == [("val/reward", 0.5, {"prog_bar": True, "sync_dist": True}),
                        ("val/length", 4.0, {"prog_bar": False, "sync_dist": True})]
    assert all(type(value) is float for _, value, _ in m.logged)


def test_pairs_go_to_an_image_logger_and_3d_shows_silhouettes():
    t = torch.zeros(5, 64, 64, dtype=torch.bool)
    assert image_grid(t, t, cols=4).shape == (1, 2 * 66, 4 * 130)
    assert not log_pairs(_Module(), "val/x", t, t)  # no logger: nothing to do
    tb = _TensorBoard()
    m = _Module(logger=type("Logger", (), {"experiment": tb})())
    assert log_pairs(m, "val/x", t, t)
    assert log_pairs(m, "val/y", t[..., None].expand(5, 64, 64, 64), t[..., None].expand(5, 64, 64, 64))
    assert tb.images == [("val/x", (1, 132, 520), 7), ("val/y", (1, 132, 520), 7)]
