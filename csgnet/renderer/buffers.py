"""Memory of the renderer: recycled CPU output buffers, per-thread scratch space, packing and unpacking
of bit-packed canvases."""

from __future__ import annotations

import sys
import threading

import numpy as np
import torch

from ..primitives import SIZE

# recycled CPU output buffers

class _BufferPool:
    """Large CPU output tensors backed by recycled memory.

    A fresh multi-megabyte allocation is a fresh ``mmap``: every page is faulted in (and zeroed by the
    kernel) on first touch, which for a 64 MiB batch of 3D volumes costs more than computing it. Small
    arrays do not pay this, because ``malloc`` recycles freed heap memory; this pool does the same for
    the renderer's large results. Each result is an ordinary tensor over a NumPy buffer held by the
    pool; a buffer is handed out again only once nothing refers to it any more (its reference count
    says that the pool is its only holder: the returned tensor, its views, and arrays made from it all
    keep it alive). At most ``max_bytes`` of buffers are remembered; older ones are forgotten (and freed
    by their last user). Disabled where reference counts cannot be relied on (free-threaded Python).
    """

    def __init__(self, min_bytes: int = 1 << 20, max_bytes: int = 256 << 20):
        self.min_bytes, self.max_bytes = min_bytes, max_bytes
        self._lock = threading.Lock()
        self._bufs: list[np.ndarray] = []
        probe = [np.empty(1, np.uint8)]
        self._idle_refs = self._refs(probe, 0)
        gil = getattr(sys, "_is_gil_enabled", None)
        self.enabled = gil is None or gil()

    @staticmethod
    def _refs(bufs: list, i: int) -> int:
        return sys.getrefcount(bufs[i])

    def empty(self, shape: tuple, dtype) -> torch.Tensor:
        """An uninitialised CPU tensor of ``shape`` and NumPy ``dtype``."""
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if not self.enabled or nbytes < self.min_bytes or nbytes > self.max_bytes:
            return torch.from_numpy(np.empty(shape, dtype))
        with self._lock:
            bufs = self._bufs
            for i in range(len(bufs) - 1, -1, -1):
                if bufs[i].nbytes == nbytes and self._refs(bufs, i) == self._idle_refs:
                    buf = bufs.pop(i)
                    break
            else:
                buf = np.empty(nbytes, np.uint8)
                total = nbytes + sum(b.nbytes for b in bufs)
                while bufs and total > self.max_bytes:
                    total -= bufs.pop(0).nbytes
            bufs.append(buf)
            return torch.from_numpy(buf.view(dtype).reshape(shape))


_POOL = _BufferPool()


# ------------------------------------------------------------------------------------------------
# packing

def unpack(words: torch.Tensor, dim: int) -> torch.Tensor:
    """Packed words ``(..., 64)`` (2D) or ``(..., 64, 64)`` (3D) -> bool ``(..., 64, 64[, 64])``."""
    words = words.contiguous()
    shape = words.shape + (SIZE,)
    if words.device.type != "cpu":
        by = words.view(torch.uint8)
        shifts = torch.arange(8, dtype=torch.uint8, device=words.device)
        bits = (by.unsqueeze(-1) >> shifts) & 1
        return bits.reshape(shape).bool()
    # Larger than the pool keeps: a fresh allocation, zeroed by the OS page by page on first touch
    # (calloc), so the all-zero rows (the empty slots of a 3D stack trace) cost nothing here.
    zeroed = int(np.prod(shape, dtype=np.int64)) > _POOL.max_bytes
    out = torch.from_numpy(np.zeros(shape, np.bool_)) if zeroed else _POOL.empty(shape, np.bool_)
    if words.numel():
        _unpack_rows(words.numpy().reshape(-1, SIZE), out.numpy().reshape(-1, SIZE * SIZE).view(np.uint8),
                     zeroed=zeroed)
    return out


def _unpack_rows(w: np.ndarray, out: np.ndarray, chunk: int = 256, zeroed: bool = False) -> None:
    """Unpack rows of 64 words (a 2D image, or one x-slab of a 3D volume) into ``out`` ``(R, 4096)``.

    All-zero rows (most of a typical 3D volume) are cleared with ``memset``-speed writes (or left
    alone if ``out`` is ``zeroed`` already); only the other rows go through ``np.unpackbits`` (in
    chunks, so its temporary stays in cache).
    """
    nz = w.view(np.uint64).max(axis=1) != 0
    rows = np.flatnonzero(nz)
    if zeroed or len(rows) * 4 < len(nz) * 3:
        if not zeroed:  # clear the zero rows run by run (contiguous slices)
            edges = np.flatnonzero(np.diff(nz.view(np.int8), prepend=1, append=1))
            for a, b in zip(edges[0::2].tolist(), edges[1::2].tolist()):
                out[a:b] = 0
        for i in range(0, len(rows), chunk):  # then fill in the others
            r = rows[i:i + chunk]
            out[r] = np.unpackbits(w[r].view(np.uint8), axis=-1, bitorder="little")
    else:
        for i in range(0, len(w), chunk):
            out[i:i + chunk] = np.unpackbits(w[i:i + chunk].view(np.uint8), axis=-1, bitorder="little")


def popcount(words: torch.Tensor) -> np.ndarray:
    """ON pixels (voxels) of packed canvases ``(N, *C)`` int64 -> ``(N,)`` int64 (NumPy, on the CPU)."""
    w = words.detach().cpu().numpy().view(np.uint64)  # bitwise_count of a signed word counts |w|'s bits
    return np.bitwise_count(w).reshape(w.shape[0], -1).sum(axis=1, dtype=np.int64)


def pack(canvas: torch.Tensor | np.ndarray) -> torch.Tensor:
    """Bool ``(..., 64)`` -> int64 words ``(...)`` (inverse of :func:`unpack`, on the last axis)."""
    if isinstance(canvas, torch.Tensor):
        dev = canvas.device
        arr = canvas.detach().cpu().numpy()
    else:
        dev, arr = torch.device("cpu"), np.asarray(canvas)
    if arr.shape[-1] != SIZE:
        raise ValueError(f"pack expects a last axis of {SIZE}, got shape {arr.shape}")
    by = np.packbits(arr.astype(bool), axis=-1, bitorder="little")
    return torch.from_numpy(np.ascontiguousarray(by).view(np.int64)[..., 0]).to(dev)


# ------------------------------------------------------------------------------------------------
# the stack machine

class _Workspace(threading.local):
    """Per-thread scratch buffers reused across calls.

    Fresh multi-megabyte CPU allocations are returned to the OS when freed, so every new one pays page
    faults on first touch (more than the copies themselves cost); reusing the buffers avoids that.
    """

    def __init__(self):
        self.buffers: dict = {}

    def get(self, name: str, numel: int, device) -> torch.Tensor:
        key = (name, str(device))
        buf = self.buffers.get(key)
        if buf is None or buf.numel() < numel:
            buf = torch.empty(max(numel, 1), dtype=torch.int64, device=device)
            self.buffers[key] = buf
        return buf[:numel]


_WORKSPACE = _Workspace()
