import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True, scope="session")
def _single_thread_torch():
    """Tests run on 2-core CI machines next to other work: one torch thread keeps them fast and steady."""
    try:
        import torch
    except ImportError:  # pragma: no cover
        return
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def train_main():
    """``train.main``: the one LightningCLI of the repository root's ``train.py``."""
    spec = importlib.util.spec_from_file_location("train", ROOT / "train.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    """The on-disk cache (shapeio.cache) of the test session is a fresh folder: tests neither read a user's
    cache nor leave entries in it."""
    import os

    from shapeio.cache import CACHE_ENV

    old = os.environ.get(CACHE_ENV)
    os.environ[CACHE_ENV] = str(tmp_path_factory.mktemp("shape-programs-cache"))
    yield
    if old is None:
        os.environ.pop(CACHE_ENV, None)
    else:
        os.environ[CACHE_ENV] = old
