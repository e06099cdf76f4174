"""PIRF-nav2 on one's own video: featureless frames counted and kept, frames too small for
table 1's settings named with their counts, loop-only runs without an index, and the
one-frame and all-black folders that used to end in tracebacks."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from conftest import shared_data

from placeloc.core.config import ConfigError, load_config
from placeloc.core.errors import StageError
from placeloc.core.runner import run_all, run_stage
from placeloc.pirf.features import SCORE_PER_PIRF_SQUARED, blank_frames_note, few_features_note
from placeloc.synth.omni import generate


def test_few_features_note_gives_the_measured_counts_and_a_tau() -> None:
    # frame 0 has no history and frame 3 no features: both left out of the medians
    n_features = np.array([5, 80, 90, 0, 70])
    n_pirfs = np.array([0, 20, 30, 0, 25])
    windows = np.array([0, 1, 1, 0, 1])
    note = few_features_note("reference", n_features, n_pirfs, windows, shape=(120, 160), kind="sift", n_pmin=40, tau=0.015)
    expected = SCORE_PER_PIRF_SQUARED * 25 ** 2  # 0.001
    assert note is not None
    assert "frames of 160 x 120 give few features: median 80 sift features and 25 PIRFs a frame" in note
    assert "the adaptive window fell to 1 in 3 of 3 frames (fewer PIRFs than pirf.n_pmin 40)" in note
    assert f"here {expected:.2g}, far below pirf.tau 0.015: most true closures will not be accepted" in note
    assert f"set pirf.tau to about {expected / 2:.2g}" in note
    # enough PIRFs for a true closure to reach tau: nothing to say
    rich = np.array([0, 120, 100, 110])
    assert few_features_note("reference", rich * 5, rich, np.array([0, 3, 3, 3]), shape=(240, 480), kind="sift",
                             n_pmin=40, tau=0.015) is None
    # a lower tau: half the true closures reach it at these counts, nothing to say
    assert few_features_note("reference", n_features, n_pirfs, windows, shape=(120, 160), kind="sift", n_pmin=40,
                             tau=2 * expected) is None


def test_blank_frames_note_counts_and_names_them() -> None:
    names = [f"f{k}.png" for k in range(9)]
    note = blank_frames_note("reference", names, np.array([9, 0, 4, 0, 0, 0, 0, 0, 3]), "sift", shown=3)
    assert note is not None
    assert note.startswith("reference: 6 of 9 frames have no sift features (blank or featureless: f1.png, f3.png, "
                           "f4.png and 3 more)")
    assert blank_frames_note("reference", names[:2], np.array([1, 2]), "sift") is None


def _folder(path: Path, frames: list[np.ndarray]) -> Path:
    path.mkdir()
    for k, img in enumerate(frames):
        cv2.imwrite(str(path / f"frame{k:03d}.png"), img)
    return path


def test_one_frame_folder_is_a_config_error(tmp_path: Path) -> None:
    one = _folder(tmp_path / "one", [np.random.default_rng(0).integers(0, 255, (120, 160), dtype=np.uint8)])
    with pytest.raises(ConfigError, match=r"reference\.images: .*one holds 1 image; PIRF-nav2 .* at least 2 frames"):
        load_config(data={"method": "pirf", "reference": {"images": str(one)}})


def test_black_video_maps_to_nothing_without_a_traceback(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Five black frames with the default blank_frames: five frames without PIRFs, an empty
    map, no loop closure, every frame counted; a query against that empty map is a
    StageError naming the cause."""
    black = _folder(tmp_path / "black", [np.zeros((120, 160), np.uint8)] * 5)
    truth = tmp_path / "truth.npy"
    np.save(truth, np.zeros((5, 5), np.uint8))
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(black)}, "plots": False,
                            "ground_truth": {"kind": "matrix", "path": str(truth)}})
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        run_all(cfg, tmp_path / "run", quiet=True)
    assert any("5 of 5 frames have no sift features" in r.getMessage() for r in caplog.records)
    with h5py.File(tmp_path / "run" / "build-dictionary.h5") as f:
        assert f.attrs["dictionary_size"] == 0 and len(f["loop_closures/frame"]) == 0
    with h5py.File(tmp_path / "run" / "index.h5") as f:
        assert f.attrs["backend"] == "none" and "index" not in f
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["n_frames"] == 5 and m["frames_without_features"] == 5 and m["n_accepted"] == 0
    with_query = load_config(data={"method": "pirf", "reference": {"images": str(black)}, "query": {"images": str(black)}})
    with pytest.raises(StageError, match=r"black: the map holds 0 dictionary entries.*5 of 5 frames have no features"):
        run_stage(with_query, tmp_path / "q", "index", quiet=True)


