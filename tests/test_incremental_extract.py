"""Incremental extract (placeloc.core.imagework): a re-run after a few images were added,
edited, touched or removed describes only those and takes every other image's rows from the
previous extract.h5; the artifact equals a full extract's, dataset by dataset."""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import h5py
import numpy as np
import pytest

from placeloc.core import imagework
from placeloc.core.config import load_config
from placeloc.core.executor import InlineExecutor, LocalExecutor
from placeloc.core.images import ImageError, list_images
from placeloc.core.imagework import ImageStream, ImageWork, write_images
from placeloc.core.runner import code_fingerprint, run_stage

# Attributes that differ between two writes of the same result (when, which write, how long).
WRITE_ATTRS = {"created", "write_id", "seconds"}


def level_and_marks(image: np.ndarray, *, scale: float) -> dict[str, np.ndarray]:
    """Fixed: the mean grey level times ``scale``; ragged: level // 10 rows (k, k); an image
    at level 30 is rejected (skipped with on_error: skip)."""
    level = float(image.mean())
    if round(level) == 30:
        raise ImageError("level 30 is not wanted here")
    k = int(round(level)) // 10
    return {"level": np.float64(level * scale), "marks": np.repeat(np.arange(k, dtype=np.int32)[:, None], 2, axis=1)}


def plus_one(arrays: dict[str, np.ndarray], *, scale: float) -> dict[str, np.ndarray]:
    return {"level_plus_one": arrays["level"] + 1.0}


def _contents(path: Path) -> dict[str, Any]:
    """Every dataset (values, dtype) and every attribute of an HDF5 file, by path; the
    attributes of a write (time, id, seconds) left out."""
    out: dict[str, Any] = {}
    with h5py.File(path, "r") as f:
        out["/@attrs"] = {k: _plain(v) for k, v in f.attrs.items() if k not in WRITE_ATTRS}

        def visit(name: str, obj: Any) -> None:
            if isinstance(obj, h5py.Dataset):
                out[name] = (obj.dtype.str, obj.shape, obj[()])
            out[f"{name}@attrs"] = {k: _plain(v) for k, v in obj.attrs.items()}

        f.visititems(visit)
    return out


def _plain(value: Any) -> Any:
    return value.tolist() if isinstance(value, np.ndarray) else value


def assert_same_artifact(a: Path, b: Path) -> None:
    ca, cb = _contents(a), _contents(b)
    assert sorted(ca) == sorted(cb)
    for key in ca:
        if key.endswith("@attrs"):
            assert ca[key] == cb[key], key
            continue
        (dt_a, shape_a, va), (dt_b, shape_b, vb) = ca[key], cb[key]
        assert (dt_a, shape_a) == (dt_b, shape_b), key
        floats = np.asarray(va).dtype.kind in "fc"
        assert np.array_equal(va, vb, equal_nan=floats), key
        if floats:   # bit for bit, not only equal values (0.0 and -0.0)
            assert np.asarray(va).tobytes() == np.asarray(vb).tobytes(), key


class _Counting:
    """describe_chunk that records the images it describes (inline executor: in this process)."""

    def __init__(self) -> None:
        self.paths: list[str] = []
        self.real = imagework.describe_chunk

    def __call__(self, task: Any) -> Any:
        self.paths.extend(Path(p).name for p in task[0])
        return self.real(task)


# ------------------------------------------------------------------ the engine


def _write(folder: Path, out: Path, work: ImageWork, executor: Any, previous: Path | None = None, on_error: str = "skip",
           fold: Any = None) -> imagework.ImageTable:
    images = list_images(folder, on_error=on_error)
    ctx = SimpleNamespace(executor=executor, stage="extract", out=None, previous=previous,
                          progress=lambda it, total=None, desc="": it)
    with h5py.File(out, "w") as f:
        f.attrs["placeloc_code"] = code_fingerprint()
        return write_images(f.create_group("reference"), ImageStream(ctx, images, work), fold=fold)


def _image(folder: Path, name: str, level: int, size: tuple[int, int] = (8, 12)) -> None:
    cv2.imwrite(str(folder / name), np.full(size, level, np.uint8))


def _bump_mtime(path: Path, seconds: int = 5) -> None:
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + seconds * 10**9))


