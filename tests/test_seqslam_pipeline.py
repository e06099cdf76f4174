"""SeqSLAM's stage dependencies: each stage re-runs exactly when what it reads changes."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from placeloc.core.config import load_config
from placeloc.core.runner import run_stage


def _mtimes(run_dir: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in run_dir.glob("*.h5")}


def _candidates(run_dir: Path) -> np.ndarray:
    with h5py.File(run_dir / "localize.h5") as f:
        return f["candidates"][()]


def test_localize_only_keys_keep_extract_and_work_splitting_keys_rerun_nothing(route, tmp_path):
    run = tmp_path / "run"
    base = ["plots=false"]
    run_stage(load_config(route / "config.yaml", base), run, "localize", quiet=True)
    first, cand = _mtimes(run), _candidates(run)

    # localize-only keys: extract stays, localize re-runs
    for key in ("seqslam.v_max=1.5", "seqslam.top_k=4", "seqslam.enhance_window=5"):
        base = base + [key]
        run_stage(load_config(route / "config.yaml", base), run, "localize", quiet=True)
        now = _mtimes(run)
        assert now["extract.h5"] == first["extract.h5"], key
        assert now["localize.h5"] != first["localize.h5"], key
        first = now

    # how the work is cut (chunks of images, blocks of queries) changes no result: nothing re-runs
    cand = _candidates(run)
    run_stage(load_config(route / "config.yaml", base + ["seqslam.block_size=7", "seqslam.images_per_task=3"]), run,
              "localize", quiet=True)
    assert _mtimes(run) == first
    # ... and really gives the same candidates when forced
    run_stage(load_config(route / "config.yaml", base + ["seqslam.block_size=7"]), run, "localize", quiet=True,
              force=True)
    np.testing.assert_array_equal(_candidates(run), cand)

    # an extract key re-runs extract (and so localize)
    run_stage(load_config(route / "config.yaml", base + ["seqslam.patch=4"]), run, "localize", quiet=True)
    now = _mtimes(run)
    assert now["extract.h5"] != first["extract.h5"]
