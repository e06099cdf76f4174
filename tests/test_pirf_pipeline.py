"""End to end on a tiny generated omnidirectional loop, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from placeloc.config import load_config
from placeloc.images import ImageError
from placeloc.pirf.stages import check_feature_type, read_poses
from placeloc.runner import run_all, run_stage
from placeloc.synth.omni import generate


@pytest.fixture(scope="module")
def omni(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("omni")
    # a 16 m loop walked 1.5 times at 0.3 m/frame: frames 54..79 revisit frames 0..25
    generate(out, seed=0, frames=80, test_frames=40, width=240, layout="small", step=0.3, movers=2)
    return out


def _config(omni: Path, **pirf) -> dict:
    data = {"method": "pirf", "reference": {"images": str(omni / "mapping")}, "query": {"images": str(omni / "test")},
            "ground_truth": {"kind": "poses", "path": str(omni / "mapping" / "poses.csv"), "radius": 1.0},
            "pirf": {"eps": 10, "tau": 0.003, "n_pmin": 20, **pirf}}
    return load_config(data=data)


def test_generator_writes_frames_and_poses(omni: Path) -> None:
    frames = sorted((omni / "mapping").glob("*.png"))
    assert len(frames) == 80 and len(list((omni / "test").glob("*.png"))) == 40
    img = cv2.imread(str(frames[0]), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (120, 240) and img.std() > 10
    poses = read_poses(omni / "mapping" / "poses.csv")
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    assert poses.shape == (80, 3) and np.median(step) == pytest.approx(0.3, abs=0.05)
    # the revisit: frame 54 stands within 0.5 m of frame 0 (16 m loop / 0.3 m)
    assert np.linalg.norm(poses[54, :2] - poses[1, :2]) < 0.5


def test_loop_closure_found_on_tiny_loop(omni: Path, tmp_path: Path) -> None:
    run_all(_config(omni), tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    with h5py.File(tmp_path / "run" / "build-dictionary.h5") as f:
        frames = f["loop_closures/frame"][()]
    assert m["loop_closures"] >= 5 and m["loop_closure_precision"] >= 0.9
    assert frames.min() >= 54 - 3  # closures only on the second lap
    assert m["accuracy_gap2"] >= 0.6 and m["accuracy_gap2"] >= m["accuracy_gap0"]
    assert m["jaccard_ann_bf"] >= 0.9
    for key in ("dictionary_size", "loop_closures_correct", "accuracy_gap1", "precision_ann_bf", "recall_ann_bf",
                "mt_seconds_bf", "mt_seconds_ann"):
        assert m[key] is not None
    assert (tmp_path / "run" / "loop_closures.png").is_file()
    # plain keeps more words than improved on the same PIRFs
    run_stage(_config(omni, update="plain"), tmp_path / "plain", "build-dictionary", quiet=True)
    with h5py.File(tmp_path / "plain" / "build-dictionary.h5") as f:
        assert f.attrs["dictionary_size"] > m["dictionary_size"]


def test_frames_of_different_sizes_are_refused(omni: Path, tmp_path: Path) -> None:
    d = tmp_path / "mixed"
    d.mkdir()
    for k, p in enumerate(sorted((omni / "mapping").glob("*.png"))[:6]):
        img = cv2.imread(str(p))
        cv2.imwrite(str(d / f"f{k}.png"), img if k != 4 else cv2.resize(img, (200, 100)))
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d)}})
    with pytest.raises(ImageError, match=r"f4\.png: size 200x100 differs"):
        run_stage(cfg, tmp_path / "run", "extract", quiet=True)


def test_blank_frame_is_refused_with_a_fix(omni: Path, tmp_path: Path) -> None:
    d = tmp_path / "blank"
    d.mkdir()
    for k, p in enumerate(sorted((omni / "mapping").glob("*.png"))[:4]):
        img = cv2.imread(str(p))
        cv2.imwrite(str(d / f"f{k}.png"), img if k != 2 else np.zeros_like(img))
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d)}})
    with pytest.raises(ImageError, match=r"f2\.png: no sift features.*blank_frames: empty"):
        run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d)}, "pirf": {"blank_frames": "empty"}})
    run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    with h5py.File(tmp_path / "run" / "extract.h5") as f:
        assert f["reference/n_features"][2] == 0 and np.diff(f["reference/offsets"][()])[2] == 0


def test_query_against_other_feature_type(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "extract.h5", "w") as ex, h5py.File(tmp_path / "build.h5", "w") as b:
        ex.attrs["features"] = "orb"
        b.attrs["features"] = "sift"
        with pytest.raises(ImageError, match="extracted with orb features but the dictionary was built from sift.*pirf.features: sift"):
            check_feature_type(ex, b, tmp_path / "extract.h5")
