"""The trained point-cloud models: an encoder with its decoder (:class:`CloudModel`), the weights files that hold
them (:func:`load_model`, :func:`load_pretrained` of :data:`PRETRAINED`), decoding codes to programs, and the
points drawn in pictures. :mod:`shapeprog.pointcloud.infer` runs them on a cloud."""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Optional

import torch

from shapeio.weights import read_weights

from ..geometry import CORNER_SIGNS
from ..lang import Program
from ..macros.library import Library
from ..vae.decode import decode_programs
from ..vae.layout import LineLayout
from ..vae.macro_decode import decode_macro
from ..vae.macro_model import MacroVAE
from ..vae.model import VAE
from ..vae.pretrained import decoder_fingerprint, load_pretrained as load_vae
from .encoder import PointNet2SSG

__all__ = ["PRETRAINED", "WEIGHTS", "CloudModel", "cloud_corners", "decode_codes", "load_encoder", "load_model",
           "load_pretrained"]

#: The weights files shipped under ``shapeprog/weights`` (docs/benchmarks.md names the command of each).
PRETRAINED = {"chair": "pointcloud_e2e_chair.pt", "table": "pointcloud_e2e_table.pt",
              "storage": "pointcloud_e2e_storage.pt"}
WEIGHTS = Path(__file__).resolve().parent.parent / "weights"
_FORMAT, _VERSION = "shapeprog-pointcloud", 1
#: Cloud points drawn as cubes in pictures, and the cubes' side (canonical units).
_PICTURE_POINTS, _PICTURE_CUBE = 512, 0.03


# ------------------------------------------------------------------------------------------ models


def cloud_corners(points, count: int = _PICTURE_POINTS, side: float = _PICTURE_CUBE) -> torch.Tensor:
    """A cloud as small axis-aligned cubes, for :func:`shapeprog.picture.render_grid`.

    Args:
        points: ``(N, 3)`` float, y up.
        count: the first ``count`` points are drawn (the clouds are random subsets already).
        side: the cubes' edge length.

    Returns:
        ``(min(N, count), 8, 3) float32`` corners in the spec's corner order.
    """
    p = torch.as_tensor(points, dtype=torch.float32)[:count]
    signs = torch.as_tensor(CORNER_SIGNS, dtype=torch.float32)
    return p[:, None, :] + (side / 2) * signs[None]


def decode_codes(vae, codes: torch.Tensor, macros: bool = False) -> list:
    """Decode latents ``(B, H)`` with ``vae``'s decoder (non-rejecting validity decoding), None where decoding
    fails: programs (corpus frame); for a :class:`~shapeprog.vae.macro_model.MacroVAE` the expansions of its
    macro programs, or with ``macros`` the :class:`~shapeprog.vae.macro_decode.MacroDecoded` themselves
    (macro program, text and expansion). Shared by :class:`CloudModel` and the training modules' validation."""
    if getattr(vae, "layout", None) is None:
        with torch.no_grad():
            return decode_programs(vae.decoder, codes)

    out = []
    with torch.no_grad():
        for z in codes:
            try:
                d = decode_macro(vae, z)
                out.append(d if macros else d.program)
            except ValueError:
                out.append(None)
    return out


