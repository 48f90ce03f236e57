"""What the commands of ``python -m csgnet`` share: option types, error locations, table notes and writing."""
from __future__ import annotations

import argparse
import os
import shlex
from pathlib import Path

from shapeio import atomic_write, refuse_overwrite
from shapeio.options import float_in, int_in

from ..lang import ParseError, is_valid, parse

__all__ = ["named", "located", "is_valid_text", "labelled_models", "command_line", "decoding", "measured_on",
           "refuse_table_over_inputs", "write_table", "beam_width", "non_negative", "MAX_SCALE", "MAX_WORKERS",
           "MAX_SEED", "MAX_LENGTH", "PRECISIONS", "MAX_PER_LENGTH", "MAX_NN_TRAIN", "MAX_IMAGES", "MAX_REFINE_ITERS", "scale",
           "workers", "seed", "length", "per_length", "int_in"]

#: Largest ``--scale`` of generate and demo: the paper's Table 2 split sizes themselves.
MAX_SCALE = 1.0
#: Most worker processes of a ``--workers`` option.
MAX_WORKERS = 256
#: Largest ``--seed`` (NumPy and torch take 0 to 2**63 - 1).
MAX_SEED = 2 ** 63 - 1
#: Longest program length of a ``--lengths`` option (2D programs go to 13 primitives, 3D to 7).
MAX_LENGTH = 13
#: Most programs per length of ``--per-length`` (demo, evaluate, table6) and ``evaluate --refined``.
MAX_PER_LENGTH = 1_000_000
#: Most training programs of ``evaluate --nn-train`` (-1: all of them).
MAX_NN_TRAIN = 10_000_000
#: Most test silhouettes of ``table4 --images`` (0: all of them).
MAX_IMAGES = 1_000_000
#: Most Powell iterations of ``parse --refine-iters``.
MAX_REFINE_ITERS = 100_000

#: The ``--precision`` choices: :data:`csgnet.decode.PRECISIONS`, named here so that ``--help`` needs no torch.
PRECISIONS = ("auto", "float32", "bfloat16")
#: The ``--views`` choices: the keys of :data:`csgnet.decode.VIEWS`.
VIEWS = (1, 2, 4, 8, 16)

#: argparse types of the shared number options (one line, exit 2, before any work).
scale = float_in(0.0, MAX_SCALE, low_open=True)
workers = int_in(1, MAX_WORKERS)
seed = int_in(0, MAX_SEED)
length = int_in(1, MAX_LENGTH)
per_length = int_in(0, MAX_PER_LENGTH)


def named(stem: Path, end: str) -> Path:
    """``stem`` with ``end`` appended (``a.v1`` -> ``a.v1.png``; ``with_suffix`` would give ``a.png``, another
    shape's name)."""
    return stem.with_name(stem.name + end)


def located(src, err: Exception) -> str:
    """``FILE: reason`` for an error about ``src`` (messages that already start with a path are kept)."""
    msg = str(err)
    return msg if msg.startswith(str(src)) else f"{src}: {msg}"


def is_valid_text(text: str, dim: int = 2) -> bool:
    try:
        return bool(text) and is_valid(parse(text, dim))
    except ParseError:
        return False


def labelled_models(specs, dim: int = 2):
    """``(label, model)`` per ``[LABEL=]PATH`` spec; the shipped ``dim``-D model when there is none."""
    from ..inference import load_model, load_pretrained  # lazy: loaded when the command runs

    def kind(model) -> str:
        return "CSGNetStack" if model.config.stack else "CSGNet"

    if not specs:
        model = load_pretrained(dim)
        return [(f"{kind(model)} (shipped)", model)]
    out = []
    for spec in specs:
        label, sep, path = spec.rpartition("=")
        model = load_model(path)
        out.append((label if sep else f"{kind(model)} ({Path(path).name})", model))
    return out


def command_line(args) -> str:
    """The command line that ran, for the notes under written tables."""
    return "python -m csgnet " + shlex.join(args.argv)


def decoding(args) -> str:
    """How the written tables' programs were decoded, for their notes (the precision where it is not float32)."""
    precision = getattr(args, "precision", "float32")
    views = getattr(args, "views", None) or [1]
    views = views if isinstance(views, (list, tuple)) else [views]
    return (f"{'grammar-constrained' if args.constrained else 'unconstrained'} decoding"
            + ("" if precision == "float32" else f", precision {precision}")
            + ("" if list(views) == [1] else ", rows labelled 'V views' decode V mirror images of each volume "
               "together (csgnet.decode.VIEWS)"))


def measured_on() -> str:
    """Where and when the written tables' times were measured, for their notes."""
    import datetime  # lazy: loaded when the command runs
    import platform  # lazy: loaded when the command runs

    import torch  # lazy: loaded when the command runs

    n = torch.get_num_threads()
    where = (f"{platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, {n} thread{'s' if n != 1 else ''}"
             f"{', CUDA available' if torch.cuda.is_available() else ''}")
    return f"times measured on {where}, {datetime.date.today().isoformat()} (the load of other jobs is not recorded)"


def refuse_table_over_inputs(args) -> None:
    """Stop before any work when a table's ``--out`` is one of its input files (weights, silhouettes)."""
    if not getattr(args, "out", None):
        return
    weights = getattr(args, "weights", None) or []
    inputs = [w.rpartition("=")[2] for w in ([weights] if isinstance(weights, str) else weights)]
    inputs += [getattr(args, "silhouettes", None), getattr(args, "cad", None), getattr(args, "init", None)]
    try:
        refuse_overwrite([args.out], [p for p in inputs if p and Path(p).is_file()])
    except FileExistsError as e:
        raise SystemExit(f"error: {e}") from None


def write_table(text: str, out) -> None:
    print(text)
    if out:
        atomic_write(out, text, mkdir=True)
        print(f"wrote {out}")


def beam_width(text: str) -> int:
    from ..decode import check_beam  # csgnet.decode imports torch: loaded only when --beam is given

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    try:
        return check_beam(value, "the beam width")
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def non_negative(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}")
    return value
