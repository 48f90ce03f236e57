"""Tests for shapeprog.picture: the cuboid renderer."""
import numpy as np
import pytest
import torch
from PIL import Image

from sa_testutil import boxes
from shapeprog.picture import PALETTE, part_colors, render_grid, render_png


def chair():
    legs = [[x, 0.225, z] for x in (-0.22, 0.22) for z in (-0.22, 0.22)]
    return boxes(legs + [[0, 0.475, 0], [0, 0.85, -0.235]], [[0.05, 0.45, 0.05]] * 4 + [[0.5, 0.05, 0.5], [0.5, 0.7, 0.04]])


def hue_mask(img, rgb, tol=0.06):
    """Pixels whose colour is a shade of `rgb` (same chromaticity)."""
    img = img.astype(np.float64) + 1e-6
    ref = np.asarray(rgb, np.float64) + 1e-6
    return (np.abs(img / img.sum(-1, keepdims=True) - ref / ref.sum()).max(-1) < tol) & (img.sum(-1) < 700)


def test_render_chair_image(tmp_path):
    labels = [1, 1, 1, 1, 2, 3]
    img = render_png(chair(), tmp_path / "chair.png", labels=labels, size=256)
    assert img.shape == (256, 256, 3) and img.dtype == np.uint8
    # white background at the borders
    assert (img[0] == 255).all() and (img[-1] == 255).all() and (img[:, 0] == 255).all()
    legs, seat, back = hue_mask(img, PALETTE[0]), hue_mask(img, PALETTE[1]), hue_mask(img, PALETTE[2])
    assert legs.sum() > 300 and seat.sum() > 1000 and back.sum() > 3000
    rows = lambda m: np.nonzero(m.any(1))[0]
    # y-up: the back is drawn above the seat, the legs below it
    assert rows(back).mean() < rows(seat).mean() < rows(legs).mean()
    assert rows(legs).max() > rows(seat).max()
    # Lambert: the seat's top is lit brighter than its front side, and both are visible
    shades = np.unique(img[seat].sum(-1) // 20)
    assert len(shades) >= 2
    # dark edges exist
    assert (img.sum(-1) < 200).sum() > 100
    # the file holds the same image
    import cv2

    back_img = cv2.imread(str(tmp_path / "chair.png"))[..., ::-1]
    assert np.array_equal(back_img, img)


def test_occlusion_front_box_hides_back_box():
    # the camera looks from +x, +y, +z: a box in front (larger z) hides an equal box behind it
    front = boxes([[0, 0, 1.0], [0, 0, -1.0]], [[1, 1, 1], [1, 1, 1]])
    img = render_png(front, labels=[0, 1], size=128)
    a, b = hue_mask(img, PALETTE[0]).sum(), hue_mask(img, PALETTE[1]).sum()
    assert a > b > 0
    swapped = render_png(boxes([[0, 0, -1.0], [0, 0, 1.0]], [[1, 1, 1], [1, 1, 1]]), labels=[0, 1], size=128)
    assert hue_mask(swapped, PALETTE[1]).sum() == a


def test_labels_and_determinism():
    c = chair()
    a = render_png(c, size=96)
    assert np.array_equal(a, render_png(c, size=96))
    assert np.array_equal(part_colors(3, [5, 9, 5]), PALETTE[[0, 1, 0]])
    assert np.array_equal(part_colors(2), PALETTE[[0, 1]])
    one = render_png(c, labels=[0] * 6, size=96)
    assert not hue_mask(one, PALETTE[1]).any()


def test_empty_and_errors():
    img = render_png(torch.zeros(0, 8, 3), size=32)
    assert (img == 255).all()
    with pytest.raises(ValueError, match=r"\(L, 8, 3\)"):
        render_png(torch.zeros(2, 3))
    with pytest.raises(ValueError, match="labels"):
        render_png(chair(), labels=[1, 2])
    with pytest.raises(ValueError, match="size"):
        render_png(chair(), size=0)


def test_grid_cells_are_the_single_renders(tmp_path):
    shapes = [chair(), (chair()[:2], [0, 1]), torch.zeros(0, 8, 3)]
    sheet = render_grid(shapes, tmp_path / "grid.png", cols=2, size=64)
    assert sheet.shape == (128, 128, 3)
    assert np.array_equal(sheet[:64, :64], render_png(chair(), size=64))
    assert np.array_equal(sheet[:64, 64:], render_png(chair()[:2], labels=[0, 1], size=64))
    assert (sheet[64:, :] == 255).all()  # an empty shape and the padding cell are white
    assert np.array_equal(np.asarray(Image.open(tmp_path / "grid.png").convert("RGB")), sheet)
    assert render_grid([chair()], cols=8, size=32).shape == (32, 32, 3)
    with pytest.raises(ValueError, match="at least one shape"):
        render_grid([])
    with pytest.raises(ValueError, match="cols"):
        render_grid([chair()], cols=0)