@pytest.fixture(scope="module")
def small_loop(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("omni")
    generate(out, seed=0, frames=40, test_frames=2, width=240, layout="small", step=0.5, movers=0)
    return out


def test_loop_only_run_builds_no_index(small_loop: Path, tmp_path: Path) -> None:
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(small_loop / "mapping")}, "plots": False,
                            "ground_truth": {"kind": "poses", "path": str(small_loop / "mapping" / "poses.csv"),
                                             "radius": 1.0}})
    run_all(cfg, tmp_path / "run", quiet=True)
    with h5py.File(tmp_path / "run" / "index.h5") as f:
        assert f.attrs["backend"] == "none" and "index" not in f
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["index"] == "none" and m["n_frames"] == 40 and m["frames_without_features"] == 0
    assert not any(k.startswith("index_tuned") for k in m)


@pytest.mark.skipif(shared_data() is None or not (shared_data() / "nordland-dev").is_dir(),
                    reason="../shared/data/nordland-dev absent")
def test_real_video_with_a_tunnel_runs_through(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """nordland-dev summer frames 181-210 (64 x 32 px): SIFT finds nothing in the 15 tunnel
    frames 188-202 (images-01880 to 02020). The run keeps them, names them, and says why frames this small give
    PIRF-nav2 too little."""
    folder = tmp_path / "tunnel"
    folder.mkdir()
    for p in sorted((shared_data() / "nordland-dev" / "summer").glob("*.png"))[180:210]:
        (folder / p.name).write_bytes(p.read_bytes())
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(folder)}})
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        run_stage(cfg, tmp_path / "run", "build-dictionary", quiet=True)
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "reference: 15 of 30 frames have no sift features (blank or featureless: images-01880.png" in text
    assert "frames of 64 x 32 give few features" in text
    with h5py.File(tmp_path / "run" / "extract.h5") as f:
        assert int((f["reference/n_features"][()] == 0).sum()) == 15


def test_unmet_index_target_says_the_sample_was_too_small(caplog: pytest.LogCaptureFixture) -> None:
    """On a two-frame video the query sample agrees perfectly on 25 matches, too few for the
    95 % bound to reach 0.97: the warning gives the counts instead of a bare contradiction."""
    from placeloc.pirf.params import PirfParams
    from placeloc.pirf.stages import _warn_if_unmet
    from placeloc.pirf.tuning import lower_bound

    assert lower_bound(1.0, 25) < 0.97 <= lower_bound(1.0, 400)
    tuned = {"target_met": False, "value": 1024, "mt_recall": 1.0, "mt_jaccard": 1.0, "mt_matched": 25,
             "nn_recall": 1.0, "nn_count": 50}
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        _warn_if_unmet(tuned, PirfParams(), "localize", "the query sample")
    assert ("localize: no faiss-hnsw setting up to 1024 shows m_t recall 0.97 / Jaccard 0.95 with 95 % confidence on "
            "the query sample (it gives 1.000 / 1.000 on 25 ratio-test matches, nearest-neighbour recall 1.000 on 50 "
            "neighbours)") in caplog.text
