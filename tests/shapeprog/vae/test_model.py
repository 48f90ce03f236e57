"""Encoder, decoder and VAE: parameter counts, shapes, bottom-up child codes, teacher forcing, devices, overfit."""
import pytest
import torch

from shapeprog.lang import numbers, parse, replace_numbers, to_text
from shapeprog.vae.losses import program_loss
from shapeprog.vae.model import VAE, Decoder, Encoder, one_hot_argmax, prediction_tree
from shapeprog.vae.vectors import VectorNode, program_to_tree, tree_to_program

FLAT = """bbox = Cuboid(0.9, 1.5, 0.9, True)
cube0 = Cuboid(0.9, 0.2, 0.9, True)
cube1 = Cuboid(0.1, 1.3, 0.1, True)
attach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)
attach(cube1, cube0, 0.5, 1.0, 0.5, 0.1, 0.0, 0.1)
reflect(cube1, Z)
"""


def _count(m):
    return sum(p.numel() for p in m.parameters())


def test_parameter_counts_of_the_reference():
    assert _count(Encoder(256)) == 740_352
    assert _count(Decoder(256)) == 1_406_403


def test_state_dict_keys_follow_the_reference_modules():
    enc, dec = Encoder(8).state_dict(), Decoder(8).state_dict()
    assert {"h_start", "inp_net.l1.weight", "gru.weight_hh_l0", "sampler.mlp2var.bias"} <= set(enc)
    heads = {k.split(".")[0] for k in dec}
    assert heads == {"bbdimNet", "gru", "inp_net", "cmd_net", "cube_net", "dim_net", "align_net", "att_net",
                     "squeeze_net", "sym_net", "next_net", "leaf_net"}


def test_forward_shapes_and_sampling(two_levels):
    torch.manual_seed(0)
    tree = program_to_tree(parse(two_levels))
    vae = VAE(16)
    out = vae(tree, sample=False)
    assert [tuple(n.lines.shape) for n in out.nodes] == [(7, 63), (5, 63)]
    assert [tuple(n.leaf.shape) for n in out.nodes] == [(3,), (2,)]
    assert out.bbox_dims.shape == (3,) and torch.equal(out.z, out.mu)
    g1, g2 = torch.Generator().manual_seed(1), torch.Generator().manual_seed(1)
    z1, mu, logvar = vae.encode(tree, sample=True, generator=g1)
    z2, _, _ = vae.encode(tree, sample=True, generator=g2)
    assert torch.equal(z1, z2) and not torch.equal(z1, mu) and logvar.shape == (16,)


def test_encoder_is_bottom_up_child_code_replaces_the_cuboid_line(two_levels):
    torch.manual_seed(0)
    enc = Encoder(16)
    tree = program_to_tree(parse(two_levels))
    child = tree.children[1]
    # the child's code stands in for its Cuboid line: changing the line's own numbers changes nothing
    other = tree.lines.clone()
    other[1, 40:43] += 0.3
    same = VectorNode(other, tree.children, tree.name)
    assert torch.allclose(enc.encode_node(same), enc.encode_node(tree))
    # ... while a change inside the child does
    cl = child.lines.clone()
    cl[1, 40] += 0.3
    changed = VectorNode(tree.lines, (None, VectorNode(cl, ()), None), tree.name)
    assert not torch.allclose(enc.encode_node(changed), enc.encode_node(tree))
    # a leaf's Cuboid line is embedded from its own vector
    leafy = VectorNode(other, (None, None, None), tree.name)
    assert not torch.allclose(enc.encode_node(leafy), enc.encode_node(VectorNode(tree.lines, (None, None, None))))


def test_decoder_greedy_equals_teacher_forced_when_the_argmax_is_fed():
    torch.manual_seed(0)
    dec = Decoder(16)
    inp = torch.randn(2, 5, 63)
    h = torch.randn(1, 2, 16)
    bb = torch.rand(2, 3)
    greedy = dec(inp, h, h, bb, depth=3)
    own = torch.cat([one_hot_argmax(greedy.lines[:, :, :7]), one_hot_argmax(greedy.lines[:, :, 7:40], 3)], dim=2)
    forced = dec(inp, h, h, bb, depth=2, teacher=own)
    assert torch.allclose(greedy.lines, forced.lines) and torch.allclose(greedy.h, forced.h)
    assert greedy.lines.shape == (2, 5, 63) and greedy.next.shape == (2, 5, 16) and greedy.leaf.shape == (2, 5)
    with pytest.raises(ValueError, match=r"inp must be \(B, T, 63\), got \(2, 5\)"):
        dec(torch.zeros(2, 5), h, h, bb, depth=0)


def test_one_hot_argmax():
    x = torch.tensor([[0.1, 0.9, -1.0, 2.0, 1.0, 0.0]])
    assert one_hot_argmax(x, 2).tolist() == [[0.0, 1.0, 0.0, 1.0, 0.0, 0.0]]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_dtype_and_device(dtype, two_levels):
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices:
        torch.manual_seed(0)
        vae = VAE(16).to(device=device, dtype=dtype)
        tree = program_to_tree(parse(two_levels), dtype=dtype, device=device)
        total, _ = program_loss(vae(tree), tree)
        total.backward()
        assert total.dtype == dtype and total.device.type == device and torch.isfinite(total)


def _structure(p):
    return to_text(replace_numbers(p, [0.0] * len(numbers(p))))


def _reconstructs(vae, tree, program, tol):
    with torch.no_grad():
        try:
            pred = tree_to_program(prediction_tree(vae(tree, sample=False), tree))
        except ValueError:  # e.g. a node that does not start with a Cuboid line yet
            return False
    if _structure(pred) != _structure(program):
        return False
    return max(abs(a - b) for a, b in zip(numbers(pred), numbers(program))) <= tol


def test_tiny_overfit_reconstructs_programs_teacher_forced(two_levels):
    """Two programs (three nodes, every statement kind) are reconstructed: every command, cuboid, face, axis,
    count, aligned flag and sub-program choice exact, every number within 0.01, in a few hundred steps."""
    torch.manual_seed(0)
    trees = [program_to_tree(parse(t)) for t in (two_levels, FLAT)]
    progs = [tree_to_program(t) for t in trees]  # the targets, in the corpus format
    vae = VAE(64)
    opt = torch.optim.Adam(vae.parameters(), lr=1e-2)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, 0.99)
    for step in range(400):
        loss = sum(program_loss(vae(t, sample=False), t, kl=False)[0] for t in trees)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 10 == 9 and all(_reconstructs(vae, t, p, 0.01) for t, p in zip(trees, progs)):
            break
    else:
        pytest.fail(f"not reconstructed after 400 steps (loss {loss.item():.3f})")
