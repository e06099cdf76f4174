"""core.artifacts.read_mapped: a large dataset read in place where HDF5 stores it as one
plain block, and read as usual where it does not; the values are HDF5's either way."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from placeloc.core.artifacts import atomic_h5, read_mapped


def _values(shape, dtype):
    rng = np.random.default_rng(7)
    x = rng.standard_normal(shape)
    if np.dtype(dtype).kind == "c":
        x = x + 1j * rng.standard_normal(shape)
    return x.astype(dtype)


@pytest.mark.parametrize("dtype", ["<c8", "<f4", "<i8", "<u8"])
def test_a_contiguous_dataset_is_mapped_not_copied(tmp_path, dtype):
    path = tmp_path / "index.h5"
    data = _values((5, 7, 33), dtype)
    with atomic_h5(path, {"stamp": "s"}) as f:  # the way every artifact is written
        f.create_dataset("spectra", data=data)
    with h5py.File(path, "r") as f:
        got = read_mapped(f["spectra"])
    # the file is closed: the map still serves the bytes
    assert np.array_equal(got, data) and got.dtype == data.dtype
    assert not got.flags.owndata and not got.flags.writeable  # the file's pages, read-only
    assert type(got) is np.ndarray  # a plain array (numba refuses the memmap subclass)


@pytest.mark.parametrize("how", ["chunked", "gzip", "big-endian"])
def test_other_layouts_are_read_as_usual_with_the_same_values(tmp_path, how):
    path = tmp_path / "x.h5"
    data = _values((4, 6, 10), "<f8")
    with h5py.File(path, "w") as f:
        if how == "chunked":
            f.create_dataset("x", data=data, chunks=(1, 6, 10))
        elif how == "gzip":
            f.create_dataset("x", data=data, compression="gzip")
        else:
            f.create_dataset("x", data=data.astype(">f8"))
    with h5py.File(path, "r") as f:
        got = read_mapped(f["x"])
    assert np.array_equal(got, data)
    if how != "big-endian":  # a plain big-endian block is mapped as big-endian values: equal all the same
        assert got.flags.owndata  # read, not mapped


def test_a_replaced_artifact_leaves_the_map_on_the_old_bytes(tmp_path):
    """A stage re-run renames a new file over the old one while a reader holds its map: the
    reader keeps the old values (never a mix), the next reader gets the new ones."""
    path = tmp_path / "index.h5"
    old, new = _values((3, 4, 8), "<c8"), _values((3, 4, 8), "<c8") * 2
    with atomic_h5(path, {"stamp": "a"}) as f:
        f.create_dataset("spectra", data=old)
    with h5py.File(path, "r") as f:
        held = read_mapped(f["spectra"])
    with atomic_h5(path, {"stamp": "b"}) as f:
        f.create_dataset("spectra", data=new)
    assert np.array_equal(held, old)
    with h5py.File(path, "r") as f:
        assert np.array_equal(read_mapped(f["spectra"]), new)


def test_a_file_system_that_cannot_map_is_read_as_usual(tmp_path, monkeypatch):
    path = tmp_path / "index.h5"
    data = _values((3, 4, 8), "<c8")
    with atomic_h5(path, {"stamp": "s"}) as f:
        f.create_dataset("spectra", data=data)

    def no_mmap(*args, **kwargs):
        raise OSError(19, "No such device")  # ENODEV: what mmap says where a FUSE mount cannot map

    monkeypatch.setattr(np, "memmap", no_mmap)
    with h5py.File(path, "r") as f:
        got = read_mapped(f["spectra"])
    assert np.array_equal(got, data) and got.flags.owndata
