"""The fuzz target modules: each defines ``TARGETS``, a list of :class:`fuzz.engine.Target`.

``tests/fuzz/test_fuzz.py`` and ``bench/fuzz.py`` run every target of every module listed here; a new
family adds its module with one line.
"""

from __future__ import annotations

import importlib

MODULES = [
    "fuzz.csg_targets",
    "fuzz.shapeassembly_targets",
    "fuzz.pointcloud_targets",
    "fuzz.shapecoder_targets",
    "fuzz.editor_targets",
    "fuzz.editor_message_targets",
    "fuzz.file_targets",
    "fuzz.library_targets",
]


def targets() -> list:
    """Every registered :class:`~fuzz.engine.Target`, in registry order."""
    return [t for name in MODULES for t in importlib.import_module(name).TARGETS]
