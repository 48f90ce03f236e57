"""Atomic checkpoints: a failed save leaves nothing behind."""
import pytest
import torch

from csgnet.train.checkpoint import AtomicCheckpointIO


def test_atomic_checkpoint_io_leaves_nothing_on_failure(tmp_path):
    io = AtomicCheckpointIO()
    io.save_checkpoint({"a": torch.zeros(2)}, tmp_path / "x.ckpt")
    assert torch.load(tmp_path / "x.ckpt", weights_only=True)["a"].shape == (2,)

    class Bad:
        def __reduce__(self):
            raise RuntimeError("cannot pickle")

    with pytest.raises(RuntimeError):
        io.save_checkpoint({"a": Bad()}, tmp_path / "y.ckpt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.ckpt"]