class CloudModel(torch.nn.Module):
    """A trained cloud encoder and the decoder of its latents.

    Attributes:
        encoder: the :class:`PointNet2SSG` (eval mode).
        vae: the VAE whose decoder decodes (the shipped VAE for a latent-regression model); a
            :class:`~shapeprog.vae.macro_model.MacroVAE` for a model that writes macro programs.
        category, recipe: what it was trained on and how (``"latent"`` or ``"e2e"``).
        meta: what the weights file records (epoch, step, command, ...).
        layout: the macro library's line layout of a macro-program model (``layout.library``); None for the base
            language.
    """

    def __init__(self, encoder: PointNet2SSG, vae: VAE, category: str, recipe: str, meta: Optional[dict] = None):
        super().__init__()
        if encoder.config["out_dim"] != vae.decoder.hidden_dim:
            raise ValueError(f"the encoder's code has {encoder.config['out_dim']} dims, the decoder takes "
                             f"{vae.decoder.hidden_dim}")
        self.encoder, self.vae = encoder.eval(), vae.eval()
        self.category, self.recipe, self.meta = category, recipe, dict(meta or {})
        self.layout = getattr(vae, "layout", None)

    def codes(self, clouds: torch.Tensor) -> torch.Tensor:
        """Latents ``(B, H)`` of canonical clouds ``(B, N, 3)``."""
        p = next(self.encoder.parameters())
        with torch.no_grad():
            return self.encoder(clouds.to(p.device, p.dtype))

    def decode(self, codes: torch.Tensor) -> list[Optional[Program]]:
        """Programs (corpus frame) of latents ``(B, H)``; None where decoding fails. A macro-program model's
        programs are the expansions of its macro programs (:meth:`decode_macros` keeps the macro text)."""
        return decode_codes(self.vae, codes)

    def decode_macros(self, codes: torch.Tensor) -> list:
        """The :class:`~shapeprog.vae.macro_decode.MacroDecoded` (macro program, its text, its expansion) of
        latents ``(B, H)`` of a macro-program model; None where decoding fails.

        Raises:
            ValueError: the model writes base-language programs.
        """
        if self.layout is None:
            raise ValueError(f"the {self.category} {self.recipe} model writes ShapeAssembly programs, not macro programs")
        return decode_codes(self.vae, codes, macros=True)


def _read_weights(path, category: Optional[str] = None) -> tuple[dict, PointNet2SSG]:
    """The checked payload of a weights file and its encoder (float32, its recorded sizes)."""
    payload = read_weights(path, _FORMAT, _VERSION, what="point-cloud model weights file")
    cat = payload["category"]
    if category is not None and cat != category:
        raise ValueError(f"{path}: a model of category {cat!r}, not {category!r}")
    encoder = PointNet2SSG(**dict(payload["config"]))
    floats = {k: v.float() if v.is_floating_point() else v for k, v in payload["encoder"].items()}
    try:
        encoder.load_state_dict(floats)
    except RuntimeError as e:
        raise ValueError(f"{path}: tensors do not fit the recorded sizes: {str(e).splitlines()[0]}") from None
    return payload, encoder


def load_encoder(path, category: Optional[str] = None) -> PointNet2SSG:
    """The encoder of a weights file alone (no decoder is built), e.g. to start a training run from it.

    Raises:
        FileNotFoundError, ValueError: as :func:`load_model`.
    """
    return _read_weights(path, category)[1]


def load_model(path, category: Optional[str] = None) -> CloudModel:
    """The :class:`CloudModel` of a weights file (:func:`shapeprog.pointcloud.train.export_weights`).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file, for an unreadable file, another format or version, another category.
    """
    payload, encoder = _read_weights(path, category)
    cat = payload["category"]
    try:
        if payload["recipe"] == "e2e":
            if payload.get("library") is not None:
                library = Library.from_text(payload["library"], f"{path}:library")
                vae = MacroVAE(LineLayout(library), int(payload["hidden_dim"]))
            else:
                vae = VAE(int(payload["hidden_dim"]))
            vae.decoder.load_state_dict({k: v.float() for k, v in payload["decoder"].items()})
        else:
            vae = load_vae(cat)
            want = payload.get("vae_decoder")  # absent in files written before it was recorded
            if want is not None and want != decoder_fingerprint(vae.decoder.state_dict()):
                raise ValueError(f"{path}: a latent-regression model trained for another {cat} VAE than the shipped "
                                 f"one (decoder {want}); retrain it with configs/pointcloud/latent_{cat}.yaml")
    except RuntimeError as e:
        raise ValueError(f"{path}: tensors do not fit the recorded sizes: {str(e).splitlines()[0]}") from None
    return CloudModel(encoder, vae, cat, payload["recipe"], payload.get("meta"))


@functools.lru_cache(maxsize=4)
def load_pretrained(category: str = "chair") -> CloudModel:
    """The model shipped for ``category`` (:data:`PRETRAINED`), loaded once per process."""
    if category not in PRETRAINED:
        raise ValueError(f"no shipped point-cloud model for category {category!r}; shipped: "
                         f"{', '.join(PRETRAINED)} (train one: configs/pointcloud/)")
    path = WEIGHTS / PRETRAINED[category]
    if not path.is_file():
        raise FileNotFoundError(f"the shipped {category} point-cloud weights {path} are missing from this installation")
    return load_model(path, category)


# ------------------------------------------------------------------------------------------ one cloud
