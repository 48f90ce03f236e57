"""Batch streams: equal counts per length, determinism, shards per rank, reshuffled passes; no Lightning."""
import subprocess
import sys

import torch

from csgnet.train.streams import MixedLengthBatches, ShuffledBatches
from csgnet.vocab import vocabulary


def tables(n=10):
    stop = vocabulary(2).stop
    out = {}
    for L_ in (3, 5):
        t = torch.full((n, 6), stop)
        t[:, :L_] = torch.arange(n * L_).view(n, L_) % 300
        out[L_] = t
    return out


def test_mixed_batches_hold_equal_counts_per_length_and_are_deterministic():
    ds = MixedLengthBatches(2, [3, 5], batch=8, steps=5, max_len=5, tables=tables())
    batches = list(ds)
    assert len(batches) == 5
    for tok, lengths in batches:
        assert tok.shape == (8, 6)
        assert (lengths == 3).sum() == 4 and (lengths == 5).sum() == 4
        stop = vocabulary(2).stop
        assert ((tok != stop).sum(1) == lengths).all()
    again = list(MixedLengthBatches(2, [3, 5], batch=8, steps=5, max_len=5, tables=tables()))
    assert all(torch.equal(a[0], b[0]) for a, b in zip(batches, again))
    # every program of a length is used once before any repeats
    seen = torch.cat([tok[lengths == 3] for tok, lengths in batches[:2]])
    assert len({tuple(r.tolist()) for r in seen[:8]}) == 8


def test_ranks_draw_different_shards():
    a = list(MixedLengthBatches(2, [3, 5], 8, 4, 5, tables(), seed=0, rank=0, world=2))
    b = list(MixedLengthBatches(2, [3, 5], 8, 4, 5, tables(), seed=0, rank=1, world=2))
    assert len(a) == len(b) == 2
    assert not torch.equal(a[0][0], b[0][0])


def test_on_the_fly_batches_are_valid_programs():
    import csgnet

    ds = MixedLengthBatches(2, [3, 5], batch=4, steps=1, max_len=5, tables=None, seed=3)
    tok, lengths = next(iter(ds))
    vocab = vocabulary(2)
    for row, n in zip(tok, lengths):
        assert csgnet.is_valid(vocab.decode(row[: int(n)].tolist()))


def test_shuffled_batches_visit_every_image_once_per_pass():
    images = torch.arange(10).view(10, 1, 1).expand(10, 64, 64).clone()
    ds = ShuffledBatches(images, batch=4, steps=5, seed=1)
    seen = torch.cat([b[:, 0, 0] for b in ds])
    assert len(seen) == 20
    assert sorted(seen[:10].tolist()) == list(range(10)) and sorted(seen[10:20].tolist()) == list(range(10))
    again = torch.cat([b[:, 0, 0] for b in ShuffledBatches(images, 4, 5, seed=1)])
    assert torch.equal(seen, again)
    ds.set_epoch(1)
    assert not torch.equal(torch.cat([b[:, 0, 0] for b in ds]), seen)


def test_streams_and_the_plain_pytorch_layers_do_not_import_lightning():
    code = ("import sys, csgnet, csgnet.models, csgnet.decode, csgnet.inference, csgnet.train, csgnet.train.streams; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('lightning', 'pytorch_lightning')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
