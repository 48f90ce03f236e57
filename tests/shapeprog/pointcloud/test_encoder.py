"""PointNet++ SSG encoder: the spec's parameter count, shapes, gradients, determinism, devices, bad input, overfit."""
import pytest
import torch

from shapeprog.errors import PointCloudError
from shapeprog.pointcloud import PointNet2SSG, SetAbstraction
from shapeprog.pointcloud.encoder import NPOINTS, NSAMPLES, OUT_DIM, RADII, WIDTHS

TINY = dict(out_dim=6, npoints=(16, 4), radii=(0.3, 0.6), nsamples=(8, 8), widths=((8, 8, 16), (16, 16, 32), (32, 32, 64)))


def _clouds(b, n, seed, dtype=torch.float32):
    return torch.rand(b, n, 3, generator=torch.Generator().manual_seed(seed), dtype=dtype) - 0.5


def test_spec_sizes_and_parameter_count():
    assert (NPOINTS, RADII, NSAMPLES, OUT_DIM) == ((512, 128), (0.2, 0.4), (64, 64), 256)
    assert WIDTHS == ((64, 64, 128), (128, 128, 256), (256, 512, 1024))
    # by hand from the spec's layer sizes: each shared-MLP layer is a bias-free 1x1 map (in * out) and a
    # batch norm (scale and shift: 2 * out); use_xyz adds 3 input channels; the head is Linear 1024 -> 256
    mlps = [[3 + 3, 64, 64, 128], [128 + 3, 128, 128, 256], [256 + 3, 256, 512, 1024]]
    count = sum(a * b + 2 * b for mlp in mlps for a, b in zip(mlp, mlp[1:])) + 1024 * 256 + 256
    net = PointNet2SSG()
    assert sum(p.numel() for p in net.parameters()) == count == 1_067_776
    assert net.min_points == 512
    assert [sa.npoint for sa in (net.sa1, net.sa2, net.sa3)] == [512, 128, None]


def test_spec_encoder_output_shape():
    net = PointNet2SSG().eval()
    with torch.no_grad():
        out = net(_clouds(2, 600, 0))
    assert out.shape == (2, 256) and out.dtype == torch.float32 and torch.isfinite(out).all()


def test_set_abstraction_shapes():
    sa = SetAbstraction(2, (5, 7), npoint=6, radius=0.4, nsample=3)
    xyz, feats = _clouds(3, 20, 1), torch.randn(3, 20, 2)
    centres, out = sa(xyz, feats)
    assert centres.shape == (3, 6, 3) and out.shape == (3, 6, 7)
    assert torch.equal(centres[:, 0], xyz[:, 0])  # farthest-point sampling starts at point 0
    centres, out = SetAbstraction(2, (4,))(xyz, feats)  # group-all
    assert centres.shape == (3, 1, 3) and not centres.any() and out.shape == (3, 1, 4)
    assert SetAbstraction(0, (4,), npoint=5, radius=0.3, nsample=2)(xyz)[1].shape == (3, 5, 4)


@pytest.mark.parametrize("group_all", [False, True])
def test_set_abstraction_gradcheck(group_all):
    torch.manual_seed(0)
    if group_all:
        sa = SetAbstraction(2, (4, 3)).double()
    else:
        sa = SetAbstraction(2, (4, 3), npoint=4, radius=0.5, nsample=3).double()
    xyz = _clouds(2, 10, 2, torch.float64).requires_grad_()
    feats = torch.randn(2, 10, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(3), requires_grad=True)
    for training in (True, False):  # batch statistics, then the running ones
        sa.train(training)
        assert torch.autograd.gradcheck(lambda x, f: sa(x, f)[1], (xyz, feats), fast_mode=True)


def test_gradients_reach_every_parameter_and_the_input():
    torch.manual_seed(0)
    net = PointNet2SSG(**TINY)
    clouds = _clouds(3, 64, 4).requires_grad_()
    net(clouds).square().sum().backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name
    assert clouds.grad.abs().sum() > 0


def test_deterministic_and_batched_like_single_clouds():
    torch.manual_seed(0)
    net = PointNet2SSG(**TINY)
    clouds = _clouds(3, 64, 5)
    a, b = net(clouds), net(clouds)
    assert torch.equal(a, b)
    a.sum().backward()
    g = [p.grad.clone() for p in net.parameters()]
    net.zero_grad()
    net(clouds).sum().backward()
    assert all(torch.equal(x, p.grad) for x, p in zip(g, net.parameters()))
    net.eval()
    with torch.no_grad():
        whole = net(clouds)
        for i in range(3):
            assert torch.allclose(net(clouds[i:i + 1])[0], whole[i], rtol=1e-5, atol=1e-6)


