"""Images: the one PNG writer, users' images read as bool masks, and folders of target images.

* :func:`write_png`: bool, uint8 or float, grey or RGB(A), optional integer upscaling, atomic.
* :func:`read_gray` / :func:`binarise` / :func:`read_mask`: a PNG, JPG, ... file to a bool mask,
  by Otsu's method (alpha and polarity handled) or by a fixed grey threshold.
* :func:`fit_to_canvas`: crop a mask (or volume) to its shape and scale it into a 64-sided canvas.
* :func:`list_images` / :func:`read_masks` / :func:`read_image_folder`: a folder of target images
  as ``(N, 64, 64)`` masks.

The rules, and which one is the default where, are in ``docs/shapeio.md``.
"""

from __future__ import annotations

import io
import os
import warnings
from pathlib import Path
from typing import Sequence, Union

import numpy as np
from PIL import Image

from .arrays import as_numpy
from .files import InputError, atomic_write

__all__ = ["IMAGE_SUFFIXES", "MAX_IMAGE_PIXELS", "write_png", "png_bytes", "read_gray", "binarise", "read_mask", "fit_to_canvas",
           "centre_on_canvas", "list_images", "read_masks", "read_image_folder"]

PathLike = Union[str, os.PathLike]

#: File types read as images (lower-case suffixes).
IMAGE_SUFFIXES = (".bmp", ".gif", ".jpeg", ".jpg", ".png", ".tif", ".tiff", ".webp")
#: Largest image read (width × height); a bigger file is an :class:`~shapeio.files.InputError` before
#: its pixels are decoded.
MAX_IMAGE_PIXELS = 4096 * 4096
SIZE = 64  # the canvas side of the targets
MARGIN = 4  # empty cells kept on each end of a fitted shape's longest side


# ------------------------------------------------------------------------------------------------
# writing

def write_png(path: PathLike, image, scale: int = 1, mkdir: bool = False) -> Path:
    """Write an image as PNG, atomically.

    Args:
        path: the output file.
        image: ``(H, W)`` grey, ``(H, W, 3)`` RGB or ``(H, W, 4)`` RGBA (NumPy or torch); bool
            (True = 255, white), uint8, or float in ``[0, 1]`` (scaled by 255 and rounded).
        scale: integer upscaling factor (each pixel becomes ``scale x scale``, nearest neighbour).
        mkdir: create the file's directory first.

    Returns:
        The path written.

    Raises:
        ValueError: naming ``path``, for a bad shape, dtype, value range or ``scale``.
    """
    return atomic_write(path, png_bytes(image, scale, where=path), mkdir=mkdir)


def png_bytes(image, scale: int = 1, where: PathLike = "<image>") -> bytes:
    """The PNG encoding of ``image`` (the images and ``scale`` of :func:`write_png`), for writers that place
    the bytes themselves (``shapeio.files.write_new_set``).

    Raises:
        ValueError: naming ``where``, for a bad shape, dtype, value range or ``scale``.
    """
    arr = as_numpy(image)
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (3, 4))) or 0 in arr.shape[:2]:
        raise ValueError(f"{where}: `image` must be (H, W), (H, W, 3) or (H, W, 4) and not empty, got {arr.shape}")
    if isinstance(scale, bool) or not isinstance(scale, (int, np.integer)) or scale < 1:
        raise ValueError(f"{where}: scale must be a positive integer, got {scale!r}")
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8) * np.uint8(255)
    elif np.issubdtype(arr.dtype, np.floating):
        if not (np.isfinite(arr).all() and arr.min() >= 0.0 and arr.max() <= 1.0):
            raise ValueError(f"{where}: a float `image` must hold values in [0, 1]")
        arr = np.rint(arr * 255.0).astype(np.uint8)
    elif arr.dtype != np.uint8:
        raise ValueError(f"{where}: `image` must be bool, uint8 or float, got dtype {arr.dtype}")
    if scale > 1:
        arr = np.repeat(np.repeat(arr, scale, axis=0), scale, axis=1)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(arr)).save(buf, format="PNG")
    return buf.getvalue()


# ------------------------------------------------------------------------------------------------
# reading one image

