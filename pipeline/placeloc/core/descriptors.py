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

DISTANCES = ("cosine", "l2")


class DescriptorError(ValueError):
    """A descriptor file that cannot be used; the message names the file and the fix."""


def _from_hdf5(path: Path) -> np.ndarray:
    import h5py

    with h5py.File(path, "r") as f:
        if "descriptors" in f and isinstance(f["descriptors"], h5py.Dataset):
            return f["descriptors"][()]
        found: list[str] = []
        f.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset) and obj.ndim == 2 else None)
        if len(found) != 1:
            raise DescriptorError(f"{path}: expected a dataset named 'descriptors' or exactly one 2-D dataset, found "
                                  f"{found or 'none'}; name the matrix 'descriptors'")
        return f[found[0]][()]


def load_descriptors(path: str | Path, n_images: int, role: str, key: str = "seqslam.descriptors") -> np.ndarray:
    """The (n_images, d) float32 descriptor matrix of one traverse, checked against its image count."""
    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("*.npy"), key=lambda x: natural_key(x.name))
        if not files:
            raise DescriptorError(f"{p}: no .npy files in this folder; give one .npy per image or an (n, d) matrix file")
        rows = [np.load(f, allow_pickle=False).ravel() for f in files]
        if len({r.shape for r in rows}) != 1:
            raise DescriptorError(f"{p}: the .npy files hold vectors of different lengths; every image needs the same d")
        mat = np.stack(rows)
    elif p.suffix == ".npy":
        mat = np.load(p, allow_pickle=False)
    elif p.suffix in (".h5", ".hdf5"):
        mat = _from_hdf5(p)
    elif not p.exists():
        raise DescriptorError(f"{p} does not exist; fix {key}_{role} (relative paths start at the config's folder)")
    else:
        raise DescriptorError(f"{p}: unknown descriptor format; use .npy, .h5/.hdf5 or a folder of .npy files")
    if mat.ndim != 2:
        raise DescriptorError(f"{p}: descriptors must be a 2-D (images x dimensions) matrix, got shape {mat.shape}")
    if len(mat) != n_images:
        raise DescriptorError(f"{p}: {len(mat)} descriptor rows for {n_images} {role} images; one row per image, in the "
                              "folder's order")
    mat = mat.astype(np.float32)
    if not np.isfinite(mat).all():
        raise DescriptorError(f"{p}: descriptors contain NaN or infinity")
    return mat


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
