"""Weights files of the ShapeAssembly VAE: export from a training checkpoint, load, and the shipped models.

A weights file (:mod:`shapeio.weights`, family :data:`FORMAT`, version :data:`VERSION`) holds
``{"category", "hidden_dim", "state_dict", "meta"}``, plus ``"library"`` (the macro library's text) for a
:class:`~shapeprog.vae.macro_model.MacroVAE` trained on macro programs: :func:`load_model` rebuilds its
:class:`~shapeprog.vae.layout.LineLayout` from that text (a file without it is the base-language VAE); :func:`read_weights` also reads a Lightning training checkpoint of
:class:`shapeprog.vae.train.VAEModule` (its ``hyper_parameters`` name the category and size). A file of
another format, version or category is refused with a message naming the file.

Example:
    >>> import tempfile, torch
    >>> from pathlib import Path
    >>> from shapeprog.vae import VAE
    >>> vae = VAE(hidden_dim=16)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     path = save_weights(vae, Path(d) / "vae.pt", category="chair", half=False)
    ...     back = load_model(path, category="chair")
    >>> bool(torch.equal(back.decoder.bbdimNet.l1.weight, vae.decoder.bbdimNet.l1.weight))
    True
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Mapping

import torch

from shapeio.weights import check_weights, load_payload, write_weights

from ..macros.library import Library
from .layout import LineLayout
from .macro_model import MacroVAE
from .model import VAE

__all__ = ["FORMAT", "PRETRAINED", "PRETRAINED_MACROS", "VERSION", "WEIGHTS", "decoder_fingerprint", "export_weights",
           "load_model", "load_pretrained", "read_weights", "save_weights"]

FORMAT = "shapeprog-vae"
VERSION = 1
#: Checkpoints :func:`export_weights` averages at the most.
MAX_AVERAGED = 100
WEIGHTS = Path(__file__).resolve().parent.parent / "weights"
# category -> file shipped under shapeprog/weights (docs/benchmarks.md names the command that trained each)
PRETRAINED = {"chair": "vae_chair.pt", "table": "vae_table.pt", "storage": "vae_storage.pt"}
# category -> the shipped VAE on macro programs calling the shipped ShapeMOD library of the category
PRETRAINED_MACROS = {"chair": "vae_chair_macros.pt", "table": "vae_table_macros.pt", "storage": "vae_storage_macros.pt"}
CHECKPOINT_PREFIX = "vae."  # the LightningModule's attribute holding the VAE


def read_weights(path) -> tuple[dict, dict]:
    """``(info, state_dict)`` of a weights file or a Lightning training checkpoint.

    ``info`` holds ``category``, ``hidden_dim``, ``meta`` (epoch, step, anything recorded at export) and, for a
    macro model only, ``library``: the macro library's text.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file, for an unreadable file, another format or a newer version.
    """
    payload = load_payload(path, "ShapeAssembly VAE weights file or checkpoint")
    if "format" in payload:
        payload = check_weights(payload, path, FORMAT, VERSION)
        info = {"category": payload["category"], "hidden_dim": int(payload["hidden_dim"]),
                "meta": dict(payload.get("meta", {}))}
        if payload.get("library") is not None:
            info["library"] = payload["library"]
        return info, payload["state_dict"]
    if "hyper_parameters" in payload and "state_dict" in payload:
        hp = payload["hyper_parameters"]
        state = {k[len(CHECKPOINT_PREFIX):]: v for k, v in payload["state_dict"].items()
                 if k.startswith(CHECKPOINT_PREFIX)}
        if "category" not in hp or "hidden_dim" not in hp or not state:
            raise ValueError(f"{path}: a Lightning checkpoint, but not of the ShapeAssembly VAE "
                             f"(hyper-parameters {sorted(hp)[:6]})")
        meta = {"epoch": int(payload.get("epoch", -1)), "global_step": int(payload.get("global_step", -1))}
        info = {"category": hp["category"], "hidden_dim": int(hp["hidden_dim"]), "meta": meta}
        library = (payload.get("shapeprog_vae") or {}).get("library_text")
        if library is not None:
            info["library"] = library
        return info, state
    raise ValueError(f"{path}: neither a ShapeAssembly VAE weights file nor a Lightning checkpoint "
                     f"(keys {sorted(payload)[:6]})")


def load_model(path, category: str | None = None, device=None):
    """The VAE of ``path`` (:func:`read_weights`) in eval mode, as float32: a :class:`VAE`, or a
    :class:`~shapeprog.vae.macro_model.MacroVAE` when the file holds a macro library.

    Args:
        category: when given, a file trained on another category is refused.

    Raises:
        ParseError: the file's library text does not parse (located in ``<path>:library``).
    """
    info, state = read_weights(path)
    if category is not None and info["category"] != category:
        raise ValueError(f"{path}: weights of category {info['category']!r}, not {category!r}")
    if info.get("library") is not None:
        vae = MacroVAE(LineLayout(Library.from_text(info["library"], f"{path}:library")), hidden_dim=info["hidden_dim"])
    else:
        vae = VAE(hidden_dim=info["hidden_dim"])
    state = {k: v.float() if v.is_floating_point() else v for k, v in state.items()}
    try:
        vae.load_state_dict(state)
    except RuntimeError as e:
        raise ValueError(f"{path}: tensors do not fit a VAE of hidden size {info['hidden_dim']}: "
                         f"{str(e).splitlines()[0]}") from None
    vae.category = info["category"]
    vae.meta = info["meta"]
    return vae.to(device).eval()


def save_weights(vae: VAE, out, category: str, meta: dict | None = None, half: bool = True) -> Path:
    """Write ``vae`` as a weights file, atomically (``half`` stores float16 tensors); a macro model's file
    also holds its library's text."""
    state = {k: (v.detach().cpu().half() if half and v.is_floating_point() else v.detach().cpu())
             for k, v in vae.state_dict().items()}
    payload = {"category": category, "hidden_dim": int(vae.decoder.hidden_dim), "state_dict": state,
               "meta": dict(meta or {})}
    layout = getattr(vae, "layout", None)
    if layout is not None:
        payload["library"] = layout.library.to_text()
    return write_weights(out, FORMAT, VERSION, payload)


