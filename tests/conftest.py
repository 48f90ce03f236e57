import pytest


@pytest.fixture(autouse=True, scope="session")
def _single_thread_torch():
    """Tests run on 2-core CI machines next to other work: one torch thread keeps them fast and steady."""
    try:
        import torch
    except ImportError:  # pragma: no cover
        return
    torch.set_num_threads(1)
