"""Map and path as CSV beside the artifacts, so results can be read without h5py."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from placeloc.core.artifacts import atomic_open


def write_map_csv(path: Path, feature_ids: np.ndarray, coords: np.ndarray, is_landmark: np.ndarray) -> Path:
    """``feature,is_landmark,x,y[,z]``: every mapped feature (landmarks as the solver placed them)."""
    names = ("x", "y", "z")[: coords.shape[1]]
    with atomic_open(path) as fh:
        fh.write(",".join(("feature", "is_landmark", *names)) + "\n")
        for f, lm, c in zip(feature_ids, is_landmark, coords):
            fh.write(f"{int(f)},{int(bool(lm))}," + ",".join(f"{v:.9g}" for v in c) + "\n")
    return Path(path)


def write_path_csv(path: Path, step_ids: np.ndarray, xy: np.ndarray, heading: np.ndarray | None, label_steps: np.ndarray) -> Path:
    """``t,x,y[,heading],is_label``: the estimated pose of every step (heading in radians)."""
    labelled = np.isin(step_ids, label_steps)
    with atomic_open(path) as fh:
        fh.write("t,x,y" + (",heading" if heading is not None else "") + ",is_label\n")
        for i, t in enumerate(step_ids):
            h = f",{heading[i]:.9g}" if heading is not None else ""
            fh.write(f"{int(t)},{xy[i, 0]:.9g},{xy[i, 1]:.9g}{h},{int(labelled[i])}\n")
    return Path(path)