@pytest.mark.parametrize("per_task", [2, 3, None])
@pytest.mark.parametrize("same_size", [False, True])
def test_engine_takes_unchanged_rows_and_equals_a_full_write(tmp_path, monkeypatch, caplog, per_task, same_size):
    # f0..f9 at levels 0..90: f3 rejected (level 30), f5 corrupt, f7 of another size (skipped
    # with same_size); then f11 added in the middle of the natural order (after f1), f2
    # edited, f4 touched, f6 removed, f5 repaired, f8 changed size.
    d = tmp_path / "frames"
    d.mkdir()
    for i in range(10):
        _image(d, f"f{i}.png", 10 * i, (10, 12) if i == 7 else (8, 12))
    (d / "f5.png").write_bytes(b"not a png")
    work = ImageWork(fn=level_and_marks, settings={"scale": 2.0}, ragged=("marks",), batch=plus_one,
                     images_per_task=per_task, same_size=same_size)
    counting = _Counting()
    monkeypatch.setattr(imagework, "describe_chunk", counting)
    _write(d, tmp_path / "old.h5", work, InlineExecutor())
    assert len(counting.paths) == 10

    _image(d, "f1b.png", 15)
    _image(d, "f2.png", 25)
    _bump_mtime(d / "f2.png")   # a rewrite within the same mtime tick is what `stat` cannot see
    _bump_mtime(d / "f4.png")
    (d / "f6.png").unlink()
    _image(d, "f5.png", 50)
    _image(d, "f8.png", 80, (10, 12))
    counting.paths.clear()
    with caplog.at_level(logging.INFO, logger="placeloc"):
        new = _write(d, tmp_path / "new.h5", work, InlineExecutor(), previous=tmp_path / "old.h5")
    # described: the added, edited, touched, repaired and resized images, and the two that
    # were not kept before (f3 rejected; f7 only with same_size, where it was skipped)
    expected = {"f1b.png", "f2.png", "f3.png", "f4.png", "f5.png", "f8.png"} | ({"f7.png"} if same_size else set())
    assert sorted(counting.paths) == sorted(expected)
    taken = 10 - len(expected)
    assert f"extract reference: {taken} of 10 images taken from the previous extract.h5 (unchanged), " \
           f"{len(expected)} described" in caplog.text
    full = _write(d, tmp_path / "full.h5", work, InlineExecutor())
    assert_same_artifact(tmp_path / "new.h5", tmp_path / "full.h5")
    assert (new.names, new.skipped, new.first_shape, new.n_listed) == (full.names, full.skipped, full.first_shape,
                                                                       full.n_listed)
    assert new.index.tolist() == full.index.tolist()
    # the pool gives the same artifact
    monkeypatch.setattr(imagework, "describe_chunk", counting.real)
    with LocalExecutor(2) as pool:
        _write(d, tmp_path / "pool.h5", work, pool, previous=tmp_path / "old.h5")
    assert_same_artifact(tmp_path / "pool.h5", tmp_path / "full.h5")


def test_a_first_image_of_a_new_size_skips_the_old_rows_of_the_old_size(tmp_path, monkeypatch, caplog):
    # same_size: f0 now has another size, so every image taken from the previous run is of
    # another size than the first: skipped with the message a full run gives
    d = tmp_path / "frames"
    d.mkdir()
    for i in range(5):
        _image(d, f"f{i}.png", 10 * i + 40)
    work = ImageWork(fn=level_and_marks, settings={"scale": 1.0}, ragged=("marks",), same_size=True, images_per_task=2)
    _write(d, tmp_path / "old.h5", work, InlineExecutor())
    _image(d, "f0.png", 40, (10, 12))
    _bump_mtime(d / "f0.png")
    counting = _Counting()
    monkeypatch.setattr(imagework, "describe_chunk", counting)
    with caplog.at_level("INFO", logger="placeloc"):
        new = _write(d, tmp_path / "new.h5", work, InlineExecutor(), previous=tmp_path / "old.h5")
    assert counting.paths == ["f0.png"]
    # the 4 rows read are then skipped for their size: none counts as taken
    assert "extract reference: 0 of 5 images taken from the previous extract.h5 (unchanged), 1 described" in caplog.text
    _write(d, tmp_path / "full.h5", work, InlineExecutor())
    assert_same_artifact(tmp_path / "new.h5", tmp_path / "full.h5")
    assert new.names == ["f0.png"] and len(new.skipped) == 4 and new.first_shape == (10, 12)


