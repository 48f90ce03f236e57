"""Synthetic CSG datasets on disk: writing (:func:`generate_dataset`), reading (:func:`load_dataset`)
and a torch ``Dataset`` of token indices (:class:`ProgramDataset`).

The programs come from the sampler of :mod:`csgnet.synth`; the file layout, the split sizes and the
determinism of generation are described in docs/csgnet.md ("Synthetic data").
"""

from __future__ import annotations

import json
import math
import multiprocessing
import platform
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from shapeio import atomic_write
from shapeio.files import parse_json

from . import primitives as P
from .lang import MAX_TOKENS, OPERATORS, STOP, Program, parse_lines
from .synth import Rules, _check_dim, sample_chunk, worker_init
from .vocab import vocabulary

__all__ = [
    "TABLE2",
    "SPLITS",
    "split_sizes",
    "generate_dataset",
    "load_dataset",
    "ProgramDataset",
    "DatasetWarning",
]

FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")

# Paper Table 2: (train, val, test) programs per length.
TABLE2 = {
    2: {3: (25_000, 5_000, 5_000), 5: (100_000, 10_000, 50_000), 7: (150_000, 20_000, 50_000),
        9: (250_000, 20_000, 50_000), 11: (350_000, 20_000, 100_000), 13: (350_000, 20_000, 100_000)},
    3: {3: (100_000, 10_000, 20_000), 5: (200_000, 20_000, 40_000), 7: (400_000, 40_000, 80_000)},
}

def _lengths(dim: int, lengths: Iterable[int] | None) -> list[int]:
    _check_dim(dim)
    if lengths is None:
        return sorted(TABLE2[dim])
    out = sorted({int(L) for L in lengths})
    bad = [L for L in out if L not in TABLE2[dim]]
    if bad:
        raise ValueError(f"lengths {bad} are not {dim}D program lengths; expected some of {sorted(TABLE2[dim])}")
    return out


def split_sizes(dim: int, scale: float, lengths: Iterable[int] | None = None) -> dict[int, dict[str, int]]:
    """Programs per length and split: paper Table 2 times ``scale``, rounded half up, at least 1."""
    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    return {L: {s: max(1, int(math.floor(n * scale + 0.5))) for s, n in zip(SPLITS, TABLE2[dim][L])}
            for L in _lengths(dim, lengths)}


# ---------------------------------------------------------------------------------------------
# files

def _split_path(root: Path, dim: int, length: int, split: str) -> Path:
    return root / f"{dim}d" / f"len_{length:02d}" / f"{split}.txt"


@lru_cache(maxsize=None)
def _token_texts(dim: int) -> tuple[str, ...]:
    vocab = vocabulary(dim)
    out = []
    for i, t in enumerate(vocab.tokens):
        if t in OPERATORS or t == STOP:
            out.append(t)
        else:
            out.append(vocab.decode([i]).text(long=True))
    return tuple(out)


P.on_change(_token_texts.cache_clear)


def _lines(rows: np.ndarray, dim: int) -> str:
    texts = _token_texts(dim)
    return "".join("".join(texts[i] for i in row) + "\n" for row in rows.tolist())