def export_weights(checkpoint, out, half: bool = True, meta: dict | None = None) -> Path:
    """Write the VAE of a training checkpoint as a small weights file (``meta`` adds to the recorded).

    ``checkpoint`` may be a list of checkpoints (or weights files) of one model, e.g. the epochs a run kept: the
    file then holds the mean of their weights (stochastic weight averaging) and ``meta["averaged"]`` names them;
    the last one's meta is kept. Models of another category, size or library are refused, naming the file.
    """
    paths = [Path(checkpoint)] if isinstance(checkpoint, (str, Path)) else [Path(p) for p in checkpoint]
    if not paths:
        raise ValueError("no checkpoint to export")
    if len(paths) > MAX_AVERAGED:
        raise ValueError(f"{len(paths)} checkpoints to average; at most {MAX_AVERAGED}")
    vae = load_model(paths[-1])  # its category and meta come with it
    if len(paths) > 1:
        want = _signature(vae)
        total = {k: v.detach().double().clone() for k, v in vae.state_dict().items() if v.is_floating_point()}
        for p in paths[:-1]:
            other = load_model(p)
            if _signature(other) != want:
                raise ValueError(f"{p}: not a model of the same kind as {paths[-1]} (category, hidden size, "
                                 "library), so the two cannot be averaged")
            for k, v in other.state_dict().items():
                if k in total:
                    total[k] += v.detach().double()
        vae.load_state_dict({k: (total[k] / len(paths)).float() if k in total else v
                             for k, v in vae.state_dict().items()})
        meta = {"averaged": [str(p) for p in paths], **(meta or {})}
    return save_weights(vae, out, vae.category, {**vae.meta, **(meta or {})}, half)


def _signature(vae) -> tuple:
    """What two models must share to be averaged: category, hidden size and macro library text."""
    layout = getattr(vae, "layout", None)
    return vae.category, int(vae.decoder.hidden_dim), None if layout is None else layout.library.to_text()


def decoder_fingerprint(state: Mapping[str, torch.Tensor]) -> str:
    """A short hash of a decoder's parameters (its ``state_dict``), at float16 precision so that a model and its
    float16 weights file agree: a model that regresses this decoder's latent codes records it, and is refused
    with another decoder."""
    h = hashlib.sha256()
    for k in sorted(state):
        v = state[k].detach().cpu()
        h.update(k.encode())
        h.update((v.half() if v.is_floating_point() else v).contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


def load_pretrained(category: str = "chair", device=None, macros: bool = False) -> VAE:
    """The model shipped with the package for ``category`` ('chair', 'table' or 'storage'); with ``macros``
    the :class:`~shapeprog.vae.macro_model.MacroVAE` on the category's macro programs
    (:data:`PRETRAINED_MACROS`)."""
    shipped = PRETRAINED_MACROS if macros else PRETRAINED
    if category not in shipped:
        kind = "macro-program VAE" if macros else "VAE"
        raise ValueError(f"no shipped {kind} for category {category!r}; shipped: {', '.join(shipped)}")
    path = WEIGHTS / shipped[category]
    if not path.is_file():
        raise FileNotFoundError(f"the shipped {category} VAE weights {path} are missing from this installation")
    return load_model(path, category=category, device=device)
