"""Program inference on users' shapes: loading inputs, the shipped weights, and :func:`infer`.

* :func:`load_shape` reads a PNG/JPG (binarised and fitted into 64×64, aspect kept), a ``.npy`` grid
  (2D or 3D) or a mesh (``.obj``, ``.ply``, ``.stl``, ... voxelised to 64³ with trimesh).
* :func:`load_pretrained` returns a shipped model (``csgnet/weights/``); :func:`load_model` reads any
  weights file written by :func:`export_weights` or a Lightning checkpoint.
* :func:`infer` decodes a batch of shapes with beam search and returns, per shape, the chosen program
  with its log-probability and its IoU / chamfer to the input.
* :func:`parse_shape` is the whole parse of one shape file or array as ``python -m csgnet parse`` runs it:
  beam search, refinement of every valid beam and the choice of a short program.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from shapeio import InputError
from shapeio.arrays import read_grid
from shapeio.image import IMAGE_SUFFIXES, MARGIN, centre_on_canvas, fit_to_canvas, read_mask
from shapeio.mesh import MESH_SUFFIXES, load_mesh
from shapeio.weights import check_weights, load_payload, write_weights

from .decode import PRECISIONS, check_views, decode, resolve_precision
from .lang import Program, is_valid, parse
from .models import CSGNet, ModelConfig, preset
from .score import score_beams

__all__ = ["InputError", "load_shape", "load_shape_framed", "fit_to_canvas", "read_checkpoint", "load_model", "export_weights",
           "load_pretrained", "infer", "Inference", "parse_shape", "Parsed",
           "WEIGHTS", "PRETRAINED", "SHIPPED", "KINDS", "DEFAULT_KIND", "INFER_BATCH", "INFER_PRECISION", "INFER_VIEWS", "PRECISIONS",
           "FORMAT", "VERSION"]

WEIGHTS = Path(__file__).parent / "weights"
KINDS = ("csgnet", "csgnetstack")
TUNINGS = ("supervised", "reinforce", "selftrain")
#: The weights-file family of a csgnet model and its version (the shipped files: the unversioned layout, 0).
FORMAT, VERSION = "csgnet", 1
#: The keys of a weights file written before weights files carried ``format`` (the shipped ones).
_LEGACY_KEYS = ("config", "state_dict")
# (dim, kind, tuning) -> the shipped file (docs/csgnet.md says how each was trained)
SHIPPED = {
    (2, "csgnet", "supervised"): "csgnet2d.pt",
    (3, "csgnet", "supervised"): "csgnet3d.pt",
    (2, "csgnetstack", "supervised"): "csgnetstack2d_medium.pt",
    (2, "csgnet", "reinforce"): "rl_csgnet2d.pt",
    (2, "csgnet", "selftrain"): "st_csgnet2d.pt",
    (2, "csgnetstack", "reinforce"): "rl_csgnetstack2d.pt",
}
DEFAULT_KIND = {2: "csgnetstack", 3: "csgnet"}
"""The kind :func:`load_pretrained` returns by default: the strongest shipped model of each dimension."""
PRETRAINED = {dim: SHIPPED[(dim, kind, "supervised")] for dim, kind in DEFAULT_KIND.items()}  # load_pretrained(dim)'s defaults
INFER_BATCH = 16
"""Shapes :func:`infer` decodes together by default: beam search over 16 to 32 shapes was fastest on a 2-core
CPU for both shipped 2D kinds (``python bench/bench_csgnet.py --threads 2 --skip-train --batch B``)."""
INFER_PRECISION = "auto"
"""The arithmetic :func:`infer` and :func:`parse_shape` decode in by default (:data:`csgnet.decode.PRECISIONS`):
bfloat16 autocast on a CPU with native bfloat16 (AVX512-BF16 or AMX), float32 elsewhere; the papers' tables
(``evaluate``, ``python -m csgnet paper``) decode in float32. docs/csgnet.md, "Decoding speed", has the
measurement behind it."""
INFER_VIEWS = {2: 1, 3: 8}
"""The mirror views (:data:`csgnet.decode.VIEWS`) :func:`infer` and :func:`parse_shape` decode with by default, per
dimension: in 3D one decode reads the volume and its seven mirror images (``python -m csgnet evaluate --dim 3 --data
data/synthetic --beams 1 10 --views 1 2 4 8 16 --nn-train 0 --per-length 100`` measures what each count buys and
costs: docs/csgnet.md, "Mirror views"); 2D decodes the image alone."""


# ------------------------------------------------------------------------------------------------
# inputs

def load_shape(path) -> np.ndarray:
    """Read a shape file as a 64-sided bool target: ``(64, 64)`` image (``img[row=y, col=x]``) or
    ``(64, 64, 64)`` volume (``vol[x, y, z]``).

    * Images: :func:`shapeio.image.read_mask` with its automatic rule (Otsu's threshold, or the alpha
      channel if the image has transparency; the side touching the border most is background). A
      64×64 image is used as is, larger or smaller ones are cropped to the shape and fitted into 64×64
      with the aspect kept (:func:`shapeio.image.fit_to_canvas`).
    * ``.npy``: a 2D or 3D array, non-zero = inside; fitted the same way unless 64-sided.
    * Meshes: loaded with trimesh, scaled so the longest side spans 56 voxels, voxelised and filled.

    Raises:
        InputError: unreadable file, unknown type, empty or full image or grid, a mesh with no volume or
            a non-finite vertex, an input over the size limits (``shapeio.image.MAX_IMAGE_PIXELS``,
            ``shapeio.arrays.MAX_GRID_CELLS``, ``shapeio.mesh.MAX_MESH_FACES``).
    """
    path = Path(path)
    name = str(path)
    if not path.is_file():
        raise InputError(f"{name}: no such file")
    suffix = path.suffix.lower()
    if suffix in IMAGE_SUFFIXES:
        return fit_to_canvas(read_mask(path), MARGIN, name)
    if suffix == ".npy":
        mask = read_grid(path)
        if not mask.any():
            raise InputError(f"{name}: empty (no non-zero cells)")
        if mask.all():
            raise InputError(f"{name}: every cell is non-zero (no background); nothing to parse")
        return fit_to_canvas(mask, MARGIN, name)
    if suffix in MESH_SUFFIXES:
        return _voxelise(path)[0]
    raise InputError(f"{name}: unknown file type {suffix!r}; use an image "
                     f"({', '.join(sorted(IMAGE_SUFFIXES))}), .npy, or a mesh ({', '.join(sorted(MESH_SUFFIXES))})")


def load_shape_framed(path) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`load_shape` and, for a mesh, the 4x4 affine that maps the volume's voxel coordinates
    (``vol[x, y, z]``, voxel centres at integers) back to the mesh's own units, so that outputs can be
    written over the input (``export.save_obj`` / ``save_scad`` with ``transform``); ``None`` for images
    and grids, whose cells are the frame."""
    path = Path(path)
    if path.suffix.lower() in MESH_SUFFIXES and path.is_file():
        return _voxelise(path)
    return load_shape(path), None


