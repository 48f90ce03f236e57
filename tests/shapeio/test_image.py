"""Tests of shapeio.image: the PNG writer, users' images as masks, folders of target images."""
import cv2
import numpy as np
import pytest
from PIL import Image

from shapeio import InputError
from shapeio.image import (binarise, centre_on_canvas, fit_to_canvas, list_images, read_gray, read_image_folder,
                           read_mask, read_masks, write_png)


def disc(size=64, r=12, centre=(32, 32)):
    yy, xx = np.mgrid[:size, :size]
    return (yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < r * r


def test_png_round_trip_gray_rgb_rgba_bool_float(tmp_path):
    rgb = np.zeros((4, 6, 3), np.uint8)
    rgb[..., 0] = 200  # red
    write_png(tmp_path / "rgb.png", rgb)
    assert np.array_equal(cv2.imread(str(tmp_path / "rgb.png"))[..., ::-1], rgb)  # OpenCV reads it too
    rgba = np.dstack([rgb, np.full((4, 6), 90, np.uint8)])
    write_png(tmp_path / "rgba.png", rgba)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "rgba.png")), rgba)
    mask = disc(16, 5, (8, 8))
    write_png(tmp_path / "b.png", mask)
    gray, alpha = read_gray(tmp_path / "b.png")
    assert alpha is None and np.array_equal(gray, np.where(mask, 255, 0))
    write_png(tmp_path / "f.png", np.array([[0.0, 0.5], [1.0, 0.25]]))
    assert read_gray(tmp_path / "f.png")[0].tolist() == [[0, 128], [255, 64]]


def test_png_upscaling_is_nearest(tmp_path):
    img = np.arange(6, dtype=np.uint8).reshape(2, 3) * 40
    write_png(tmp_path / "s.png", img, scale=3)
    back = read_gray(tmp_path / "s.png")[0]
    assert back.shape == (6, 9) and np.array_equal(back[::3, ::3], img)
    assert np.array_equal(back, np.kron(img, np.ones((3, 3), np.uint8)))


def test_png_bad_input_names_the_file_and_writes_nothing(tmp_path):
    for bad, pattern in [(np.zeros((2, 3, 5), np.uint8), r"x\.png: `image` must be"),
                         (np.zeros((2, 2), np.int32), r"x\.png: .*dtype int32"),
                         (np.full((2, 2), 1.5), r"x\.png: .*\[0, 1\]")]:
        with pytest.raises(ValueError, match=pattern):
            write_png(tmp_path / "x.png", bad)
    with pytest.raises(ValueError, match=r"x\.png: scale must be a positive integer, got 0"):
        write_png(tmp_path / "x.png", np.zeros((2, 2), bool), scale=0)
    assert list(tmp_path.iterdir()) == []


def test_automatic_rule_polarity_alpha_and_palette(tmp_path):
    mask = disc()
    Image.fromarray(np.where(mask, 0, 255).astype(np.uint8)).save(tmp_path / "dark.png")
    Image.fromarray(np.where(mask, 255, 0).astype(np.uint8)).save(tmp_path / "light.jpg", quality=95)
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[..., 3] = np.where(mask, 255, 0)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "alpha.png")
    pal = Image.fromarray(np.where(mask, 1, 0).astype(np.uint8), "P")
    pal.putpalette([0, 0, 0, 0, 0, 0])  # both entries black: only transparency tells the shape
    pal.save(tmp_path / "pal.png", transparency=0)
    for name in ("dark.png", "light.jpg", "alpha.png", "pal.png"):
        assert np.array_equal(read_mask(tmp_path / name), mask), name
    assert np.array_equal(read_mask(tmp_path / "dark.png", invert=True), ~mask)


def test_fixed_rule_threshold_invert_and_16_bit(tmp_path):
    gray = np.array([[0, 100, 127, 128, 255]], np.uint8)
    assert binarise(gray, threshold=127).tolist() == [[False, False, False, True, True]]
    assert binarise(gray, threshold=99, invert=True).tolist() == [[True, False, False, False, False]]
    cv2.imwrite(str(tmp_path / "deep.png"), (gray.astype(np.uint16) * 257))  # 16-bit grey
    g16, _ = read_gray(tmp_path / "deep.png")
    assert np.array_equal(g16, gray)


def test_fit_to_canvas_and_centre():
    m = np.zeros((100, 300), bool)
    m[40:60, 50:250] = True
    out = fit_to_canvas(m)
    cols = np.nonzero(out.any(axis=0))[0]
    assert out.shape == (64, 64) and cols.max() - cols.min() + 1 == 56
    assert fit_to_canvas(m, margin=2, size=32).shape == (32, 32)
    assert np.array_equal(fit_to_canvas(disc()), disc())  # already 64-sided: unchanged
    c = centre_on_canvas(np.ones((2, 4), bool), size=8)
    assert np.argwhere(c).min(0).tolist() == [3, 2] and c.sum() == 8
    with pytest.raises(InputError, match="blank: empty"):
        fit_to_canvas(np.zeros((10, 10), bool), name="blank")


def test_folder_rules_and_order(tmp_path):
    big = np.zeros((128, 96), bool)
    big[20:100, 30:70] = True
    Image.fromarray(np.where(big, 0, 255).astype(np.uint8)).save(tmp_path / "b.png")
    Image.fromarray(np.where(disc(), 255, 0).astype(np.uint8)).save(tmp_path / "a.jpg", quality=95)
    (tmp_path / "notes.txt").write_text("x")
    assert [f.name for f in list_images(tmp_path)] == ["a.jpg", "b.png"]
    masks = read_image_folder(tmp_path)
    assert masks.shape == (2, 64, 64) and np.array_equal(masks[0], disc())
    rows = np.nonzero(masks[1].any(axis=1))[0]
    assert rows.max() - rows.min() + 1 == 56  # the longest side fitted into 64 - 2 * 4
    with pytest.raises(InputError, match=r"b\.png: target images must be 64x64, got 96x128"):
        read_masks(list_images(tmp_path), threshold=127, fit=False)
    assert np.array_equal(read_image_folder(tmp_path, suffixes=(".jpg",), threshold=127, fit=False)[0], disc())


def test_bad_files_get_located_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere: no such directory"):
        list_images(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match=r"no \.png file in the directory"):
        list_images(tmp_path, suffixes=(".png",))
    (tmp_path / "broken.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"broken\.png: not a readable PNG image"):
        read_mask(tmp_path / "broken.png")
    with pytest.raises(InputError, match=r"broken\.png: not a readable PNG image"):
        read_image_folder(tmp_path)
    Image.new("L", (20, 20), 90).save(tmp_path / "flat.png")
    with pytest.raises(InputError, match=r"flat\.png: the image is a single colour"):
        read_mask(tmp_path / "flat.png")
    with pytest.raises(FileNotFoundError, match=r"missing\.png: no such file"):
        read_gray(tmp_path / "missing.png")