def _refused(tmp_path: Path, monkeypatch: Any, work: ImageWork, old_work: ImageWork | None = None,
             damage: Any = None, fold: Any = None) -> list[str]:
    """The images described again after adding one, when the previous artifact was written
    with ``old_work`` (and then ``damage``d): every one where reuse is refused."""
    d = tmp_path / "frames"
    d.mkdir(parents=True, exist_ok=True)
    for i in range(4):
        _image(d, f"f{i}.png", 10 * i + 40)
    _write(d, tmp_path / "old.h5", old_work or work, InlineExecutor(), fold=fold)
    if damage is not None:
        with h5py.File(tmp_path / "old.h5", "a") as f:
            damage(f)
    _image(d, "f9.png", 90)
    counting = _Counting()
    monkeypatch.setattr(imagework, "describe_chunk", counting)
    _write(d, tmp_path / "new.h5", work, InlineExecutor(), previous=tmp_path / "old.h5", fold=fold)
    return counting.paths


ALL = ["f0.png", "f1.png", "f2.png", "f3.png", "f9.png"]


def test_rows_are_taken_only_from_the_same_code_work_and_keys(tmp_path, monkeypatch):
    work = ImageWork(fn=level_and_marks, settings={"scale": 2.0}, ragged=("marks",))
    assert _refused(tmp_path / "same", monkeypatch, work) == ["f9.png"]
    # other settings (2 is not 2.0 either), another batch, another code, an artifact from before the keys
    assert _refused(tmp_path / "settings", monkeypatch, work, ImageWork(fn=level_and_marks, settings={"scale": 3.0},
                                                                       ragged=("marks",))) == ALL
    assert _refused(tmp_path / "int", monkeypatch, work, ImageWork(fn=level_and_marks, settings={"scale": 2},
                                                                  ragged=("marks",))) == ALL
    assert _refused(tmp_path / "batch", monkeypatch, work, ImageWork(fn=level_and_marks, settings={"scale": 2.0},
                                                                    ragged=("marks",), batch=plus_one)) == ALL
    assert _refused(tmp_path / "code", monkeypatch, work,
                    damage=lambda f: f.attrs.__setitem__("placeloc_code", "0" * 64)) == ALL
    assert _refused(tmp_path / "old", monkeypatch, work, damage=lambda f: f["reference"].__delitem__("image_keys")) == ALL
    # a lambda has no lasting identity: never taken
    anonymous = ImageWork(fn=level_and_marks, settings={"scale": 2.0}, ragged=("marks",), read=lambda p: cv2.imread(p, 0))
    assert _refused(tmp_path / "lambda", monkeypatch, anonymous) == ALL


def test_no_rows_are_taken_with_a_fold(tmp_path, monkeypatch):
    work = ImageWork(fn=level_and_marks, settings={"scale": 2.0}, ragged=("marks",))
    total = {"sum": 0.0}

    def running_sum(item: imagework.ImageResult) -> dict[str, np.ndarray]:
        total["sum"] += float(item.arrays["level"])
        return {"running": np.float64(total["sum"]), "marks": item.arrays["marks"]}

    assert _refused(tmp_path, monkeypatch, work, fold=running_sum) == ALL


def test_work_identity_is_exact():
    a = ImageWork(fn=level_and_marks, settings={"scale": 0.1 + 0.2})
    b = ImageWork(fn=level_and_marks, settings={"scale": 0.3})
    assert imagework.work_identity(a) != imagework.work_identity(b)
    assert imagework.work_identity(a) == imagework.work_identity(ImageWork(fn=level_and_marks, settings={"scale": 0.1 + 0.2}))
    arr = ImageWork(fn=level_and_marks, settings={"scale": np.arange(2000.0)})
    arr2 = ImageWork(fn=level_and_marks, settings={"scale": np.r_[np.arange(1999.0), 0.5]})
    assert imagework.work_identity(arr) != imagework.work_identity(arr2)   # not by a shortened repr
    assert imagework.work_identity(ImageWork(fn=level_and_marks, settings={"scale": (1, 2)})) != \
        imagework.work_identity(ImageWork(fn=level_and_marks, settings={"scale": [1, 2]}))
    assert imagework.work_identity(ImageWork(fn=level_and_marks, settings={"scale": object()})) is None


