"""PointNet++ (single-scale grouping) in plain PyTorch: the set abstraction layer and the cloud encoder.

:class:`SetAbstraction` samples centres by farthest-point sampling, groups each centre's ball
neighbourhood (coordinates relative to the centre, then the features), runs a shared MLP over every
neighbour and max-pools over the neighbourhood; with ``npoint=None`` the whole cloud is one group.
:class:`PointNet2SSG` is the point-cloud encoder of the ShapeAssembly paper
(``/work/shared/specs/shapeassembly.md``, "Point-cloud encoder"): three set abstractions and a linear
layer, ``(B, N, 3) -> (B, out_dim)``; the defaults are the spec's sizes (:data:`NPOINTS`,
:data:`RADII`, :data:`NSAMPLES`, :data:`WIDTHS`, :data:`OUT_DIM`). The point features are the
coordinates themselves, and every MLP also sees the (relative) coordinates, so SA1's MLP reads 3 + 3
channels.

The shared MLP is the reference's 1x1 ``Conv2d`` (no bias) + ``BatchNorm2d`` + ReLU layers written as
``Linear`` (no bias) + ``BatchNorm1d`` + ReLU over the rows of channel-last ``(B, M, K, C)`` groups:
the same function, the same statistics (batch norm over every neighbour of every group and cloud) and
the same parameter count, with the weight stored as ``(out, in)`` instead of ``(out, in, 1, 1)``. On
the 2-core CPU a training step of the spec's encoder took about 25% less CPU time this way than with
the convolutions on channel-first groups. The operations underneath are :mod:`shapeprog.pointcloud.ops`;
how fast a training step is: ``docs/pointcloud.md``.

Example:
    >>> import torch
    >>> net = PointNet2SSG(out_dim=8, npoints=(16, 4), nsamples=(8, 8),
    ...                    widths=((8, 8, 16), (16, 16, 32), (32, 32, 64))).eval()
    >>> tuple(net(torch.rand(2, 100, 3)).shape), net.min_points
    ((2, 8), 16)
"""
from __future__ import annotations

from typing import Optional, Sequence

import torch
from torch import nn

from shapeprog.errors import PointCloudError

from .ops import _check_cloud, _check_features, _farthest_point_sample, _group, _group_all, _query_and_group

__all__ = ["NPOINTS", "NSAMPLES", "OUT_DIM", "PointNet2SSG", "RADII", "SetAbstraction", "WIDTHS"]

#: Centres of the two sampling set abstractions (SA1, SA2); SA3 groups all.
NPOINTS = (512, 128)
#: Ball radii of SA1 and SA2, in the clouds' units (PartNet shapes fit a unit box).
RADII = (0.2, 0.4)
#: Neighbours per ball of SA1 and SA2.
NSAMPLES = (64, 64)
#: Output channels of each layer of the shared MLPs of SA1, SA2 and SA3 (their inputs add 3 coordinates).
WIDTHS = ((64, 64, 128), (128, 128, 256), (256, 512, 1024))
#: Size of the cloud's code (the ShapeAssembly VAE's latent size).
OUT_DIM = 256


def _positive_int(value, name: str) -> int:
    if isinstance(value, bool) or int(value) != value or int(value) < 1:
        raise ValueError(f"`{name}` must be a positive int, got {value!r}")
    return int(value)


class SetAbstraction(nn.Module):
    """One set abstraction of PointNet++: sample centres, group their neighbours, shared MLP, max pool.

    Args:
        in_channels: feature channels C of the incoming points (0: coordinates only).
        widths: output channels of the shared MLP's layers (each ``Linear`` without bias, then
            ``BatchNorm1d`` and ReLU); the MLP reads ``in_channels + 3`` channels with ``use_xyz``
            (else ``in_channels``).
        npoint: centres chosen by farthest-point sampling (M); None groups the whole cloud round the
            origin (then ``radius`` and ``nsample`` must be None).
        radius: ball radius of a neighbourhood.
        nsample: neighbours per centre (K), as :func:`~shapeprog.pointcloud.ops.ball_query` picks them.
        use_xyz: feed each neighbour's coordinates relative to its centre to the MLP.

    Shapes:
        ``forward(xyz (B, N, 3), features (B, N, C) or None) -> (centres (B, M, 3), features (B, M, widths[-1]))``;
        group-all gives ``M = 1`` and the origin as its centre. Gradients flow to ``xyz`` and ``features``.
    """

    def __init__(self, in_channels: int, widths: Sequence[int], npoint: Optional[int] = None,
                 radius: Optional[float] = None, nsample: Optional[int] = None, use_xyz: bool = True):
        super().__init__()
        if isinstance(in_channels, bool) or int(in_channels) != in_channels or in_channels < 0:
            raise ValueError(f"`in_channels` must be an int >= 0, got {in_channels!r}")
        widths = [_positive_int(w, "widths") for w in widths]
        if not widths:
            raise ValueError("`widths` must hold at least one layer size")
        if npoint is None:
            if radius is not None or nsample is not None:
                raise ValueError("group-all (`npoint=None`) takes no `radius` or `nsample`")
        else:
            npoint, nsample = _positive_int(npoint, "npoint"), _positive_int(nsample, "nsample")
            if radius is None or not float(radius) > 0 or float(radius) == float("inf"):
                raise ValueError(f"`radius` must be a finite number > 0, got {radius!r}")
            radius = float(radius)
        if not use_xyz and in_channels == 0:
            raise ValueError("`use_xyz=False` needs `in_channels` > 0: the MLP would read no channel")
        self.in_channels, self.npoint, self.radius, self.nsample = int(in_channels), npoint, radius, nsample
        self.use_xyz = bool(use_xyz)
        self.widths = tuple(widths)
        layers = []
        prev = self.in_channels + (3 if self.use_xyz else 0)
        for w in widths:
            layers += [nn.Linear(prev, w, bias=False), nn.BatchNorm1d(w), nn.ReLU(inplace=True)]
            prev = w
        self.mlp = nn.Sequential(*layers)

    @property
    def out_channels(self) -> int:
        return self.widths[-1]

    def extra_repr(self) -> str:
        if self.npoint is None:
            return f"group_all, in_channels={self.in_channels}, use_xyz={self.use_xyz}"
        return (f"npoint={self.npoint}, radius={self.radius:g}, nsample={self.nsample}, "
                f"in_channels={self.in_channels}, use_xyz={self.use_xyz}")

    def forward(self, xyz: torch.Tensor, features: Optional[torch.Tensor] = None) -> tuple[torch.Tensor, torch.Tensor]:
        _check_cloud(xyz, "xyz", min_points=self.npoint or 1)
        if (features is None) != (self.in_channels == 0):
            raise PointCloudError(f"this layer takes {self.in_channels} feature channels, got "
                                  f"{'none' if features is None else tuple(features.shape)}", "features")
        if features is not None:
            _check_features(features, xyz, "xyz")
            if features.shape[2] != self.in_channels:
                raise PointCloudError(f"must have {self.in_channels} channels, got {tuple(features.shape)}",
                                      "features")
        if self.npoint is None:
            centres = xyz.new_zeros(xyz.shape[0], 1, 3)
            grouped = _group_all(xyz, features, self.use_xyz)  # (B, 1, N, C')
        else:
            centres = _group(xyz, _farthest_point_sample(xyz, self.npoint))  # (B, M, 3), differentiable
            grouped = _query_and_group(xyz, centres, features, self.radius, self.nsample, self.use_xyz)  # (B, M, K, C')
        rows = self.mlp(grouped.reshape(-1, grouped.shape[-1]))
        # max over the neighbourhood; its backward goes through the argmax indices, not a mask
        return centres, rows.view(*grouped.shape[:3], -1).max(dim=2).values