def _affine(scale, shift) -> np.ndarray:
    """The 4x4 affine ``x -> scale * x + shift`` (per axis)."""
    t = np.eye(4)
    t[:3, :3] = np.diag(np.broadcast_to(np.asarray(scale, dtype=np.float64), (3,)))
    t[:3, 3] = shift
    return t


def _voxelise(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The filled 64³ volume of a mesh and the affine from its voxel coordinates to the mesh's units."""
    # SciPy's ndimage takes tenths of a second to import: loaded only where a mesh is voxelised
    from scipy.ndimage import binary_fill_holes  # lazy: scipy only for a mesh or grid input

    name = str(path)
    mesh = load_mesh(path)
    extent = mesh.extents
    if extent.min() <= 1e-9 * max(extent.max(), 1e-30):
        raise InputError(f"{name}: the mesh has no volume (it is flat: extents {extent.tolist()})")
    side = 64 - 2 * MARGIN
    pitch = float(extent.max()) / (side - 1)
    try:
        grid = mesh.voxelized(pitch)
    except Exception as e:
        raise InputError(f"{name}: voxelisation failed ({type(e).__name__}: {e})") from None
    vol = binary_fill_holes(np.asarray(grid.matrix, dtype=bool))
    if not vol.any():
        raise InputError(f"{name}: the mesh has no volume")
    to_mesh = np.asarray(grid.transform, dtype=np.float64)  # grid index -> mesh units
    if max(vol.shape) > side:  # voxelisation can add one layer
        # fit_to_canvas crops to the shape, scales by s (cell centres: i = (c + 0.5) / s - 0.5 + lo) and centres
        idx = np.nonzero(vol)
        lo = np.array([i.min() for i in idx], dtype=np.float64)
        extent = np.array([i.max() + 1 for i in idx], dtype=np.float64) - lo
        s = side / extent.max()
        scaled = np.minimum(np.floor(extent * s + 0.5), side)  # zoom's output size, cut to the side
        start = (64 - scaled) // 2
        return fit_to_canvas(vol, MARGIN, name), to_mesh @ _affine(1 / s, (0.5 - start) / s - 0.5 + lo)
    start = np.array([(64 - n) // 2 for n in vol.shape], dtype=np.float64)
    return centre_on_canvas(vol), to_mesh @ _affine(1.0, -start)


# ------------------------------------------------------------------------------------------------
# models

def read_checkpoint(path) -> tuple[ModelConfig, dict, dict]:
    """The model of a weights file (:mod:`shapeio.weights`, family :data:`FORMAT`: ``{"config",
    "state_dict", "meta"}``; the shipped files, written before weights files carried their family, are its
    version 0) or of a Lightning training checkpoint.

    Returns:
        ``(config, state_dict, meta)``: the model's configuration, its tensors (as stored) and, for a
        training checkpoint, its ``epoch`` and ``global_step``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file, for anything that is not one of the two layouts.
    """
    payload = load_payload(path, "Lightning training checkpoint or weights file of csgnet")
    if "config" in payload or "format" in payload:
        payload = check_weights(payload, path, FORMAT, VERSION, legacy=_LEGACY_KEYS)
    try:
        if "config" in payload:
            return ModelConfig.from_dict(payload["config"]), payload["state_dict"], payload.get("meta", {})
        if "hyper_parameters" in payload and "state_dict" in payload:
            hp = payload["hyper_parameters"]
            config = preset(hp.get("size", "small"), hp.get("dim", 2), hp.get("stack", False), **(hp.get("model") or {}))
            state = {k[len("model."):]: v for k, v in payload["state_dict"].items() if k.startswith("model.")}
            if not state:
                raise ValueError("a Lightning checkpoint without csgnet model weights (no 'model.' keys)")
            meta = {"epoch": int(payload.get("epoch", -1)), "global_step": int(payload.get("global_step", -1))}
            return config, state, meta
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: not a csgnet weights file or checkpoint ({type(e).__name__}: {e})") from None
    raise ValueError(f"{path}: neither a weights file nor a Lightning checkpoint (keys {sorted(payload)[:6]})")


def load_model(path, device=None) -> CSGNet:
    """A model from a weights file or a Lightning checkpoint (:func:`read_checkpoint`), in eval mode."""
    config, state, _ = read_checkpoint(path)
    model = CSGNet(config)
    try:
        model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()})
    except RuntimeError as e:  # missing, unexpected or mis-sized tensors
        first = str(e).strip().splitlines()[0]
        raise ValueError(f"{path}: its weights do not fit the model its config describes ({first})") from None
    return model.to(device or "cpu").eval()


def export_weights(checkpoint, out, half: bool = True) -> Path:
    """Write the model of a training checkpoint (or weights file) as a small weights file
    ``{"config", "state_dict", "meta"}`` of family :data:`FORMAT`, version :data:`VERSION`, atomically.

    ``half`` stores float16 tensors (loaded back as float32 by :func:`load_model`).
    """
    config, state, meta = read_checkpoint(checkpoint)
    if half:
        state = {k: (v.half() if v.is_floating_point() else v) for k, v in state.items()}
    return write_weights(out, FORMAT, VERSION, {"config": config.to_dict(), "state_dict": state, "meta": meta})


def load_pretrained(dim: int = 2, kind: str | None = None, tuning: str = "supervised", device=None) -> CSGNet:
    """A model shipped with the package (see ``docs/csgnet.md`` for how each was trained and how it scores).

    Args:
        dim: 2 or 3.
        kind: ``"csgnet"`` or ``"csgnetstack"`` (default :data:`DEFAULT_KIND`: the strongest shipped model,
            CSGNetStack in 2D, CSGNet in 3D).
        tuning: ``"supervised"`` (trained on synthetic programs), or fine-tuned on the silhouettes without
            programs: ``"reinforce"`` or ``"selftrain"``.
        device: where to put the model.

    Raises:
        ValueError: an unknown ``dim``, ``kind`` or ``tuning``, or a combination not shipped (the message
            lists those that are).
    """
    if dim not in PRETRAINED:
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    kind = DEFAULT_KIND[dim] if kind is None else kind
    if kind not in KINDS or tuning not in TUNINGS:
        raise ValueError(f"kind must be one of {KINDS} and tuning one of {TUNINGS}, got {kind!r}, {tuning!r}")
    if (dim, kind, tuning) not in SHIPPED:
        have = ", ".join(f"({d}, {k!r}, {t!r})" for d, k, t in sorted(SHIPPED))
        raise ValueError(f"no {tuning} {kind} model is shipped for {dim}D; shipped (dim, kind, tuning): {have}")
    path = WEIGHTS / SHIPPED[(dim, kind, tuning)]
    if not path.is_file():
        raise FileNotFoundError(f"the shipped {dim}D weights {path} are missing from this installation")
    return load_model(path, device)


# ------------------------------------------------------------------------------------------------
# inference

@dataclass
class Inference:
    """The program chosen for one shape.

    Attributes:
        text: program text.
        score: its log-probability under the model (decoded with several mirror views: the views' mean
            log-probability, summed over the program's steps).
        iou: IoU with the input (2D: ``|A∧B| / |A∨B|``; 3D: ``/ (|A∨B| + 1)``).
        chamfer: the paper's 2D chamfer distance in pixels (NaN in 3D).
        valid: the program is valid (an invalid one renders empty).
        beams: all hypotheses' texts, most likely first.
        dim: 2 or 3.
    """

    text: str
    score: float
    iou: float
    chamfer: float
    valid: bool
    beams: list[str]
    dim: int

    @property
    def program(self) -> Program:
        return parse(self.text, self.dim)


def infer(model: CSGNet, shapes, beam: int = 10, select: str = "likelihood", constrained: bool = True,
          batch: int = INFER_BATCH, mode: str = "improved", precision: str = INFER_PRECISION,
          views: int | None = None) -> list[Inference]:
    """Parse shapes into programs.

    Args:
        model: a :class:`~csgnet.models.CSGNet` (e.g. :func:`load_pretrained`).
        shapes: bool ``(N, 64, 64)`` images or ``(N, 64, 64, 64)`` volumes (NumPy or torch), or one shape.
        beam: beam width (1 = greedy).
        select: ``"likelihood"``: the most likely hypothesis; ``"match"``: the hypothesis closest to the
            input (highest IoU in 3D, lowest chamfer in 2D; the paper's best-of-k protocol).
        constrained: mask tokens that would make the program invalid (:mod:`csgnet.decode`).
        batch: shapes decoded together.
        mode: beam-search behaviour, ``"improved"`` or ``"reference"``.
        precision: the model's arithmetic, ``"auto"``, ``"float32"`` or ``"bfloat16"``
            (:data:`csgnet.decode.PRECISIONS`; default :data:`INFER_PRECISION`); the scores are float32 in all.
        views: mirror views per decode (:data:`csgnet.decode.VIEWS`, more than 1 in 3D only; default
            :data:`INFER_VIEWS` of the model's dimension; 1 is the paper's decoding).

    Raises:
        ValueError: a bad ``select``, ``precision``, ``views``, beam width or shape array (the message names it).
    """
    if select not in ("likelihood", "match"):
        raise ValueError(f"select must be 'likelihood' or 'match', got {select!r}")
    resolve_precision(precision)
    dim = model.config.dim
    views = check_views(INFER_VIEWS[dim] if views is None else views, dim)
    x = torch.as_tensor(np.asarray(shapes) if not isinstance(shapes, torch.Tensor) else shapes).bool()
    if x.dim() == dim:
        x = x[None]
    if tuple(x.shape[1:]) != (64,) * dim:
        raise ValueError(f"shapes must be (N, {', '.join(['64'] * dim)}) for this {dim}D model, got {tuple(x.shape)}")
    model.eval()
    out: list[Inference] = []
    for lo in range(0, x.shape[0], batch):
        tgt = x[lo: lo + batch]
        dec = decode(model, tgt, beam, mode=mode, constrained=constrained, precision=precision, views=views)
        _, iou, cd = score_beams(dec, tgt)
        n = dec.tokens.shape[0]
        texts = dec.texts()
        for i in range(n):
            if select == "likelihood":
                j = 0
            else:
                j = int(np.argmin(cd[i]) if dim == 2 else np.argmax(iou[i]))
            out.append(Inference(texts[i][j], float(dec.logprob[i, j]), float(iou[i, j]), float(cd[i, j]),
                                 bool(dec.valid[i, j]), texts[i], dim))
    return out


# ------------------------------------------------------------------------------------------------
# the whole parse of one shape, as `python -m csgnet parse` runs it

@dataclass
class Parsed:
    """What :func:`parse_shape` found for one shape.

    Attributes:
        program: the program to use: the refined and chosen one with ``refine``, else the decoded one;
            ``None`` when no valid program was decoded.
        decoded: the beam search's result (:class:`Inference`: the chosen beam, its scores, every beam).
        refined: the refinement's record (:class:`csgnet.refinement.Refined`: IoU and chamfer before and
            after, the rule), or ``None`` without ``refine`` or without a valid decoded program.
        shape: the ``(64, 64)`` image or ``(64, 64, 64)`` volume that was parsed.
        frame: for a mesh file, the 4x4 affine from the volume's voxel coordinates to the mesh's units
            (:func:`load_shape_framed`); else ``None``.
        refined_beams: the valid beams that were refined (0 without refinement).
    """

    program: Program | None
    decoded: Inference
    refined: object | None
    shape: np.ndarray
    frame: np.ndarray | None = None
    refined_beams: int = 0

    @property
    def text(self) -> str:
        """The program's text ('' when there is none)."""
        return "" if self.program is None else self.program.text()


def parse_shape(shape, model: CSGNet | None = None, kind: str | None = None, beam: int = 10,
                select: str = "match", refine: bool = True, rule: str = "short", refine_iters: int | None = None,
                constrained: bool = True, graft: bool = True, extend: bool = True, fit: bool = True,
                precision: str = INFER_PRECISION, views: int | None = None) -> Parsed:
    """Infer a program for one shape the way ``python -m csgnet parse --select match --refine`` does.

    Args:
        shape: a shape file (image, ``.npy`` grid or mesh; :func:`load_shape_framed`) or a bool ``(64, 64)``
            image / ``(64, 64, 64)`` volume.
        model: the parser (default: :func:`load_pretrained` of the shape's dimension and ``kind``).
        kind: the shipped kind when ``model`` is not given (default: the strongest, :data:`DEFAULT_KIND`).
        beam: beam width.
        select: ``"match"`` (the beam closest to the shape) or ``"likelihood"`` (the most likely).
        refine: refine every valid beam and choose by ``rule`` (:func:`csgnet.refinement.refine_guarded`).
        rule: ``"short"`` (IoU minus a price per primitive), ``"guarded"`` or ``"chamfer"``.
        refine_iters: Powell iterations (default: to convergence).
        constrained: grammar-constrained decoding.
        graft: with the ``"short"`` rule, also try adding other beams' primitives to the choice
            (:func:`csgnet.rewrite.graft`).
        extend: with the ``"short"`` rule, also try adding any primitive of the vocabulary
            (:func:`csgnet.rewrite.extend`).
        fit: with the ``"short"`` rule, also try primitives fitted to the parts the choice gets wrong, and
            to the shape from nothing (:func:`csgnet.rewrite.fit`).
        precision: the decoder's arithmetic (:func:`infer`; default :data:`INFER_PRECISION`).
        views: mirror views per decode (:func:`infer`; default :data:`INFER_VIEWS` of the shape's dimension).
    """
    resolve_precision(precision)  # a bad name is refused before the shape is read
    if views is not None:
        check_views(views, 3)  # likewise a views count no model takes (a 2D shape's model refuses more than 1)
    frame = None
    if isinstance(shape, (str, Path)):
        shape, frame = load_shape_framed(shape)
    shape = np.asarray(shape.cpu() if isinstance(shape, torch.Tensor) else shape).astype(bool)
    if shape.shape not in ((64, 64), (64, 64, 64)):
        raise ValueError(f"a shape must be a (64, 64) image or a (64, 64, 64) volume, got shape {shape.shape}")
    if model is None:
        model = load_pretrained(shape.ndim, kind=kind)
    elif model.config.dim != shape.ndim:
        raise ValueError(f"a {model.config.dim}D model cannot parse a {shape.ndim}D shape")
    decoded = infer(model, shape[None], beam=beam, select=select, constrained=constrained, precision=precision,
                    views=views)[0]
    program = decoded.program if decoded.valid else None
    refined = None
    if refine and program is not None:
        from .refinement import refine_guarded  # lazy: refinement brings scipy and OpenCV

        beams = []
        for text in decoded.beams:
            try:
                p = parse(text, shape.ndim, strict=False)
            except ValueError:
                continue
            if is_valid(p):
                beams.append(p)
        refined = refine_guarded(program, beams, shape, rule=rule, maxiter=refine_iters, use_graft=graft,
                                 use_extend=extend, use_fit=fit)
        program = refined.program
    return Parsed(program, decoded, refined, shape, frame, len(beams) if refined is not None else 0)
