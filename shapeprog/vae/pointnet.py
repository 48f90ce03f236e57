"""PointNet classifiers of point clouds (plain PyTorch): the model, its training loop and weight files.

:class:`PointNetCls` is the classification network of Qi et al. in the layout of the reference's
``PointNetCls(k, feature_transform=False)``: a shared per-point MLP (1x1 ``Conv1d`` 3 -> 64 -> 128 ->
1024, batch norm, ReLU after the first two), a max pool over the points giving the **global feature**
``(B, 1024)``, and a head 1024 -> 512 -> 256 -> k (batch norm, ReLU, dropout 0.3 before the second batch
norm). The input transform (``STN3d``) is optional (``stn=True``); the classifier shipped with the package
is trained without it (half the compute on CPU). The generation metrics (:mod:`shapeprog.vae.genmetrics`) use
the global feature for the Fréchet distance and train fresh binary classifiers for the "% fool" metric.

Clouds are batch first, ``(B, N, 3) float``. Training (:func:`fit_classifier`) and inference touch no
global state: the random streams come from a seed, and torch's global generator is restored afterwards.
Weight files (:mod:`shapeio.weights`, family :data:`FORMAT`) hold ``{"config", "classes", "state_dict", "meta"}``;
the shipped file, written before weights files carried their family, is read as version 0 of it.
:func:`load_classifier` checks the shipped file's SHA-256 before reading it. How the shipped weights were
trained and how well they classify: ``docs/generation_metrics.md``.

Example:
    >>> import torch
    >>> net = PointNetCls(k=3, widths=(8, 16, 32), head=(16, 8)).eval()
    >>> tuple(net(torch.zeros(2, 100, 3)).shape), tuple(net.features(torch.zeros(2, 100, 3)).shape)
    ((2, 3), (2, 32))
"""
from __future__ import annotations

import hashlib
import math
import time
from pathlib import Path
from typing import Callable, Optional, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from shapeio.weights import read_weights, write_weights

__all__ = ["FORMAT", "VERSION", "PRETRAINED", "PRETRAINED_SHA256", "PointNetCls", "STN3d", "accuracy", "fit_classifier", "global_features",
           "load_classifier", "predict", "save_classifier", "sha256_file"]

#: The weights-file family of a classifier and its version (the shipped file has the unversioned layout, 0).
FORMAT, VERSION = "shapeprog-pointnet-cls", 1
#: The keys of a classifier file written before weights files carried ``format`` (the shipped one).
_LEGACY_KEYS = ("config", "classes", "state_dict")
#: The shipped chair / table / storage classifier (``shapeprog/weights``).
PRETRAINED = Path(__file__).resolve().parent.parent / "weights" / "pointnet_cls.pt"
#: SHA-256 of :data:`PRETRAINED`; :func:`load_classifier` refuses a file that does not match.
PRETRAINED_SHA256 = "c7a967bb1e291e89f700b2192dda74294221037ab109f36a600e7860bc634385"


def _check_clouds(x: torch.Tensor, name: str = "clouds") -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"`{name}` must be a torch.Tensor of shape (B, N, 3), got {type(x).__name__}")
    if x.dim() != 3 or x.shape[2] != 3 or x.shape[1] == 0:
        raise ValueError(f"`{name}` must have shape (B, N, 3) with N >= 1, got {tuple(x.shape)}")
    if not x.is_floating_point():
        raise TypeError(f"`{name}` must be a floating-point tensor, got {x.dtype}")
    return x


