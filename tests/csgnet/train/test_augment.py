"""The 2D training augmentation (csgnet.train.augment.jitter)."""
import numpy as np
import pytest
import torch

from csgnet.renderer.reference import render_np
from csgnet.synth import sample_programs
from csgnet.train.augment import jitter, jitter_reference
from csgnet.vocab import vocabulary


def _images(seed=0, n=6):
    vocab = vocabulary(2)
    rows = sample_programs(2, 5, n, np.random.default_rng(seed))
    return np.stack([render_np(vocab.decode(r)) for r in rows])


def test_jitter_identity_and_shapes():
    imgs = _images()
    same = jitter(imgs, np.random.default_rng(0), shift=0.0, zoom=0.0)
    assert same.dtype == bool and same.shape == imgs.shape and (same == imgs).all()
    t = torch.from_numpy(imgs)
    out = jitter(t, torch.Generator().manual_seed(0))
    assert isinstance(out, torch.Tensor) and out.dtype == torch.bool and out.shape == (6, 64, 64)
    again = jitter(t, torch.Generator().manual_seed(0))
    assert torch.equal(out, again)
    with pytest.raises(ValueError, match=r"\(B, 64, 64\)"):
        jitter(imgs[0], np.random.default_rng(0))


def test_jitter_matches_the_affine_formula_and_draw_order():
    imgs = _images(1, 4)
    out = jitter(imgs, np.random.default_rng(5))
    u = np.random.default_rng(5).random((4, 4))  # per image: t_row, t_col, z_row, z_col
    rows, cols = np.meshgrid(np.arange(64), np.arange(64), indexing="ij")
    changed = 0
    for b in range(4):
        t_row, t_col = -3 + 6 * u[b, 0], -3 + 6 * u[b, 1]
        z_row, z_col = (1 - 2 / 64) + (4 / 64) * u[b, 2], (1 - 2 / 64) + (4 / 64) * u[b, 3]
        sr = z_row * (rows - 32.5) + t_row + 32.5
        sc = z_col * (cols - 32.5) + t_col + 32.5
        ir = np.clip(np.floor(sr + 0.5), 0, 63).astype(int)
        ic = np.clip(np.floor(sc + 0.5), 0, 63).astype(int)
        want = imgs[b][ir, ic]
        assert (out[b] == want).all()
        changed += int((out[b] != imgs[b]).sum())
    assert changed > 0


def test_jitter_equals_scipy_affine_transform_pixel_for_pixel():
    # the executable definition (jitter_reference): scipy.ndimage.affine_transform(order=0, mode='nearest')
    # per image with the same draws; the batched gather must give the same pixels, for NumPy and torch inputs
    imgs = np.random.default_rng(11).random((300, 64, 64)) < 0.5
    for shift, zoom in ((3.0, 2.0 / 64.0), (7.5, 0.2), (0.5, 0.0)):
        want = jitter_reference(imgs, np.random.default_rng(3), shift=shift, zoom=zoom)
        got = jitter(imgs, np.random.default_rng(3), shift=shift, zoom=zoom)
        assert got.dtype == bool and (got == want).all()
        got_t = jitter(torch.from_numpy(imgs), np.random.default_rng(3), shift=shift, zoom=zoom)
        assert got_t.dtype == torch.bool and torch.equal(got_t, torch.from_numpy(want))
    # the torch.Generator draws go through the same path: the same 4 uniforms per image as float64
    want = jitter_reference(imgs, torch.Generator().manual_seed(9))
    assert torch.equal(jitter(torch.from_numpy(imgs), torch.Generator().manual_seed(9)), torch.from_numpy(want))


def test_jitter_of_an_empty_batch_and_of_non_bool_images():
    assert jitter(np.zeros((0, 64, 64), bool), np.random.default_rng(0)).shape == (0, 64, 64)
    assert jitter(torch.zeros((0, 64, 64), dtype=torch.bool), np.random.default_rng(0)).shape == (0, 64, 64)
    # non-bool values are cast through uint8 (0.25 and 0.5 -> 0 -> False, 3 -> True)
    vals = np.full((3, 64, 64), 3.0)
    vals[0], vals[1] = 0.25, 0.5
    out = jitter(vals, np.random.default_rng(0))
    assert out.dtype == bool and not out[0].any() and not out[1].any() and out[2].all()
    out_t = jitter(torch.from_numpy(vals), np.random.default_rng(0))
    assert torch.equal(out_t, torch.from_numpy(out))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU")