def test_config_rebuilds_the_same_model():
    torch.manual_seed(0)
    net = PointNet2SSG(**TINY)
    copy = PointNet2SSG(**net.config)
    copy.load_state_dict(net.state_dict())
    net.eval(), copy.eval()
    clouds = _clouds(2, 40, 6)
    assert torch.equal(net(clouds), copy(clouds))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU")
def test_cuda_matches_cpu():
    torch.manual_seed(0)
    net = PointNet2SSG(**TINY).double()
    clouds = _clouds(3, 64, 7, torch.float64)
    want = net(clouds)
    got = net.cuda()(clouds.cuda())
    assert torch.allclose(got.cpu(), want, rtol=1e-9, atol=1e-12)


def test_bad_input_raises_point_cloud_errors():
    net = PointNet2SSG(**TINY)
    with pytest.raises(PointCloudError, match=r"`clouds`: must have shape \(B, N, 3\), got \(2, 64, 4\)"):
        net(torch.zeros(2, 64, 4))
    with pytest.raises(PointCloudError, match="has 15 points per cloud, fewer than the 16 needed"):
        net(_clouds(2, 15, 8))
    bad = _clouds(3, 64, 8)
    bad[2, 7, 0] = float("inf")
    with pytest.raises(PointCloudError, match="`clouds`: cloud 2: a coordinate is not finite") as e:
        net(bad)
    assert e.value.index == 2
    with pytest.raises(PointCloudError, match="float64 on cpu but the encoder is torch.float32"):
        net(_clouds(2, 64, 8, torch.float64))
    with pytest.raises(TypeError, match="torch.Tensor"):
        net([[0.0, 0.0, 0.0]] * 20)
    sa = SetAbstraction(2, (4,), npoint=4, radius=0.3, nsample=2)
    with pytest.raises(PointCloudError, match="must have 2 channels"):
        sa(_clouds(1, 10, 9), torch.zeros(1, 10, 3))
    with pytest.raises(PointCloudError, match="takes 2 feature channels, got none"):
        sa(_clouds(1, 10, 9))


def test_bad_sizes_raise_value_errors():
    with pytest.raises(ValueError, match="`npoints` must not grow"):
        PointNet2SSG(npoints=(64, 128))
    with pytest.raises(ValueError, match="take 2 values"):
        PointNet2SSG(radii=(0.2,))
    with pytest.raises(ValueError, match="`out_dim` must be a positive int"):
        PointNet2SSG(out_dim=0)
    with pytest.raises(ValueError, match="`radius`"):
        SetAbstraction(3, (4,), npoint=4, radius=0.0, nsample=2)
    with pytest.raises(ValueError, match="group-all"):
        SetAbstraction(3, (4,), radius=0.2)


def _adam_step(params, state, step, lr=2e-2, betas=(0.9, 0.999), eps=1e-8):
    """Adam by hand: the first torch.optim optimiser of a process costs seconds of imports."""
    with torch.no_grad():
        for p, (m, v) in zip(params, state):
            m.mul_(betas[0]).add_(p.grad, alpha=1 - betas[0])
            v.mul_(betas[1]).addcmul_(p.grad, p.grad, value=1 - betas[1])
            p -= lr * (m / (1 - betas[0] ** step)) / ((v / (1 - betas[1] ** step)).sqrt() + eps)


def test_overfits_a_few_clouds():
    torch.manual_seed(0)
    net = PointNet2SSG(out_dim=4, npoints=(8, 4), radii=(0.3, 0.6), nsamples=(4, 4),
                       widths=((8, 16), (16, 32), (32, 32)))
    clouds, targets = _clouds(4, 24, 10), torch.randn(4, 4, generator=torch.Generator().manual_seed(11))
    params = list(net.parameters())
    state = [(torch.zeros_like(p), torch.zeros_like(p)) for p in params]
    losses = []
    for step in range(1, 26):
        loss = (net(clouds) - targets).square().sum(1).mean()
        losses.append(float(loss.detach()))
        net.zero_grad()
        loss.backward()
        _adam_step(params, state, step)
    assert losses[-1] < 0.1 * losses[0], losses
