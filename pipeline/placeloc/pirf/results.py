"""Read a PIRF-nav2 run directory's results as plain arrays (for experiments, notebooks, benches).

Each reader opens one artifact by the stage that wrote it, so callers never need to know
HDF5 dataset names; a missing artifact is an error naming the file and the stage to run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import h5py
import numpy as np

from placeloc.core.artifacts import read_strings


def _open(run_dir: str | Path, stage: str) -> h5py.File:
    path = Path(run_dir) / f"{stage}.h5"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: run `placeloc {stage}` (or `placeloc run`) on that run directory first")
    return h5py.File(path, "r")


def read_pirfs(run_dir: str | Path, role: str) -> tuple[np.ndarray, np.ndarray]:
    """PIRFs of a traverse ("reference" or "query"): (descriptors (n, d), per-frame offsets)."""
    with _open(run_dir, "extract") as f:
        return f[f"{role}/pirfs"][()], f[f"{role}/offsets"][()]


def read_frame_names(run_dir: str | Path, role: str) -> list[str]:
    """Image file name of every frame kept for ``role`` (skipped images are left out)."""
    with _open(run_dir, "extract") as f:
        return read_strings(f[f"{role}/names"])


def read_dictionary(run_dir: str | Path) -> np.ndarray:
    """The PIRF dictionary (words x d) built by build-dictionary."""
    with _open(run_dir, "build-dictionary") as f:
        return f["dictionary"][()]


def read_node_vectors(run_dir: str | Path, backend: str) -> tuple[np.ndarray, np.ndarray]:
    """Query m_t vectors computed at localize with ``backend`` as CSR (ptr, word ids)."""
    with _open(run_dir, "localize") as f:
        if backend not in f:
            raise ValueError(f"{Path(run_dir) / 'localize.h5'} holds no results for {backend!r} (it has {', '.join(f)}); "
                             "set pirf.index (or pirf.compare_bf: true) and re-run localize")
        return f[f"{backend}/m_ptr"][()], f[f"{backend}/m_words"][()]


def read_index_info(run_dir: str | Path) -> dict[str, Any]:
    """The index's backend, build seconds and parameters (and the recall tuning, when it ran)."""
    with _open(run_dir, "index") as f:
        return {k: (v.item() if hasattr(v, "item") else v) for k, v in f["index"].attrs.items() if k != "data_sha256"}


def stage_seconds(run_dir: str | Path, stage: str) -> float:
    """Wall seconds the stage took when its artifact was written."""
    with _open(run_dir, stage) as f:
        return float(f.attrs["seconds"])


def read_loop_closures(run_dir: str | Path, candidates: bool = False) -> dict[str, np.ndarray]:
    """The map's loop closures (frame, node, matched_node, score); with ``candidates`` every
    frame whose score reached tau, before the geometric check, with the check's ``keep``,
    ``residual`` and ``reference`` (maps built before the check existed have no candidates)."""
    with _open(run_dir, "build-dictionary") as f:
        group = "closure_candidates" if candidates else "loop_closures"
        if group not in f:
            raise ValueError(f"{Path(run_dir) / 'build-dictionary.h5'} has no {group}: it was built before the geometric check "
                             "existed; re-run build-dictionary")
        return {k: f[f"{group}/{k}"][()] for k in f[group]}


def loop_closure_count(metrics: dict[str, Any]) -> int:
    """PIRF-nav2's own loop closures from a run's metrics.json: ``loop_closures`` where they
    differ from the contract's ``n_accepted`` (ground_truth.exclude_recent dropped some of
    them), else ``n_accepted`` (metrics.json does not repeat a count)."""
    return int(metrics.get("loop_closures", metrics["n_accepted"]))