# ------------------------------------------------------------------ through the runner, per method


def _run_twice(cfg: dict, tmp_path: Path, change: Any, monkeypatch: Any, caplog: Any) -> list[str]:
    """extract in tmp_path/run; ``change()`` the images; extract again (counting the images
    described) and a full extract into tmp_path/full: the two artifacts must be equal."""
    run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    change()
    counting = _Counting()
    monkeypatch.setattr(imagework, "describe_chunk", counting)
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    described = sorted(counting.paths)
    monkeypatch.setattr(imagework, "describe_chunk", counting.real)
    run_stage(cfg, tmp_path / "full", "extract", quiet=True)
    assert_same_artifact(tmp_path / "run" / "extract.h5", tmp_path / "full" / "extract.h5")
    # the kept copy of the previous artifact is gone
    assert not [p.name for p in (tmp_path / "run").iterdir() if ".previous" in p.name]
    return described


@pytest.mark.parametrize("fingerprint", ["stat", "content"])
def test_seqslam_extract_describes_only_the_changed_images(route, tmp_path, monkeypatch, caplog, fingerprint):
    cfg = load_config(route / "config.yaml", ["plots=false", "executor.workers=1", "ground_truth.kind=none",
                                              f"query.fingerprint={fingerprint}", f"reference.fingerprint={fingerprint}"])
    q = route / "query"

    def change() -> None:
        shutil.copy(q / "frame5.png", q / "frame5b.png")          # added, between frame5 and frame6
        img = cv2.imread(str(q / "frame7.png"), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(q / "frame7.png"), 255 - img)              # edited
        _bump_mtime(q / "frame7.png")
        _bump_mtime(q / "frame9.png")                              # touched: described again with `stat` only
        (q / "frame12.png").unlink()                               # removed

    described = _run_twice(cfg, tmp_path, change, monkeypatch, caplog)
    expected = ["frame5b.png", "frame7.png"] + (["frame9.png"] if fingerprint == "stat" else [])
    assert described == expected
    n = len(list_images(q))
    assert f"extract query: {n - len(expected)} of {n} images taken from the previous extract.h5 (unchanged), " \
           f"{len(expected)} described" in caplog.text
    assert "extract reference: 80 of 80 images taken from the previous extract.h5 (unchanged), 0 described" in caplog.text


def test_seqslam_forced_extract_describes_every_image(route, tmp_path, monkeypatch):
    cfg = load_config(route / "config.yaml", ["plots=false", "executor.workers=1", "ground_truth.kind=none"])
    run_stage(cfg, tmp_path / "run", "extract", quiet=True)
    shutil.copy(route / "query" / "frame5.png", route / "query" / "frame5b.png")
    counting = _Counting()
    monkeypatch.setattr(imagework, "describe_chunk", counting)
    run_stage(cfg, tmp_path / "run", "extract", quiet=True, force=True)
    assert len(counting.paths) == 80 + len(list_images(route / 'query'))


def test_seqslam_skipped_images_are_described_again(route, tmp_path, monkeypatch, caplog):
    # on_error: skip: a corrupt frame is skipped; repaired, it is described (and only it)
    cfg = load_config(route / "config.yaml", ["plots=false", "executor.workers=1", "ground_truth.kind=none",
                                              "query.on_error=skip"])
    q = route / "query"
    good = (q / "frame3.png").read_bytes()
    (q / "frame3.png").write_bytes(b"broken")
    (q / "frame40.png").write_bytes(b"broken too")

    def change() -> None:
        (q / "frame3.png").write_bytes(good)
        _bump_mtime(q / "frame3.png")

    assert _run_twice(cfg, tmp_path, change, monkeypatch, caplog) == ["frame3.png", "frame40.png"]
    with h5py.File(tmp_path / "run" / "extract.h5") as f:
        assert [s.decode() for s in f["query/skipped"][()]] and "frame40.png" in f["query/skipped"][0].decode()


def test_retrieval_extract_describes_only_the_changed_images(route, tmp_path, monkeypatch, caplog):
    cfg = load_config(data={"method": "retrieval", "reference": {"images": str(route / "reference")},
                            "query": {"images": str(route / "query")}, "plots": False, "executor": {"workers": 1},
                            "retrieval": {"thumbnail": [64, 32], "distance": "cosine"}}, base_dir=route)
    r = route / "reference"

    def change() -> None:
        shutil.copy(r / "frame0.png", r / "frame79b.png")   # added at the end
        (r / "frame0.png").unlink()                         # the first removed

    assert _run_twice(cfg, tmp_path, change, monkeypatch, caplog) == ["frame79b.png"]
    assert "extract reference: 79 of 80 images taken from the previous extract.h5 (unchanged), 1 described" in caplog.text


