"""Fixtures of the training tests: the repository's ``train.py`` entry point."""
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def train_main():
    """``train.main``: the one LightningCLI of the repository root's ``train.py``."""
    spec = importlib.util.spec_from_file_location("train", ROOT / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main