class PointNet2SSG(nn.Module):
    """The point-cloud encoder: PointNet++ SSG, classification layout, ``(B, N, 3) -> (B, out_dim)``.

    SA1 (``npoints[0]`` centres, ``radii[0]``, ``nsamples[0]`` neighbours, MLP ``widths[0]``), SA2 (the
    same with index 1, on SA1's centres), SA3 (group-all, MLP ``widths[2]``), then a linear layer
    ``widths[2][-1] -> out_dim`` without batch norm or activation. The input features are the
    coordinates (3 channels), and every MLP adds the 3 relative coordinates. The defaults are the
    spec's sizes (1,067,776 parameters); smaller ``npoints`` suit smaller clouds. The configuration is
    kept in :attr:`config` (plain ints and floats) for checkpoints.

    Args:
        out_dim: size of the code.
        npoints: centres of SA1 and SA2 (SA2's at most SA1's).
        radii: ball radii of SA1 and SA2.
        nsamples: neighbours per ball of SA1 and SA2.
        widths: the three shared MLPs' layer sizes.

    Raises:
        ValueError: sizes of the wrong count or sign.
    """

    def __init__(self, out_dim: int = OUT_DIM, npoints: Sequence[int] = NPOINTS, radii: Sequence[float] = RADII,
                 nsamples: Sequence[int] = NSAMPLES, widths: Sequence[Sequence[int]] = WIDTHS):
        super().__init__()
        if len(npoints) != 2 or len(radii) != 2 or len(nsamples) != 2 or len(widths) != 3:
            raise ValueError(f"`npoints`, `radii` and `nsamples` take 2 values and `widths` 3 MLPs, got "
                             f"{len(npoints)}, {len(radii)}, {len(nsamples)} and {len(widths)}")
        npoints = [_positive_int(m, "npoints") for m in npoints]
        if npoints[1] > npoints[0]:
            raise ValueError(f"SA2 samples its centres from SA1's: `npoints` must not grow, got {tuple(npoints)}")
        out_dim = _positive_int(out_dim, "out_dim")
        self.config = {"out_dim": out_dim, "npoints": npoints, "radii": [float(r) for r in radii],
                       "nsamples": [int(k) for k in nsamples], "widths": [[int(w) for w in ws] for ws in widths]}
        self.sa1 = SetAbstraction(3, widths[0], npoints[0], radii[0], nsamples[0])
        self.sa2 = SetAbstraction(self.sa1.out_channels, widths[1], npoints[1], radii[1], nsamples[1])
        self.sa3 = SetAbstraction(self.sa2.out_channels, widths[2])
        self.fc = nn.Linear(self.sa3.out_channels, out_dim)

    @property
    def min_points(self) -> int:
        """The fewest points per cloud the encoder takes (SA1's centres)."""
        return self.config["npoints"][0]

    def forward(self, clouds: torch.Tensor) -> torch.Tensor:
        """The codes ``(B, out_dim)`` of clouds ``(B, N, 3)`` (``N >= min_points``; the model's dtype and device).

        Raises:
            PointCloudError: a wrong shape, dtype or device, a non-finite coordinate (naming the
                cloud), fewer than :attr:`min_points` points.
        """
        _check_cloud(clouds, "clouds", min_points=self.min_points)
        weight = self.fc.weight
        if clouds.dtype != weight.dtype or clouds.device != weight.device:
            raise PointCloudError(f"are {clouds.dtype} on {clouds.device} but the encoder is {weight.dtype} on "
                                  f"{weight.device}", "clouds")
        xyz, f = self.sa1(clouds, clouds)  # the coordinates are the points' features
        xyz, f = self.sa2(xyz, f)
        _, f = self.sa3(xyz, f)
        return self.fc(f.squeeze(1))