def _umap_config(d: Path, **umap: Any) -> dict:
    data = {"method": "umap", "query": {"images": str(d / "q")}, "plots": False, "executor": {"workers": 1},
            "umap": {"model": str(d / "plan.yaml"),
                     "grid": {"x": [0.4, 11.6, 0.2], "y": [0.4, 2.0, 0.4], "z": 1.14, "headings": [45.0, 315.0]}, **umap}}
    return load_config(data=data, base_dir=d)


def test_umap_pinhole_extract_describes_only_the_changed_photos(tmp_path, monkeypatch, caplog):
    # line images and AKAZE keypoints (ragged, kp_offsets), every photo of the first one's size
    from test_umap_method import _tiny_corridor

    (tmp_path / "data").mkdir()
    d = _tiny_corridor(tmp_path / "data")
    cfg = _umap_config(d, mode="umap+ca", sensor_csv=str(d / "sensor.csv"))
    q = d / "q"

    def change() -> None:
        shutil.copy(q / "f3.png", q / "f3b.png")
        img = cv2.imread(str(q / "f5.png"), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(q / "f5.png"), np.flipud(img))
        _bump_mtime(q / "f5.png")
        (q / "f6.png").unlink()

    assert _run_twice(cfg, tmp_path, change, monkeypatch, caplog) == ["f3b.png", "f5.png"]
    assert "extract query: 6 of 8 images taken from the previous extract.h5 (unchanged), 2 described" in caplog.text


def test_umap_panorama_extract_describes_only_the_changed_panoramas(tmp_path, monkeypatch, caplog):
    import yaml

    from placeloc.geometry.floorplan import floor_plan_model
    from placeloc.geometry.panorama import render_panoramas
    from placeloc.umap.bits import unpack

    d = tmp_path / "data"
    (d / "q").mkdir(parents=True)
    plan = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [6, 0], [6, 3], [0, 3]],
            "doors": [{"from": [2, 0], "to": [2.9, 0], "height": 2.0}]}
    (d / "plan.yaml").write_text(yaml.safe_dump(plan))
    m = floor_plan_model(plan)
    truths = np.array([[1.0 + k, 1.5, 1.4, 30.0 * k] for k in range(5)])
    pictures = unpack(render_panoramas(m.segments, m.faces, truths, width=256, height=128, hidden=True), 128, 256)

    def save(k: int, name: str, size: tuple[int, int] = (256, 128)) -> None:
        grey = np.where(cv2.dilate(pictures[k], np.ones((2, 2), np.uint8)) > 0, 60, 190).astype(np.uint8)
        cv2.imwrite(str(d / "q" / name), cv2.resize(grey, size, interpolation=cv2.INTER_NEAREST))

    # p0 larger than the others: removed, the artifact's query size (first_shape) is p1's,
    # which comes from the previous artifact's stored sizes
    save(0, "p0.png", (384, 192))
    for k in range(1, 4):
        save(k, f"p{k}.png")
    cfg = load_config(data={"method": "umap", "query": {"images": str(d / "q")}, "plots": False,
                            "executor": {"workers": 1},
                            "umap": {"model": str(d / "plan.yaml"), "query_kind": "panorama",
                                     "grid": {"x": [0.25, 5.75, 0.25], "y": [0.25, 2.75, 0.25], "z": 1.4,
                                              "headings": [0.0]},
                                     "panorama": {"orientation_bins": 1}}}, base_dir=d)

    def change() -> None:
        save(4, "p1b.png")
        (d / "q" / "p0.png").unlink()

    assert _run_twice(cfg, tmp_path, change, monkeypatch, caplog) == ["p1b.png"]
    assert "extract query: 3 of 4 images taken from the previous extract.h5 (unchanged), 1 described" in caplog.text
    with h5py.File(tmp_path / "run" / "extract.h5") as f:
        assert (int(f.attrs["query_width"]), int(f.attrs["query_height"])) == (256, 128)
