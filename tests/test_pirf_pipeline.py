"""End to end on a tiny generated omnidirectional loop, and bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from placeloc.core.config import ConfigError, load_config
from placeloc.core.images import ImageError
from placeloc.core.runner import run_all, run_stage
from placeloc.evaluation.poses import read_poses
from placeloc.pirf.results import loop_closure_count
from placeloc.pirf.stages import check_feature_type
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
            "pirf": {"eps": 10, "tau": 0.003, "n_pmin": 20, "query_poses": str(omni / "test" / "poses.csv"), **pirf}}
    return load_config(data=data)


def test_generator_writes_frames_and_poses(omni: Path) -> None:
    frames = sorted((omni / "mapping").glob("*.png"))
    assert len(frames) == 80 and len(list((omni / "test").glob("*.png"))) == 40
    img = cv2.imread(str(frames[0]), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (120, 240) and img.std() > 10
    xy = read_poses(omni / "mapping" / "poses.csv").xy
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert xy.shape == (80, 2) and np.median(step) == pytest.approx(0.3, abs=0.05)
    # the revisit: frame 54 stands within 0.5 m of frame 0 (16 m loop / 0.3 m)
    assert np.linalg.norm(xy[54] - xy[1]) < 0.5


@pytest.fixture(scope="module")
def full_run(omni: Path, tmp_path_factory) -> Path:
    """One complete run with the default settings, copied by the tests that change one key."""
    run = tmp_path_factory.mktemp("pirf-run") / "run"
    run_all(_config(omni), run, quiet=True)
    return run


def _copy(run: Path, dst: Path) -> Path:
    shutil.copytree(run, dst, copy_function=shutil.copy2)
    return dst


def test_loop_closure_found_on_tiny_loop(omni: Path, full_run: Path, tmp_path: Path) -> None:
    m = json.loads((full_run / "metrics.json").read_text())
    with h5py.File(full_run / "build-dictionary.h5") as f:
        frames = f["loop_closures/frame"][()]
    assert loop_closure_count(m) >= 5 and m["loop_closure_precision"] >= 0.9
    assert frames.min() >= 54 - 3  # closures only on the second lap
    assert m["accuracy_gap2"] >= 0.6 and m["accuracy_gap2"] >= m["accuracy_gap0"]
    assert m["jaccard_ann_bf"] >= 0.9
    for key in ("dictionary_size", "loop_closures_correct", "accuracy_gap1", "precision_ann_bf", "recall_ann_bf",
                "mt_seconds_bf", "mt_seconds_ann"):
        assert m[key] is not None
    assert (full_run / "loop_closures.png").is_file()
    # plain keeps more words than improved on the same PIRFs
    run_stage(_config(omni, update="plain"), _copy(full_run, tmp_path / "plain"), "build-dictionary", quiet=True)
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


def test_blank_frame_is_kept_by_default_and_refused_with_stop(omni: Path, tmp_path: Path) -> None:
    d = tmp_path / "blank"
    d.mkdir()
    for k, p in enumerate(sorted((omni / "mapping").glob("*.png"))[:4]):
        img = cv2.imread(str(p))
        cv2.imwrite(str(d / f"f{k}.png"), img if k != 2 else np.zeros_like(img))
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d)}, "pirf": {"blank_frames": "stop"}})
    with pytest.raises(ImageError, match=r"f2\.png: no sift features.*blank_frames: empty"):
        run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d)}})
    run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    with h5py.File(tmp_path / "run" / "extract.h5") as f:
        assert f["reference/n_features"][2] == 0 and np.diff(f["reference/offsets"][()])[2] == 0


def test_query_against_other_feature_type(tmp_path: Path) -> None:
    with h5py.File(tmp_path / "extract.h5", "w") as ex, h5py.File(tmp_path / "build.h5", "w") as b:
        ex.attrs["features"] = "orb"
        b.attrs["features"] = "sift"
        with pytest.raises(ImageError, match="extracted with orb features but the dictionary was built from sift.*pirf.features: sift"):
            check_feature_type(ex, b, tmp_path / "extract.h5")


def _mtimes(run_dir: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in run_dir.glob("*.h5")}


def test_localize_only_key_does_not_rerun_extract(omni: Path, full_run: Path, tmp_path: Path) -> None:
    run = _copy(full_run, tmp_path / "run")
    first = _mtimes(run)
    run_stage(_config(omni, compare_bf=False), run, "localize", quiet=True)
    after = _mtimes(run)
    for stage in ("extract.h5", "build-dictionary.h5", "index.h5"):
        assert after[stage] == first[stage], stage
    assert after["localize.h5"] != first["localize.h5"]
    with h5py.File(run / "localize.h5") as f:
        assert "bruteforce" not in f  # the new setting took effect
        assert "query_tuning" in f  # re-tuned on the queries (the default)
    run_stage(_config(omni, compare_bf=False, index_tune_queries=False), run, "localize", quiet=True)
    assert _mtimes(run)["index.h5"] == first["index.h5"]
    with h5py.File(run / "localize.h5") as f:
        assert "query_tuning" not in f


def test_localize_retunes_the_index_on_the_query_run(full_run: Path) -> None:
    from placeloc.pirf.ann import AnnIndex
    from placeloc.pirf.knn import exact_knn
    from placeloc.pirf.tuning import SEARCH_GRID, agreement, meets

    m = json.loads((full_run / "metrics.json").read_text())
    with h5py.File(full_run / "localize.h5") as f:
        tuned = dict(f["query_tuning"].attrs)
        tried = {k: f[f"query_tuning/tuning/{k}"][()] for k in ("value", "mt_recall", "nn_recall")}
    assert m["index_query_tuned_value"] == tuned["tuned_value"] in SEARCH_GRID["faiss-hnsw"][1]
    assert m["index_query_tuned_sample"] == tuned["tuned_sample"] > 0
    assert m["mt_total_seconds_ann"] >= tuned["tuned_seconds"]  # the re-tuning is counted in the whole run's m_t
    assert tried["value"][-1] == tuned["tuned_value"] and list(tried["value"]) == sorted(tried["value"])
    # The stored choice reproduces: the same seeded sample of the query PIRFs, searched
    # exactly and at the chosen setting, meets the targets (or it is the grid's last).
    with h5py.File(full_run / "extract.h5") as ex, h5py.File(full_run / "build-dictionary.h5") as b, \
            h5py.File(full_run / "index.h5") as ix:
        q, words = ex["query/pirfs"][()], b["dictionary"][()]
        index = AnnIndex.from_h5(ix["index"], words)
    n = len(q)
    ids = np.random.default_rng(0).permutation(n)[: int(tuned["tuned_sample"])]
    index.set_search("ef_search", int(tuned["tuned_value"]))
    ag = agreement(exact_knn(q[ids], words, 2), index.knn2(q[ids]), 0.7)
    assert ag["nn_recall"] == pytest.approx(tuned["tuned_nn_recall"])
    assert bool(tuned["tuned_target_met"]) == meets(ag, 0.97, 0.95)


def test_outputs_csv_and_poses_aligned_by_frame_column(omni: Path, full_run: Path, tmp_path: Path) -> None:
    # shuffled rows with the frame column: the same figures as the ordered file
    rows = (omni / "mapping" / "poses.csv").read_text().splitlines()
    shuffled = tmp_path / "shuffled.csv"
    rng = np.random.default_rng(0)
    shuffled.write_text("\n".join([rows[0]] + [rows[1:][i] for i in rng.permutation(len(rows) - 1)]) + "\n")
    cfg = _config(omni)
    cfg["ground_truth"]["path"] = str(shuffled)
    run_b = _copy(full_run, tmp_path / "b")
    before = _mtimes(run_b)
    run_all(cfg, run_b, quiet=True)
    assert _mtimes(run_b)["extract.h5"] == before["extract.h5"]  # only evaluate reads the ground truth
    ma, mb = (json.loads((r / "metrics.json").read_text()) for r in (full_run, run_b))
    assert ma["loop_closure_precision"] == mb["loop_closure_precision"] and ma["accuracy_gap0"] == mb["accuracy_gap0"]
    # loop closures and per-frame localization as CSV, consistent with metrics.json
    lc = (full_run / "loop_closures.csv").read_text().splitlines()
    assert lc[0] == "frame,image,node,node_image,score,distance_m,correct"
    assert len(lc) - 1 == loop_closure_count(ma) and sum(r.endswith(",1") for r in lc[1:]) == ma["loop_closures_correct"]
    loc = [r.split(",") for r in (full_run / "localization.csv").read_text().splitlines()[1:]]
    ann = [r for r in loc if r[0] == ma["index"]]
    assert len(ann) == 40 and sum(r[-1] == "1" for r in ann) / 40 == pytest.approx(ma["accuracy_gap0"])


def test_fewer_poses_than_frames_is_an_error(omni: Path, tmp_path: Path) -> None:
    short = tmp_path / "short.csv"
    short.write_text("\n".join((omni / "mapping" / "poses.csv").read_text().splitlines()[:4]) + "\n")
    data = {"method": "pirf", "reference": {"images": str(omni / "mapping")},
            "ground_truth": {"kind": "poses", "path": str(short), "radius": 1.0}}
    with pytest.raises(ConfigError, match=r"short\.csv: 3 poses for 80 frames"):
        load_config(data=data)
    # a poses file given as loop-closure pairs: the loops contract reads it up front and says what it expects
    data["ground_truth"] = {"kind": "csv", "path": str(short)}
    with pytest.raises(ConfigError, match=r"short\.csv:1: header must be 'query,reference'"):
        load_config(data=data)
    data["ground_truth"] = {"kind": "synchronous"}
    with pytest.raises(ConfigError, match="scored against poses"):
        load_config(data=data)


def test_on_error_skip_leaves_out_unreadable_frames(omni: Path, tmp_path: Path) -> None:
    d = tmp_path / "frames"
    d.mkdir()
    for k, p in enumerate(sorted((omni / "mapping").glob("*.png"))[:12]):
        (d / f"f{k:02d}.png").write_bytes(p.read_bytes() if k != 5 else b"not a png")
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d)}})
    with pytest.raises(ImageError, match=r"f05\.png: cannot be read"):
        run_stage(cfg, tmp_path / "stop", "extract", quiet=True)
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(d), "on_error": "skip"}})
    run_stage(cfg, tmp_path / "skip", "extract", quiet=True)
    with h5py.File(tmp_path / "skip" / "extract.h5") as f:
        assert f["reference/index"][()].tolist() == [k for k in range(12) if k != 5]
        assert len(f["reference/offsets"]) == 12 and "f05.png" in f["reference/skipped"][0].decode()