def read_gray(path: PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image file as grey levels and, when it has one, its alpha channel.

    Grey is PIL's luma (``L = 0.299 R + 0.587 G + 0.114 B``); 16-bit grey is reduced to its high
    byte; a palette image with a transparent entry gets an alpha channel.

    Args:
        path: a PNG, JPG, BMP, GIF, TIFF or WebP file.

    Returns:
        ``gray: (H, W) uint8`` and ``alpha: (H, W) uint8`` or None.

    Raises:
        FileNotFoundError: no such file.
        InputError: the file is not a readable image, or has more than :data:`MAX_IMAGE_PIXELS`
            pixels (the message names it).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    kind = path.suffix[1:].upper() or "image"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                w, h = im.size
                if w * h > MAX_IMAGE_PIXELS:
                    raise InputError(f"{path}: the image is {w}x{h} pixels; at most "
                                     f"MAX_IMAGE_PIXELS = {MAX_IMAGE_PIXELS} are read")
                gray, alpha = _gray_alpha(im)
    except InputError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        raise InputError(f"{path}: the image is too large to read ({e})") from None
    except Exception as e:  # Pillow's decoders raise many types for corrupt files (SyntaxError, EOFError, ...)
        raise InputError(f"{path}: not a readable {kind} image (cannot read it: {type(e).__name__}: {e})") from None
    return gray, alpha


def _gray_alpha(im) -> tuple[np.ndarray, np.ndarray | None]:
    """The grey levels and alpha of an open Pillow image (see :func:`read_gray`)."""
    im.load()
    if im.mode == "PA" or (im.mode == "P" and "transparency" in im.info):
        im = im.convert("RGBA")
    alpha = np.asarray(im.getchannel("A")) if "A" in im.getbands() else None
    if im.mode in ("I", "I;16", "I;16B", "I;16L"):
        gray = (np.clip(np.asarray(im, dtype=np.int64), 0, 65535) >> 8).astype(np.uint8)
    else:
        gray = np.asarray(im.convert("L"))
    return gray, alpha


def binarise(gray: np.ndarray, alpha: np.ndarray | None = None, threshold: int | None = None,
             invert: bool = False, name: str = "image") -> np.ndarray:
    """Turn grey levels into a bool mask by one of the two rules of ``docs/shapeio.md``.

    Args:
        gray: ``(H, W) uint8``.
        alpha: ``(H, W) uint8`` or None.
        threshold: None for the automatic rule: the alpha channel (``>= 128``) when the image has
            transparency, otherwise Otsu's threshold with the side that covers most of the border
            taken as background. An int ``t`` for the fixed rule: ON where ``gray > t`` (alpha ignored).
        invert: flip the mask at the end.
        name: the file, for error messages.

    Returns:
        ``(H, W) bool``.

    Raises:
        InputError: automatic rule only: a single-colour image, or no foreground.
    """
    if threshold is not None:
        fg = gray > int(threshold)
        return ~fg if invert else fg
    # scikit-image (with SciPy) takes tenths of a second to import: loaded only where Otsu's rule runs
    from skimage.filters import threshold_otsu  # lazy: scikit-image only for grey images

    if alpha is not None and alpha.min() < 255:
        fg = alpha >= 128
    else:
        if gray.max() == gray.min():
            raise InputError(f"{name}: the image is a single colour; nothing to parse")
        fg = gray > threshold_otsu(gray)
        border = np.concatenate([fg[0], fg[-1], fg[:, 0], fg[:, -1]])
        if border.mean() > 0.5:  # light background: the shape is the dark part
            fg = ~fg
    if not fg.any() or fg.all():
        raise InputError(f"{name}: no foreground after binarisation")
    return ~fg if invert else fg


def read_mask(path: PathLike, threshold: int | None = None, invert: bool = False) -> np.ndarray:
    """An image file as a bool mask at its own size: :func:`read_gray` then :func:`binarise`.

    Returns:
        ``(H, W) bool``, ``mask[row, col]``.
    """
    gray, alpha = read_gray(path)
    return binarise(gray, alpha, threshold, invert, name=str(path))


# ------------------------------------------------------------------------------------------------
# fitting into the canvas

def centre_on_canvas(mask: np.ndarray, size: int = SIZE) -> np.ndarray:
    """``mask`` (no side above ``size``) placed in the middle of an empty ``size``-sided canvas."""
    out = np.zeros((size,) * mask.ndim, dtype=bool)
    start = [(size - n) // 2 for n in mask.shape]
    out[tuple(slice(a, a + n) for a, n in zip(start, mask.shape))] = mask
    return out


def fit_to_canvas(mask: np.ndarray, margin: int = MARGIN, name: str = "shape", size: int = SIZE) -> np.ndarray:
    """Crop a bool image or volume to its foreground and scale it into a ``size``-sided canvas.

    The scale keeps the aspect (linear interpolation, then ``>= 0.5``) and leaves ``margin`` empty
    cells on the longest side; the result is centred. A mask that is already ``size``-sided is
    returned unchanged.

    Args:
        mask: ``(H, W)`` or ``(X, Y, Z)`` bool (any non-zero is ON).
        margin: empty cells kept on each end of the longest side.
        name: the file, for error messages.
        size: the canvas side.

    Returns:
        ``(size, size)`` or ``(size, size, size)`` bool.

    Raises:
        InputError: an empty mask, or a shape too thin to survive the scaling.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.shape == (size,) * mask.ndim:
        return mask
    # SciPy's ndimage takes tenths of a second to import: loaded only where a mask is scaled
    from scipy.ndimage import zoom  # lazy: scipy only when a mask is resized

    idx = np.nonzero(mask)
    if not idx[0].size:
        raise InputError(f"{name}: empty (no foreground)")
    lo = [int(i.min()) for i in idx]
    hi = [int(i.max()) + 1 for i in idx]
    crop = mask[tuple(slice(a, b) for a, b in zip(lo, hi))]
    side = size - 2 * margin
    s = side / max(crop.shape)
    scaled = zoom(crop.astype(np.float32), s, order=1, grid_mode=True, mode="grid-constant") >= 0.5
    scaled = scaled[tuple(slice(0, side) for _ in scaled.shape)]
    if not scaled.any():
        raise InputError(f"{name}: the shape vanishes when scaled to {side} cells (too thin)")
    return centre_on_canvas(scaled, size)


# ------------------------------------------------------------------------------------------------
# folders of target images

def list_images(folder: PathLike, suffixes: Sequence[str] = IMAGE_SUFFIXES) -> list[Path]:
    """The image files of ``folder`` (suffix in ``suffixes``, case-insensitive), sorted by name.

    Raises:
        FileNotFoundError: the folder does not exist or holds no such file.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such directory of target images")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes and p.is_file())
    if not files:
        raise FileNotFoundError(f"{folder}: no {', '.join(suffixes)} file in the directory")
    return files


def read_masks(files: Sequence[PathLike], size: int = SIZE, threshold: int | None = None,
               invert: bool = False, fit: bool = True) -> np.ndarray:
    """Image files as target masks, in the given order.

    Args:
        files: image files.
        size: the canvas side.
        threshold, invert: the binarisation rule (:func:`binarise`; None = automatic).
        fit: scale each mask into the canvas (:func:`fit_to_canvas`); with False every image must
            already be ``size x size``.

    Returns:
        ``(N, size, size) bool``.

    Raises:
        InputError: an unreadable file, a wrong size (``fit=False``), or a mask the rule refuses;
            the message names the file.
    """
    out = np.empty((len(files), size, size), dtype=bool)
    for i, f in enumerate(files):
        gray, alpha = read_gray(f)
        if not fit and gray.shape != (size, size):
            raise InputError(f"{f}: target images must be {size}x{size}, got {gray.shape[1]}x{gray.shape[0]}")
        mask = binarise(gray, alpha, threshold, invert, name=str(f))
        out[i] = fit_to_canvas(mask, name=str(f), size=size) if fit else mask
    return out


def read_image_folder(folder: PathLike, size: int = SIZE, threshold: int | None = None, invert: bool = False,
                      fit: bool = True, suffixes: Sequence[str] = IMAGE_SUFFIXES) -> np.ndarray:
    """A folder of target images as masks: :func:`list_images` then :func:`read_masks`.

    Returns:
        ``(N, size, size) bool``, files in name order.
    """
    return read_masks(list_images(folder, suffixes), size, threshold, invert, fit)
