"""Fuzz targets for the project's own state and settings files: strict JSON (``shapeio.files.parse_json``),
a ShapeMOD discovery state (``Discovery.from_json``) and a ShapeMOD settings file (``load_config``).

Each seed is a file the project writes; mutations may only end in the reader's own error (``InputError`` for
plain JSON, ``ParseError`` for the two ShapeMOD files), never a bare ``KeyError``, ``TypeError``,
``OverflowError`` or ``RecursionError``.
"""
from __future__ import annotations

import json
import os
import tempfile

from shapeio.files import InputError, parse_json
from shapeprog.errors import ParseError
from shapeprog.macros.api import load_library
from shapeprog.macros.state import Discovery
from shapeprog.macros.config import DEFAULTS, load_config

from fuzz.engine import Target

__all__ = ["TARGETS"]

_DIR = tempfile.mkdtemp(prefix="fuzz-files-")


def _numbers(value) -> list[float]:
    """The finite-checked numbers of a decoded JSON value (bools and strings aside)."""
    if isinstance(value, dict):
        return [x for v in value.values() for x in _numbers(v)]
    if isinstance(value, list):
        return [x for v in value for x in _numbers(v)]
    return [float(value)] if type(value) in (int, float) and abs(value) < 1e300 else []


def _json_seeds() -> list[bytes]:
    return [json.dumps(v, indent=1).encode() for v in (
        {"lengths": [3, 5, 7], "complete": True, "seed": 0, "scale": 0.001},
        {"train": [1, 2, 3], "val": [4], "test": [], "n_points": 10000, "note": "a \"quoted\" [string]"},
        [[0.5, -1e-9, 2.5e10], {"a": None, "b": False}])]


def _run_json(data: bytes) -> list[float]:
    return _numbers(parse_json(data.decode("utf-8", "replace"), "x.json"))


def _state_seeds() -> list[bytes]:
    lib = load_library("chair")
    names = [m.name for m in lib.macros]
    full = Discovery(list(lib.macros), names[:3], [[0, 1], [0]], [{"round": 1, "f_after": 12.5}], len(names))
    return [Discovery([], [], [[0]], [], 0).to_json("d" * 64, DEFAULTS, 0).encode(),
            full.to_json("d" * 64, DEFAULTS, 1, start="e" * 64).encode()]


def _run_state(data: bytes) -> list[float]:
    state, raw = Discovery.from_json(data.decode("utf-8", "replace"), "state.json")
    return [float(state.counter), float(len(state.active)), *(float(o) for c in state.current for o in c)]


def _config_seeds() -> list[bytes]:
    text = "".join(f"{k}: {json.dumps(v)}\n" for k, v in DEFAULTS.items())
    return [text.encode(), b"num_rounds: 3\nabs_beam_size: 4\n# a comment\n", b""]


def _run_config(data: bytes) -> list[float]:
    path = os.path.join(_DIR, "config.yaml")
    with open(path, "wb") as f:
        f.write(data)
    try:
        cfg = load_config(path)
    finally:
        os.unlink(path)
    return [float(v) for v in cfg.values() if type(v) in (int, float)]


TARGETS = [Target("shapeio/json", _json_seeds(), _run_json, (InputError,), 1.0),
           Target("macros/discovery-state", _state_seeds(), _run_state, (ParseError,), 2.0),
           Target("macros/config", _config_seeds(), _run_config, (ParseError,), 2.0)]