def generate_dataset(out_dir, dim: int = 2, scale: float = 0.001, seed: int = 0, workers: int = 1,
                     lengths: Iterable[int] | None = None, progress: bool = True, **rules) -> dict:
    """Generate a synthetic dataset and write it under ``out_dir/<dim>d/``.

    Args:
        out_dir: dataset directory (created).
        dim: 2 or 3.
        scale: fraction of the paper's Table 2 sizes (``0.001``: 25/5/5 programs of length 3 in 2D).
        seed: the seed; the same seed gives identical files for any ``workers``.
        workers: processes (``1``: in this process).
        lengths: program lengths (default: all of the dimension, 3-13 in 2D, 3-7 in 3D).
        progress: show a tqdm progress bar.
        **rules: :class:`Rules` fields (``min_change``, ``change_rule``, ``min_pixels``, ``op_weights``,
            ``type_weights``, ``chunk_size``, ``batch_size``).

    Returns:
        ``{length: {"train": n, "val": n, "test": n}}``, the programs written.
    """
    _check_dim(dim)
    rules_ = Rules.from_kwargs(dim, **rules)
    lengths_ = _lengths(dim, lengths)
    sizes = split_sizes(dim, scale, lengths_)
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    workers = int(workers)
    root = Path(out_dir)
    totals = {L: sum(sizes[L].values()) for L in lengths_}
    plan = [(L, i) for L in lengths_ for i in range(-(-totals[L] // rules_.chunk_size))]

    meta = {
        "format": "one program per line, postfix, no '$' (2D c/s/t, 3D long form sp/cu/cy)",
        "format_version": FORMAT_VERSION,
        "complete": False,
        "dim": dim,
        "seed": seed,
        "scale": scale,
        "lengths": lengths_,
        "counts": {str(L): sizes[L] for L in lengths_},
        "rules": asdict(rules_),
        "versions": {"numpy": np.__version__, "torch": torch.__version__.split("+")[0],
                     "python": platform.python_version()},
    }
    # written first with "complete": false, so that an interrupted run leaves a dataset that says so
    atomic_write(root / f"{dim}d" / "meta.json", json.dumps(meta, indent=2) + "\n", mkdir=True)
    bar = tqdm(total=sum(totals.values()), desc=f"{dim}D programs", unit="prog", disable=not progress)
    pool = None
    if workers > 1:
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=worker_init)
    futures: dict = {}
    nxt = 0

    def get(L: int, i: int) -> np.ndarray:
        nonlocal nxt
        job = (dim, L, seed, i, rules_)
        if pool is None:
            return sample_chunk(job)
        while nxt < len(plan) and len(futures) < 2 * workers:
            pL, pi = plan[nxt]
            futures[(pL, pi)] = pool.submit(sample_chunk, (dim, pL, seed, pi, rules_))
            nxt += 1
        fut = futures.pop((L, i), None) or pool.submit(sample_chunk, job)
        return fut.result()

    try:
        for L in lengths_:
            seen: set = set()
            rows: list[np.ndarray] = []
            i = 0
            while len(rows) < totals[L]:
                before = len(rows)
                for row in get(L, i).astype(np.int64):
                    key = row.tobytes()
                    if key not in seen:
                        seen.add(key)
                        rows.append(row)
                        if len(rows) == totals[L]:
                            break
                bar.update(len(rows) - before)
                i += 1
            start = 0
            for split in SPLITS:
                k = sizes[L][split]
                atomic_write(_split_path(root, dim, L, split), _lines(np.stack(rows[start:start + k]), dim), mkdir=True)
                start += k
    finally:
        bar.close()
        if pool is not None:
            for f in futures.values():
                f.cancel()
            pool.shutdown(wait=True, cancel_futures=True)

    meta["complete"] = True
    atomic_write(root / f"{dim}d" / "meta.json", json.dumps(meta, indent=2) + "\n", mkdir=True)
    return {L: dict(sizes[L]) for L in lengths_}


def load_dataset(path, dim: int, split: str, lengths: Iterable[int] | None = None, *,
                 errors: str = "warn") -> dict[int, list[Program]]:
    """Read one split of a dataset written by :func:`generate_dataset`.

    Args:
        path: the dataset directory (the ``out_dir`` given to :func:`generate_dataset`).
        dim: 2 or 3.
        split: ``"train"``, ``"val"`` or ``"test"``.
        lengths: lengths to read (default: those in ``meta.json``, else every ``len_*`` folder).
        errors: a bad line (unparsable, or a program whose length is not the file's) is reported as
            ``file:line: reason``. ``"warn"`` (default) issues one ``UserWarning`` listing every bad line
            and keeps the good programs; ``"raise"`` raises one ``ValueError`` listing them all. A line
            that is not UTF-8 is a bad line too (``file:line:column: not UTF-8 text``).

    Warns:
        DatasetWarning: ``meta.json`` is missing, marks an unfinished ``generate`` run, or does not
            list a requested length (files that another run left).

    Returns:
        ``{length: [Program, ...]}`` in file order.
    """
    _check_dim(dim)
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if errors not in ("warn", "raise"):
        raise ValueError(f"errors must be 'warn' or 'raise', got {errors!r}")
    base = Path(path) / f"{dim}d"
    meta = _read_meta(base / "meta.json")
    if lengths is None:
        if meta is not None and isinstance(meta.get("lengths"), list):
            lengths = meta["lengths"]
        else:
            lengths = sorted(int(p.name[4:]) for p in base.glob("len_*") if p.name[4:].isdigit())
        if not lengths:
            raise FileNotFoundError(f"no {dim}D dataset under {str(base)!r} (expected len_XX folders)")
    lengths = sorted(int(v) for v in lengths)
    _check_meta(meta, base / "meta.json", lengths)
    out: dict[int, list[Program]] = {}
    bad: list[str] = []
    for L in lengths:
        f = _split_path(Path(path), dim, L, split)
        if not f.exists():
            raise FileNotFoundError(f"missing dataset file {str(f)!r}")
        lines, errs = _text_lines(f)
        bad += errs
        programs, errs = parse_lines(lines, dim, file=str(f), errors="collect")
        bad += [str(e) for e in errs]
        # parse_lines drops bad and blank lines; match programs back to line numbers for the length check
        err_lines = {e.line for e in errs}
        numbers = [i for i, s in enumerate(lines, 1) if s.strip() and i not in err_lines]
        keep = []
        for no, p in zip(numbers, programs):
            if len(p) != L:
                bad.append(f"{f}:{no}: program has {len(p)} tokens, expected {L} in {p.text()!r}")
            else:
                keep.append(p)
        out[L] = keep
    if bad:
        msg = f"{len(bad)} bad line(s) in the {dim}D {split} split:\n  " + "\n  ".join(bad)
        if errors == "raise":
            raise ValueError(msg)
        warnings.warn(msg + "\nthe other programs were loaded", UserWarning, stacklevel=2)
    return out


class DatasetWarning(UserWarning):
    """A dataset that may not be what :func:`generate_dataset` wrote in one complete run."""


def _read_meta(path: Path) -> dict | None:
    if not path.exists():
        return None

    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a readable meta.json ({type(e).__name__}: {e})") from None
    meta = parse_json(text, str(path))
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: not a readable meta.json (a JSON object is expected)")
    lengths = meta.get("lengths", [])
    if not isinstance(lengths, list) or not all(type(n) is int and 0 < n <= MAX_TOKENS for n in lengths):
        raise ValueError(f"{path}: not a readable meta.json ('lengths' is not a list of program lengths)")
    if "complete" in meta and not isinstance(meta["complete"], bool):
        raise ValueError(f"{path}: not a readable meta.json ('complete' is not true or false)")
    return meta


def _check_meta(meta: dict | None, path: Path, lengths: list[int]) -> None:
    """Warn (:class:`DatasetWarning`) when ``meta.json`` does not vouch for the files about to be read."""
    stale = [] if meta is None else [L for L in lengths if L not in meta.get("lengths", [])]
    if meta is None:
        problem = "is missing: the files may come from an interrupted or older `generate`"
    elif meta.get("complete") is False:
        problem = ("says the run that wrote it did not finish: the files may mix that run's programs "
                   "with an earlier run's (seeds or scales)")
    elif stale:
        problem = f"does not list lengths {stale}: their files come from another run"
    else:
        return
    warnings.warn(f"{path} {problem}; regenerate the dataset to be sure (into a new folder: `generate` never "
                  "replaces one)", DatasetWarning, stacklevel=3)


def _text_lines(f: Path) -> tuple[list[str], list[str]]:
    """The lines of a UTF-8 file, and ``file:line:column: reason`` for each line that is not UTF-8
    (such a line is read as blank, so that the others keep their numbers)."""
    raw = f.read_bytes()
    try:
        return raw.decode("utf-8").splitlines(), []
    except UnicodeDecodeError:
        pass
    lines, errs = [], []
    for no, chunk in enumerate(raw.split(b"\n"), start=1):
        try:
            lines.append(chunk.decode("utf-8").rstrip("\r"))
        except UnicodeDecodeError as e:
            errs.append(f"{f}:{no}:{e.start + 1}: not UTF-8 text (byte 0x{chunk[e.start]:02x})")
            lines.append("")
    if lines and lines[-1] == "" and raw.endswith(b"\n"):
        lines.pop()
    return lines, errs


# ---------------------------------------------------------------------------------------------
# torch dataset

class ProgramDataset(torch.utils.data.Dataset):
    """Programs as padded token indices, for supervised training.

    Item ``i`` is ``(tokens, length)``: ``tokens (max_len + 1,) int64`` holds the program's token
    indices followed by ``$`` (the stop index) up to the end, ``length`` the number of program tokens
    (without ``$``). The supervised targets are ``tokens[:length + 1]``.

    Args:
        programs: :class:`~csgnet.lang.Program` objects or texts of one dimension.
        dim: 2 or 3.
        max_len: pad to this many program tokens (default: the longest program).

    Raises:
        KeyError: a primitive outside the vocabulary.
        ValueError: a program longer than ``max_len``.
    """

    def __init__(self, programs: Sequence[Program | str], dim: int, max_len: int | None = None):
        _check_dim(dim)
        vocab = vocabulary(dim)
        encoded = [vocab.encode(p) for p in programs]
        longest = max((len(e) for e in encoded), default=0)
        self.max_len = longest if max_len is None else int(max_len)
        if longest > self.max_len:
            raise ValueError(f"a program has {longest} tokens, more than max_len={self.max_len}")
        self.dim = dim
        self.tokens = torch.full((len(encoded), self.max_len + 1), vocab.stop, dtype=torch.int64)
        for i, e in enumerate(encoded):
            self.tokens[i, : len(e)] = torch.tensor(e, dtype=torch.int64)
        self.lengths = torch.tensor([len(e) for e in encoded], dtype=torch.int64)

    def __len__(self) -> int:
        return self.tokens.shape[0]

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.tokens[i], self.lengths[i]