def test_jitter_on_the_gpu_equals_the_cpu():
    imgs = torch.from_numpy(np.random.default_rng(4).random((64, 64, 64)) < 0.5)
    cpu = jitter(imgs, np.random.default_rng(2))
    gpu = jitter(imgs.cuda(), np.random.default_rng(2))
    assert gpu.device.type == "cuda" and torch.equal(gpu.cpu(), cpu)


# ---------------------------------------------------------------------------------------------
# mirror symmetries of 3D programs

def test_mirrored_programs_draw_the_mirrored_shape_moved_by_one_voxel():
    from itertools import product
    from csgnet.renderer import render_tokens
    from csgnet.synth import sample_programs
    from csgnet.train.augment import symmetry_tables
    tables = symmetry_tables(3)
    assert tables.shape[0] == 16 and torch.equal(tables[0], torch.arange(tables.shape[1]))
    rows = torch.as_tensor(np.asarray(sample_programs(3, 7, 12, np.random.default_rng(3))))
    lengths = torch.full((len(rows),), 7)
    image = render_tokens(rows, 3, lengths).clone()
    checked = 0
    for g, (swap, flips) in enumerate(product((False, True), product((False, True), repeat=3))):
        mapped = tables[g][rows]
        ok = (mapped >= 0).all(1)
        want = image[ok]
        for a in range(3):
            if flips[a]:
                want = torch.roll(want.flip(1 + a), 1, 1 + a)
        if swap:
            want = want.transpose(1, 2)
        got = render_tokens(mapped[ok], 3, lengths[ok])
        assert torch.equal(got, want), g
        checked += int(ok.sum())
    assert checked > 12 * 12


def test_mirror_programs_keeps_programs_whose_image_leaves_the_vocabulary():
    from csgnet.train.augment import mirror_programs, symmetry_tables
    from csgnet.vocab import vocabulary
    vocab, tables = vocabulary(3), symmetry_tables(3)
    missing = int((tables < 0).any(0).nonzero()[0])
    row = torch.tensor([missing, vocab.index("sp(32,32,32,16)"), vocab.index("+"), vocab.stop])
    images = {tuple(tables[g][row].tolist()) for g in range(16) if (tables[g][row] >= 0).all()}
    assert 1 <= len(images) < 16
    out = mirror_programs(row.repeat(200, 1), np.random.default_rng(0))
    got = {tuple(r) for r in out.tolist()}
    assert got <= images | {tuple(row.tolist())} and len(got) == len(images)
    tokens = torch.tensor([[vocab.index("cu(16,24,40,12)"), vocab.index("sp(32,32,32,16)"), vocab.index("+"),
                            vocab.stop]] * 200)
    out = mirror_programs(tokens, np.random.default_rng(0))
    assert len({tuple(r) for r in out.tolist()}) == 16
    assert (out[:, 2:] == tokens[:, 2:]).all()


def test_mirror_pairs_map_a_program_and_its_target_alike():
    from csgnet.renderer import render_tokens
    from csgnet.train.augment import mirror_pairs, mirror_programs, mirror_volumes
    rows = torch.as_tensor(np.asarray(sample_programs(3, 5, 40, np.random.default_rng(5))))
    lengths = torch.full((len(rows),), 5)
    targets = render_tokens(rows, 3, lengths).clone()
    tokens, volumes = mirror_pairs(rows, targets, np.random.default_rng(1))
    assert torch.equal(tokens, mirror_programs(rows, np.random.default_rng(1)))  # the same draws
    assert (tokens != rows).any(1).sum() > 30  # most pairs moved
    assert torch.equal(render_tokens(tokens, 3, lengths), volumes)  # each label still draws its target
    assert torch.equal(mirror_volumes(targets, torch.zeros(len(rows), dtype=torch.int64)), targets)
    # symmetry 14 = 8 (exchange) + 4 (mirror x) + 2 (mirror y): a voxel (x, y, z) goes to (64 - y, 64 - x, z)
    one = torch.zeros(1, 64, 64, 64, dtype=torch.bool)
    one[0, 10, 20, 30] = True
    assert mirror_volumes(one, torch.tensor([14]))[0].nonzero().tolist() == [[44, 54, 30]]
