"""Bring your own descriptors: image descriptors computed elsewhere (NetVLAD, CosPlace,
MixVPR, ...) as the rows a method compares instead of thumbnails (SeqSLAM's sequences,
retrieval's nearest neighbours).

Accepted forms, one row per image in the image folder's (natural) order:

- a ``.npy`` file holding an (n_images, d) matrix;
- an HDF5 file (``.h5``/``.hdf5``) whose dataset ``descriptors`` (or its only 2-D
  dataset) is that matrix;
- a folder of ``.npy`` files, one vector per image, in natural name order.

Distances (lower = more alike): ``cosine`` = 1 - cosine
similarity (rows are L2-normalised once, here), ``l2`` = Euclidean distance.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from placeloc.core.images import natural_key
from placeloc.core.safe_io import UnsafeInputError, h5_dataset, load_arrays, open_h5_input

DISTANCES = ("cosine", "l2")


class DescriptorError(ValueError):
    """A descriptor file that cannot be used; the message names the file and the fix."""


# A descriptor has at most this many dimensions (NetVLAD's unreduced 32,768 included), at
# 8 bytes each: the budget an input's header is checked against before it is read.
MAX_DIMENSIONS = 65536


def _from_hdf5(path: Path, what: str, max_bytes: int) -> np.ndarray:
    import h5py

    with open_h5_input(path, what) as f:
        if "descriptors" in f and isinstance(f["descriptors"], h5py.Dataset):
            return h5_dataset(f["descriptors"], max_bytes)
        found: list[str] = []
        f.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset) and obj.ndim == 2 else None)
        if len(found) != 1:
            raise DescriptorError(f"{path}: expected a dataset named 'descriptors' or exactly one 2-D dataset, found "
                                  f"{found or 'none'}; name the matrix 'descriptors'")
        return h5_dataset(f[found[0]], max_bytes)


def _load_npy(path: Path, mmap: bool = False) -> np.ndarray:
    """np.load without pickle, every failure a DescriptorError naming the file."""
    try:
        return np.load(path, allow_pickle=False, mmap_mode="r" if mmap else None)
    except (ValueError, OSError, EOFError) as exc:  # object arrays, a damaged header, a truncated file
        raise DescriptorError(f"{path}: not a numeric .npy matrix ({' '.join(str(exc).split())[:160]}); save it with "
                              "np.save(path, matrix.astype(np.float32))") from exc


def descriptor_shape(path: str | Path) -> tuple[int, ...] | None:
    """The shape of a descriptor source from its headers (no data read): (rows, d) for a
    matrix file or a folder of vectors; None when the source cannot be told (missing, or a
    form :func:`load_descriptors` will refuse with its own message)."""
    import h5py

    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("*.npy"), key=lambda x: natural_key(x.name))
        return (len(files), int(_load_npy(files[0], mmap=True).size)) if files else None
    if p.suffix == ".npy" and p.is_file():
        return tuple(_load_npy(p, mmap=True).shape)
    if p.suffix in (".h5", ".hdf5") and p.is_file():
        try:
            with h5py.File(p, "r") as f:
                if "descriptors" in f and isinstance(f["descriptors"], h5py.Dataset):
                    return tuple(f["descriptors"].shape)
                found: list[tuple[int, ...]] = []
                f.visititems(lambda _n, obj: found.append(obj.shape) if isinstance(obj, h5py.Dataset) and obj.ndim == 2 else None)
                return found[0] if len(found) == 1 else None
        except OSError:
            return None  # not HDF5: load_descriptors names it
    return None


def check_descriptor_pair(reference: str | Path | None, query: str | Path | None, key: str) -> None:
    """Refuse, before any stage runs, reference and query descriptors of different
    dimensions (two models, or one model at two sizes): their distances mean nothing, and
    the matrix product would fail deep inside a stage."""
    if reference is None or query is None:
        return
    shapes = {role: descriptor_shape(path) for role, path in (("reference", reference), ("query", query))}
    dims = {role: shape[1] for role, shape in shapes.items() if shape is not None and len(shape) == 2}
    if len(dims) == 2 and dims["reference"] != dims["query"]:
        raise DescriptorError(f"{key}_query: {Path(query).name} holds {dims['query']}-dimensional descriptors but "
                              f"{key}_reference ({Path(reference).name}) holds {dims['reference']}-dimensional ones; "
                              "compute both traverses' descriptors with the same model and settings")


def load_descriptors(path: str | Path, n_images: int, role: str, key: str = "seqslam.descriptors") -> np.ndarray:
    """The (n_images, d) float32 descriptor matrix of one traverse, checked against its image count."""
    p = Path(path)
    what = f"{key}_{role}"
    budget = max(n_images, 1) * MAX_DIMENSIONS * 8
    try:
        mat = _read(p, what, budget, key, role)
    except UnsafeInputError as exc:
        raise DescriptorError(str(exc)) from None
    if mat.ndim != 2:
        raise DescriptorError(f"{p}: descriptors must be a 2-D (images x dimensions) matrix, got shape {mat.shape}")
    if len(mat) != n_images:
        raise DescriptorError(f"{p}: {len(mat)} descriptor rows for {n_images} {role} images; one row per image, in the "
                              "folder's order")
    if not (np.issubdtype(mat.dtype, np.integer) or np.issubdtype(mat.dtype, np.floating)) or mat.dtype == bool:
        raise DescriptorError(f"{p}: descriptors must be real numbers, got {mat.dtype} values; save a float32 matrix")
    if mat.shape[1] == 0:
        raise DescriptorError(f"{p}: descriptors of dimension 0 (shape {mat.shape}); one non-empty vector per image")
    mat = mat.astype(np.float32)
    if not np.isfinite(mat).all():
        raise DescriptorError(f"{p}: descriptors contain NaN or infinity")
    return mat


def _read(p: Path, what: str, budget: int, key: str, role: str) -> np.ndarray:
    """The matrix of a .npy or HDF5 file, or of a folder of per-image .npy files, each array
    checked from its header against ``budget`` bytes before it is read."""
    if p.is_dir():
        files = sorted(p.glob("*.npy"), key=lambda x: natural_key(x.name))
        if not files:
            raise DescriptorError(f"{p}: no .npy files in this folder; give one .npy per image or an (n, d) matrix file")
        rows = [load_arrays(f, what, MAX_DIMENSIONS * 8)["array"].ravel() for f in files]
        if len({r.shape for r in rows}) != 1:
            raise DescriptorError(f"{p}: the .npy files hold vectors of different lengths; every image needs the same d")
        return np.stack(rows)
    if p.suffix == ".npy":
        return load_arrays(p, what, budget)["array"]
    if p.suffix in (".h5", ".hdf5"):
        return _from_hdf5(p, what, budget)
    if not p.exists():
        raise DescriptorError(f"{p} does not exist; fix {key}_{role} (relative paths start at the config's folder)")
    raise DescriptorError(f"{p}: unknown descriptor format; use .npy, .h5/.hdf5 or a folder of .npy files")


def prepare_descriptors(mat: np.ndarray, distance: str) -> np.ndarray:
    """Rows as the distance works on them: unit length for ``cosine``, as given for ``l2``."""
    if distance == "cosine":
        n = np.linalg.norm(mat, axis=1, keepdims=True)
        return (mat / np.where(n > 0, n, 1)).astype(np.float32)
    if distance == "l2":
        return mat.astype(np.float32)
    raise ValueError(f"unknown descriptor distance {distance!r}; choose one of {', '.join(DISTANCES)}")


def descriptor_difference(ref: np.ndarray, query: np.ndarray, distance: str) -> np.ndarray:
    """D[i, j] between prepared reference row i and query row j, float32."""
    if distance == "cosine":
        return (1.0 - ref @ query.T).astype(np.float32)
    if distance == "l2":
        sq = (ref * ref).sum(1)[:, None] + (query * query).sum(1)[None, :] - 2.0 * (ref @ query.T)
        return np.sqrt(np.maximum(sq, 0.0)).astype(np.float32)
    raise ValueError(f"unknown descriptor distance {distance!r}; choose one of {', '.join(DISTANCES)}")
