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


def test_int_entry_reads_integer_scalars_in_range_and_names_the_rest():
    import pytest

    from shapeio.arrays import int_entry
    from shapeio.files import InputError

    assert int_entry(np.array(7), "f.npz", "size", 1, 8) == 7
    assert int_entry(np.int64(-3), "f.npz", "seed") == -3
    assert int_entry(np.array(0, np.uint8), "f.npz", "n", 0) == 0
    for value, low, high, bounds in ((np.array(9), 1, 8, r" in \[1, 8\]"), (np.array(-1), 0, None, " >= 0"),
                                     (np.array(5), None, 4, " <= 4"), (np.array(2.0), None, None, ""),
                                     (np.array([1, 2]), None, None, ""), (np.array("x"), 0, 1, r" in \[0, 1\]")):
        with pytest.raises(InputError, match=rf"^f\.npz: the entry 'e' is not an integer{bounds}: dtype"):
            int_entry(value, "f.npz", "e", low, high)
