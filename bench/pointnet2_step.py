"""Training step of the PointNet++ SSG point-cloud encoder: ours against a naive plain-PyTorch version.

One step is the encoder's forward and backward on a batch of ``--batch`` clouds (MSE to random codes;
no optimiser step), for each cloud size in ``--points``. ``ours`` is
:class:`shapeprog.pointcloud.PointNet2SSG`. ``naive`` is written below in the common pure-PyTorch way:
farthest-point sampling with a boolean-mask update and advanced indexing, a ball query that sorts all N
candidates of every centre, grouping by advanced indexing and the shared MLP as 1x1 ``Conv2d`` +
``BatchNorm2d`` + ReLU on channel-first groups; it has the same sizes and parameter count, and its
sampling and ball query also run on one intra-op thread (as ours do on the CPU), so that the ratio
compares the algorithms. ``sampling``
is the part of ours that is not the MLP (farthest-point sampling and ball query of SA1 and SA2) in the
same step. Clouds are points on the faces of the cube [-0.5, 0.5]^3 (a surface, like the PartNet
samples). Each figure is the median of ``--steps`` steps after one warm-up step: wall-clock ms and the
process's CPU seconds (less sensitive to other jobs on a shared machine).

Usage::

    OMP_NUM_THREADS=2 python bench/pointnet2_step.py [--points 1024 2048 10000] [--batch 16] [--steps 3]
        [--threads N] [--devices cpu cuda] [--npoints 512 128] [--nsamples 64 64] [--no-naive]
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import torch
from torch import nn

from shapeprog.pointcloud import PointNet2SSG
from shapeprog.pointcloud.encoder import NPOINTS, NSAMPLES, RADII, WIDTHS
from shapeprog.pointcloud.ops import _ball_query, _farthest_point_sample, _group, _one_cpu_thread

# --------------------------------------------------------------------------------------------------
# the naive version


def naive_fps(xyz: torch.Tensor, m: int) -> torch.Tensor:
    b, n, _ = xyz.shape
    out = torch.zeros(b, m, dtype=torch.long, device=xyz.device)
    dist = torch.full((b, n), 1e10, device=xyz.device)
    far = torch.zeros(b, dtype=torch.long, device=xyz.device)
    rows = torch.arange(b, device=xyz.device)
    for i in range(m):
        out[:, i] = far
        d = ((xyz - xyz[rows, far].view(b, 1, 3)) ** 2).sum(-1)
        closer = d < dist
        dist[closer] = d[closer]
        far = dist.max(-1)[1]
    return out


def naive_ball_query(radius: float, k: int, xyz: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    b, n, _ = xyz.shape
    m = centres.shape[1]
    d2 = -2 * centres @ xyz.transpose(1, 2) + (centres ** 2).sum(-1, keepdim=True) + (xyz ** 2).sum(-1).unsqueeze(1)
    idx = torch.arange(n, device=xyz.device).view(1, 1, n).repeat(b, m, 1)
    idx[d2 > radius ** 2] = n
    idx = idx.sort(dim=-1)[0][:, :, :k]  # every candidate sorted
    first = idx[:, :, :1].expand(-1, -1, k)
    missing = idx == n
    idx[missing] = first[missing]
    return idx


def index_points(points: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    rows = torch.arange(points.shape[0], device=points.device).view(-1, *([1] * (idx.dim() - 1)))
    return points[rows, idx]


class NaiveSA(nn.Module):
    def __init__(self, in_channels, widths, npoint=None, radius=None, nsample=None):
        super().__init__()
        self.npoint, self.radius, self.nsample = npoint, radius, nsample
        layers, prev = [], in_channels + 3
        for w in widths:
            layers += [nn.Conv2d(prev, w, 1, bias=False), nn.BatchNorm2d(w), nn.ReLU()]
            prev = w
        self.mlp = nn.Sequential(*layers)

    def forward(self, xyz, points):
        if self.npoint is None:
            centres = xyz.new_zeros(xyz.shape[0], 1, 3)
            grouped = torch.cat([xyz, points], -1).unsqueeze(1)  # (B, 1, N, C)
        else:
            with torch.no_grad(), _one_cpu_thread(xyz.device):  # one thread, as ours (ops._one_cpu_thread)
                fps = naive_fps(xyz, self.npoint)
                idx = naive_ball_query(self.radius, self.nsample, xyz, index_points(xyz, fps))
            centres = index_points(xyz, fps)
            grouped = torch.cat([index_points(xyz, idx) - centres.unsqueeze(2), index_points(points, idx)], -1)
        out = self.mlp(grouped.permute(0, 3, 2, 1))  # (B, C, K, M)
        return centres, out.max(2)[0].transpose(1, 2)


class NaivePointNet2(nn.Module):
    def __init__(self, npoints, radii, nsamples, widths, out_dim=256):
        super().__init__()
        self.sa1 = NaiveSA(3, widths[0], npoints[0], radii[0], nsamples[0])
        self.sa2 = NaiveSA(widths[0][-1], widths[1], npoints[1], radii[1], nsamples[1])
        self.sa3 = NaiveSA(widths[1][-1], widths[2])
        self.fc = nn.Linear(widths[2][-1], out_dim)

    def forward(self, clouds):
        xyz, f = self.sa1(clouds, clouds)
        xyz, f = self.sa2(xyz, f)
        return self.fc(self.sa3(xyz, f)[1].squeeze(1))


# --------------------------------------------------------------------------------------------------
# measurement


def surface_clouds(b: int, n: int, seed: int = 0) -> torch.Tensor:
    """Points on the faces of the cube [-0.5, 0.5]^3, uniform over the faces."""
    g = torch.Generator().manual_seed(seed)
    p = torch.rand(b, n, 3, generator=g) - 0.5
    axis = torch.randint(0, 3, (b, n, 1), generator=g)
    side = torch.randint(0, 2, (b, n, 1), generator=g).float() - 0.5
    return p.scatter(2, axis, side)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def timed(fn, device, steps: int) -> tuple[float, float]:
    """(median wall ms, median CPU s) of ``steps`` calls after one warm-up call."""
    fn()
    _sync(device)
    wall, cpu = [], []
    for _ in range(steps):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        _sync(device)
        wall.append(1e3 * (time.perf_counter() - t0))
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def step_fn(net, clouds, targets):
    def step():
        net.zero_grad(set_to_none=True)
        loss = (net(clouds) - targets).square().sum(1).mean()
        loss.backward()
    return step


def sampling_fn(clouds, npoints, radii, nsamples):
    def run():
        centres = _group(clouds, _farthest_point_sample(clouds, npoints[0]))
        _ball_query(radii[0], nsamples[0], clouds, centres)
        centres2 = _group(centres, _farthest_point_sample(centres, npoints[1]))
        _ball_query(radii[1], nsamples[1], centres, centres2)
    return run


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, nargs="+", default=[1024, 2048, 10000], help="points per cloud")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--steps", type=int, default=3, help="timed steps per figure (median)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's, i.e. OMP_NUM_THREADS)")
    ap.add_argument("--devices", nargs="+", default=None, help="default: cpu, and cuda when available")
    ap.add_argument("--npoints", type=int, nargs=2, default=list(NPOINTS), help="centres of SA1 and SA2")
    ap.add_argument("--nsamples", type=int, nargs=2, default=list(NSAMPLES), help="neighbours per ball of SA1 and SA2")
    ap.add_argument("--no-naive", action="store_true", help="measure ours only")
    args = ap.parse_args(argv)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    devices = args.devices or (["cpu"] + (["cuda"] if torch.cuda.is_available() else []))
    print(f"# command: {' '.join(['python'] + sys.argv)}")
    print(f"# machine: {platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"threads {torch.get_num_threads()}, load average {os.getloadavg()[0]:.1f}"
          + (f", GPU {torch.cuda.get_device_name()}" if "cuda" in devices else ""))
    print(f"# batch {args.batch}; SA1 {args.npoints[0]} centres x {args.nsamples[0]} neighbours, SA2 {args.npoints[1]} x "
          f"{args.nsamples[1]}; one step = forward + backward (no optimiser step); median of {args.steps} steps")
    sizes = dict(npoints=tuple(args.npoints), radii=RADII, nsamples=tuple(args.nsamples), widths=WIDTHS)
    for name in devices:
        device = torch.device(name)
        torch.manual_seed(0)
        ours = PointNet2SSG(**sizes).to(device)
        naive = None if args.no_naive else NaivePointNet2(**sizes).to(device)
        if naive is not None:
            assert sum(p.numel() for p in naive.parameters()) == sum(p.numel() for p in ours.parameters())
        for n in args.points:
            clouds = surface_clouds(args.batch, n).to(device)
            targets = torch.randn(args.batch, 256, generator=torch.Generator().manual_seed(1)).to(device)
            ms, cpu = timed(step_fn(ours, clouds, targets), device, args.steps)
            s_ms, s_cpu = timed(sampling_fn(clouds, args.npoints, RADII, args.nsamples), device, args.steps)
            line = (f"{name} N={n:6d}: ours {ms:9.1f} ms/step ({cpu:6.2f} CPU s), of which sampling + ball query "
                    f"{s_ms:7.1f} ms ({100 * s_ms / ms:4.1f}%)")
            if naive is not None:
                n_ms, n_cpu = timed(step_fn(naive, clouds, targets), device, args.steps)
                line += f"; naive {n_ms:9.1f} ms/step ({n_cpu:6.2f} CPU s); naive / ours {n_ms / ms:5.2f}x"
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