class STN3d(nn.Module):
    """The input transform of PointNet: ``(B, 3, N) -> (B, 3, 3)``, identity plus a learnt offset."""

    def __init__(self, widths: Sequence[int] = (64, 128, 1024), head: Sequence[int] = (512, 256)):
        super().__init__()
        w1, w2, w3 = widths
        h1, h2 = head
        self.conv = nn.Sequential(
            nn.Conv1d(3, w1, 1), nn.BatchNorm1d(w1), nn.ReLU(),
            nn.Conv1d(w1, w2, 1), nn.BatchNorm1d(w2), nn.ReLU(),
            nn.Conv1d(w2, w3, 1), nn.BatchNorm1d(w3), nn.ReLU(),
        )
        self.fc = nn.Sequential(
            nn.Linear(w3, h1), nn.BatchNorm1d(h1), nn.ReLU(),
            nn.Linear(h1, h2), nn.BatchNorm1d(h2), nn.ReLU(),
            nn.Linear(h2, 9),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.fc(self.conv(x).amax(dim=2))
        return y.view(-1, 3, 3) + torch.eye(3, dtype=y.dtype, device=y.device)


class PointNetCls(nn.Module):
    """PointNet classifier ``(B, N, 3) float -> (B, k)`` logits, without the feature transform.

    Args:
        k: number of classes.
        widths: channels of the shared per-point MLP; the last is the global feature's size.
        head: hidden sizes of the classification head.
        dropout: dropout probability before the head's second batch norm.
        stn: add the input transform (``STN3d``) in front of the shared MLP.
    """

    def __init__(self, k: int = 3, widths: Sequence[int] = (64, 128, 1024), head: Sequence[int] = (512, 256),
                 dropout: float = 0.3, stn: bool = False):
        super().__init__()
        if int(k) < 2:
            raise ValueError(f"`k` must be at least 2 classes, got {k!r}")
        if len(widths) != 3 or len(head) != 2 or min(*widths, *head) < 1:
            raise ValueError(f"`widths` must be 3 and `head` 2 positive sizes, got {tuple(widths)} and {tuple(head)}")
        self.config = {"k": int(k), "widths": [int(w) for w in widths], "head": [int(h) for h in head],
                       "dropout": float(dropout), "stn": bool(stn)}
        w1, w2, w3 = self.config["widths"]
        h1, h2 = self.config["head"]
        self.stn = STN3d(widths, head) if stn else None
        self.conv1, self.bn1 = nn.Conv1d(3, w1, 1), nn.BatchNorm1d(w1)
        self.conv2, self.bn2 = nn.Conv1d(w1, w2, 1), nn.BatchNorm1d(w2)
        self.conv3, self.bn3 = nn.Conv1d(w2, w3, 1), nn.BatchNorm1d(w3)
        self.fc1, self.fbn1 = nn.Linear(w3, h1), nn.BatchNorm1d(h1)
        self.fc2, self.fbn2 = nn.Linear(h1, h2), nn.BatchNorm1d(h2)
        self.fc3 = nn.Linear(h2, int(k))
        self.dropout = nn.Dropout(p=dropout)

    @property
    def feature_dim(self) -> int:
        return self.config["widths"][-1]

    def features(self, clouds: torch.Tensor) -> torch.Tensor:
        """The max-pooled global feature ``(B, widths[-1])`` of clouds ``(B, N, 3)`` (after the last
        batch norm, before any ReLU, as in the reference's ``PointNetfeat``)."""
        x = _check_clouds(clouds).transpose(1, 2)
        if self.stn is not None:
            x = torch.bmm(self.stn(x).transpose(1, 2), x)
        x = F.relu(self.bn1(self.conv1(x)))
        x = F.relu(self.bn2(self.conv2(x)))
        return self.bn3(self.conv3(x)).amax(dim=2)

    def head(self, feats: torch.Tensor) -> torch.Tensor:
        """Logits ``(B, k)`` of global features ``(B, widths[-1])``."""
        x = F.relu(self.fbn1(self.fc1(feats)))
        x = F.relu(self.fbn2(self.dropout(self.fc2(x))))
        return self.fc3(x)

    def forward(self, clouds: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(clouds))


# --------------------------------------------------------------------------------------------------
# inference


@torch.no_grad()
def _batched(model: PointNetCls, clouds: torch.Tensor, fn, batch_size: int) -> torch.Tensor:
    _check_clouds(clouds)
    was = model.training
    model.eval()
    try:
        out = [fn(clouds[s:s + batch_size]) for s in range(0, clouds.shape[0], batch_size)]
    finally:
        model.train(was)
    return torch.cat(out) if out else torch.empty(0)


def global_features(model: PointNetCls, clouds: torch.Tensor, batch_size: int = 32) -> torch.Tensor:
    """Global features ``(B, widths[-1]) float`` of clouds ``(B, N, 3)`` in eval mode, without grad."""
    return _batched(model, clouds, model.features, batch_size)


def predict(model: PointNetCls, clouds: torch.Tensor, batch_size: int = 32) -> torch.Tensor:
    """Predicted class ``(B,) int64`` of clouds ``(B, N, 3)`` in eval mode."""
    return _batched(model, clouds, lambda x: model(x).argmax(dim=1), batch_size)


# --------------------------------------------------------------------------------------------------
# training


def _subsample(clouds: torch.Tensor, points: Optional[int], g: torch.Generator) -> torch.Tensor:
    """A random subset of ``points`` points of every cloud ``(B, M, 3)`` (all of them when None)."""
    if points is None or points >= clouds.shape[1]:
        return clouds
    idx = torch.rand(clouds.shape[:2], generator=g).argsort(dim=1)[:, :points]
    return torch.gather(clouds, 1, idx[..., None].expand(-1, -1, 3))


def _epoch_rows(labels: torch.Tensor, per_class: Optional[int], g: torch.Generator) -> torch.Tensor:
    """A shuffled epoch: every row, or ``per_class`` rows of each class (without replacement)."""
    if per_class is None:
        return torch.randperm(labels.shape[0], generator=g)
    rows = []
    for c in labels.unique().tolist():
        own = torch.nonzero(labels == c).flatten()
        rows.append(own[torch.randperm(own.shape[0], generator=g)[:per_class]])
    rows = torch.cat(rows)
    return rows[torch.randperm(rows.shape[0], generator=g)]


def fit_classifier(
    clouds: torch.Tensor,
    labels: torch.Tensor,
    k: Optional[int] = None,
    epochs: int = 10,
    batch_size: int = 32,
    lr: float = 1e-3,
    points: Optional[int] = None,
    per_class: Optional[int] = None,
    seed: int = 0,
    model: Optional[PointNetCls] = None,
    on_epoch: Optional[Callable[[int, PointNetCls, float], None]] = None,
    log: Optional[Callable[[str], None]] = None,
    **model_kwargs,
) -> PointNetCls:
    """Train a :class:`PointNetCls` with Adam and cross-entropy (plain PyTorch loop, on the clouds' device).

    Each epoch visits every cloud once in a random order, or ``per_class`` clouds of each class (a
    balanced draw without replacement, fresh each epoch); each visit uses a fresh random subset of
    ``points`` of the cloud's points (all when None). The last partial batch is dropped when it has a
    single cloud (batch norm needs two). Seeded: the model's initialisation, the order, the subsets and
    dropout all come from ``seed``; torch's global random state is left as it was.

    Args:
        clouds: ``(S, M, 3) float``.
        labels: ``(S,) int64`` in ``[0, k)``.
        k: number of classes (default ``labels.max() + 1``).
        epochs, batch_size, lr: the optimisation budget.
        points: points per cloud and visit (a random subset of the M).
        per_class: clouds per class and epoch (None: all of them).
        seed: the seed.
        model: continue training this model instead of a new one.
        on_epoch: called after every epoch with ``(epoch, model, mean training loss)``; the model is in
            training mode again afterwards.
        log: a function taking a line of progress text (e.g. ``print``).
        **model_kwargs: :class:`PointNetCls` arguments (``widths``, ``head``, ``dropout``, ``stn``).

    Returns:
        The trained model, in eval mode.
    """
    _check_clouds(clouds)
    labels = torch.as_tensor(labels, dtype=torch.long)
    if labels.shape != clouds.shape[:1]:
        raise ValueError(f"`labels` must have shape ({clouds.shape[0]},), got {tuple(labels.shape)}")
    if clouds.shape[0] < 2:
        raise ValueError(f"training needs at least 2 clouds, got {clouds.shape[0]}")
    k = int(labels.max()) + 1 if k is None else int(k)
    if int(labels.min()) < 0 or int(labels.max()) >= k:
        raise ValueError(f"`labels` must lie in [0, {k}), got [{int(labels.min())}, {int(labels.max())}]")
    devices = [clouds.device] if clouds.device.type != "cpu" else []
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(seed)
        g = torch.Generator().manual_seed(seed)
        model = model if model is not None else PointNetCls(k, **model_kwargs)
        model = model.to(clouds.device).train()
        opt = torch.optim.Adam(model.parameters(), lr=lr)
        for epoch in range(epochs):
            t0 = time.perf_counter()
            rows = _epoch_rows(labels, per_class, g)
            total, count = 0.0, 0
            for s in range(0, rows.shape[0], batch_size):
                b = rows[s:s + batch_size]
                if b.shape[0] < 2:
                    continue
                x = _subsample(clouds[b.to(clouds.device)], points, g)
                loss = F.cross_entropy(model(x), labels[b].to(clouds.device))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                total += float(loss.detach()) * b.shape[0]
                count += b.shape[0]
            mean = total / max(count, 1)
            if log is not None:
                log(f"epoch {epoch + 1}/{epochs}: loss {mean:.4f} over {count} clouds, "
                    f"{time.perf_counter() - t0:.1f} s")
            if on_epoch is not None:
                on_epoch(epoch, model, mean)
                model.train()
    return model.eval()


# --------------------------------------------------------------------------------------------------
# weight files


def sha256_file(path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_classifier(path, model: PointNetCls, classes: Sequence[str], meta: Optional[dict] = None) -> Path:
    """Write ``{"config", "classes", "state_dict", "meta"}`` atomically (float32 tensors, on the CPU).

    Returns:
        ``path``; its SHA-256 is :func:`sha256_file` of it.
    """
    classes = [str(c) for c in classes]
    if len(classes) != model.config["k"]:
        raise ValueError(f"{len(classes)} class names for a {model.config['k']}-class model")
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    payload = {"config": dict(model.config), "classes": classes, "state_dict": state, "meta": dict(meta or {})}
    return write_weights(path, FORMAT, VERSION, payload)


def load_classifier(path=None, sha256: Optional[str] = None, device=None) -> tuple[PointNetCls, tuple[str, ...], dict]:
    """A classifier written by :func:`save_classifier`, in eval mode.

    Args:
        path: the weights file; default the shipped :data:`PRETRAINED`.
        sha256: the file's expected hex SHA-256; default :data:`PRETRAINED_SHA256` for the shipped file and
            no check for another file.
        device: where to put the model (default CPU).

    Returns:
        ``(model, classes, meta)``: class names in label order, and the training record (``meta``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file, when its SHA-256 differs from the expected one or it is not a
            classifier weights file.
    """
    path = PRETRAINED if path is None else Path(path)
    if sha256 is None and path.resolve() == PRETRAINED:
        sha256 = PRETRAINED_SHA256
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such weights file")
    if sha256 is not None:
        actual = sha256_file(path)
        if actual != sha256.lower():
            raise ValueError(f"{path}: SHA-256 {actual} differs from the expected {sha256.lower()}; "
                             "the file is damaged or not the one these metrics were defined with")
    payload = read_weights(path, FORMAT, VERSION, legacy=_LEGACY_KEYS, what="PointNet classifier weights file")
    try:
        model = PointNetCls(**payload["config"])
        model.load_state_dict(payload["state_dict"])
        classes = tuple(str(c) for c in payload["classes"])
        meta = dict(payload.get("meta", {}))
    except Exception as e:  # missing keys, another model's config or tensors of other shapes
        raise ValueError(f"{path}: not a PointNet classifier weights file ({type(e).__name__} in its contents)") from None
    if len(classes) != model.config["k"]:
        raise ValueError(f"{path}: {len(classes)} class names for a {model.config['k']}-class model")
    return model.to(device or "cpu").eval(), classes, meta


def accuracy(model: PointNetCls, clouds: torch.Tensor, labels: torch.Tensor, batch_size: int = 32) -> float:
    """Percentage of clouds ``(B, N, 3)`` whose predicted class equals ``labels (B,)``."""
    pred = predict(model, clouds, batch_size)
    return 100.0 * float((pred == torch.as_tensor(labels, device=pred.device)).double().mean()) if len(pred) else math.nan
