"""Tests of shapeio.arrays: tensors and array-likes as NumPy arrays."""
import numpy as np
import torch

from shapeio.arrays import as_numpy


def test_tensors_lists_and_arrays():
    t = torch.ones(2, 3, requires_grad=True) * 2
    out = as_numpy(t)
    assert isinstance(out, np.ndarray) and out.shape == (2, 3) and (out == 2).all()
    assert as_numpy([[1, 2]]).tolist() == [[1, 2]]
    a = np.zeros(3)
    assert as_numpy(a) is a
