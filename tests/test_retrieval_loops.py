"""Retrieval's loop mode (no query: each frame against the earlier frames) and the one loop
exclusion, ground_truth.exclude_recent, that adapts to short sequences."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from placeloc.core.common_params import loop_exclusion
from placeloc.core.config import ConfigError, load_config
from placeloc.core.images import natural_key
from placeloc.core.runner import run_all
from placeloc.retrieval.neighbours import nearest_earlier, prepare


@pytest.mark.parametrize("distance", ["cosine", "l2"])
@pytest.mark.parametrize("exclude", [0, 1, 7])
def test_nearest_earlier_equals_brute_force(distance: str, exclude: int) -> None:
    rng = np.random.default_rng(5)
    rows = rng.normal(size=(53, 12))
    idx, score = nearest_earlier(rows, exclude_recent=exclude, distance=distance, block_size=4)
    r = prepare(rows, distance).astype(np.float64)
    gap = max(exclude, 1)  # a frame never matches itself
    for i in range(len(rows)):
        if i < gap:
            assert idx[i] == -1 and np.isnan(score[i])
            continue
        earlier = r[: i - gap + 1]
        if distance == "cosine":
            sims = earlier @ r[i]
            assert idx[i] == int(np.argmax(sims)) and score[i] == pytest.approx(sims.max(), abs=1e-5)
        else:
            dist = np.linalg.norm(earlier - r[i], axis=1)
            assert idx[i] == int(np.argmin(dist)) and score[i] == pytest.approx(dist.min(), abs=1e-4)


def test_loop_exclusion_adapts_to_short_sequences_and_says_why() -> None:
    assert loop_exclusion(None, 1200)[0] == 50 and loop_exclusion(None, 250)[0] == 50
    value, rule = loop_exclusion(None, 84)
    assert value == 16 and "a fifth of the 84 frames" in rule and "the default 50 would leave 34 frames" in rule
    assert loop_exclusion(None, 249)[0] == 49
    assert loop_exclusion(30, 84) == (30, "as set (ground_truth.exclude_recent)")
    assert loop_exclusion(0, 10)[0] == 0


@pytest.fixture
def twice(route: Path, tmp_path: Path) -> Path:
    """84 frames: the route's first 42 reference frames, then the same 42 again, so frame
    42 + i revisits frame i (byte-identical), and the ground truth says exactly that."""
    frames = sorted((route / "reference").iterdir(), key=lambda p: natural_key(p.name))[:42]
    folder = tmp_path / "twice"
    folder.mkdir()
    for i, p in enumerate(frames + frames):
        (folder / f"f{i:03d}.png").write_bytes(p.read_bytes())
    (tmp_path / "loops.csv").write_text("query,reference\n" + "".join(f"{42 + i},{i}\n" for i in range(42)))
    return folder


def _loop_config(folder: Path, method: str, **ground_truth) -> dict:
    return load_config(data={"method": method, "reference": {"images": str(folder)}, "plots": False,
                             "ground_truth": {"kind": "csv", "path": str(folder.parent / "loops.csv"), **ground_truth}})


def test_retrieval_loop_mode_closes_every_revisit(twice: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        run_all(_loop_config(twice, "retrieval"), tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    # the default exclusion, adapted: 84 // 5 = 16 frames, said in the log and in metrics.json
    assert m["exclude_recent"] == 16 and "a fifth of the 84 frames" in m["exclude_recent_rule"]
    assert any("pairs fewer than 16 frames apart never count" in r.getMessage() for r in caplog.records)
    # every revisit is a byte-identical frame: all 42 close their loop, ahead of every false match
    assert m["frames_with_loop"] == 42 and m["n_frames"] == 84
    assert m["recall_at_100_precision"] == 1.0 and m["auc_pr"] == pytest.approx(1.0)
    import h5py

    with h5py.File(tmp_path / "run" / "localize.h5") as f:
        match, frames = f["result/match"][()], f["result/frame_index"][()]
    assert (match[42:] == np.arange(42)).all()
    assert (match[:16] == -1).all() and (match[16:] <= frames[16:] - 16).all()  # searched with the same exclusion


def test_the_fixed_default_would_have_scored_nothing(twice: Path, tmp_path: Path) -> None:
    """A short sequence: with 50 frames excluded, an 84-frame sequence whose revisits lie 42
    frames back has no frame left that can close a loop."""
    run_all(_loop_config(twice, "retrieval", exclude_recent=50), tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["exclude_recent"] == 50 and m["frames_with_loop"] == 0


def test_seqslam_loop_mode_searches_with_the_same_exclusion(twice: Path, tmp_path: Path) -> None:
    run_all(_loop_config(twice, "seqslam"), tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    import h5py

    with h5py.File(tmp_path / "run" / "localize.h5") as f:
        match, frames = f["result/match"][()], f["result/frame_index"][()]
    found = match >= 0
    assert m["exclude_recent"] == 16 and (match[found] <= frames[found] - 16).all()
    # once its causal window (ds 10) lies wholly inside the second pass, every frame closes
    # its loop exactly
    assert (match[52:] == np.arange(10, 42)).all()


def test_retrieval_loop_mode_refuses_query_descriptors_without_a_query(twice: Path, tmp_path: Path) -> None:
    np.save(tmp_path / "q.npy", np.zeros((84, 4), np.float32))
    with pytest.raises(ConfigError, match=r"retrieval\.descriptors_query is set but no query\.images"):
        load_config(data={"method": "retrieval", "reference": {"images": str(twice)},
                          "retrieval": {"descriptors_query": str(tmp_path / "q.npy")}})
