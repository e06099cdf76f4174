"""The engine's per-image work (placeloc.core.imagework): listing, on_error, chunking over
executors, ragged storage, original indices; checked against answers known by construction."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import h5py
import numpy as np
import pytest

from placeloc.core.executor import InlineExecutor, LocalExecutor
from placeloc.core.images import ImageError, list_images
from placeloc.core.imagework import (
    ImageStream,
    ImageWork,
    describe_chunk,
    images_per_task,
    local_to_original,
    original_to_local,
    read_ragged,
    write_images,
)


def level_and_marks(image: np.ndarray, *, scale: float) -> dict[str, np.ndarray]:
    """Fixed: the image's mean grey level times ``scale``; ragged: one row (k, k) per k < the
    image's level // 10 (so image i, drawn at level 10 i, has i rows)."""
    level = float(image.mean())
    k = int(round(level)) // 10
    return {"level": np.float64(level * scale), "marks": np.repeat(np.arange(k, dtype=np.int32)[:, None], 2, axis=1)}


def plus_one(arrays: dict[str, np.ndarray], *, scale: float) -> dict[str, np.ndarray]:
    return {"level_plus_one": arrays["level"] + 1.0}


def reject_level_30(image: np.ndarray, *, scale: float) -> dict[str, np.ndarray]:
    if round(float(image.mean())) == 30:
        raise ImageError("level 30 is not wanted here")
    return level_and_marks(image, scale=scale)


def _folder(tmp_path, levels, sizes=None, corrupt=()):
    d = tmp_path / "frames"
    d.mkdir()
    for i, level in enumerate(levels):
        h, w = (sizes or {}).get(i, (8, 12))
        path = d / f"f{i}.png"
        if i in corrupt:
            path.write_bytes(b"not a png")
        else:
            cv2.imwrite(str(path), np.full((h, w), level, np.uint8))
    return d


def _ctx(executor, out=None):
    return SimpleNamespace(executor=executor, stage="extract", out=out,
                           progress=lambda it, total=None, desc="": it)


@pytest.mark.parametrize("executor", ["inline", "pool"])
@pytest.mark.parametrize("per_task", [1, 2, None])
def test_fixed_ragged_and_skipped_are_stored_at_their_original_index(tmp_path, executor, per_task):
    # images f0..f6 at levels 0, 10, ..., 60; f2 corrupt, f4 rejected by the method (level 40 -> "reject")
    d = _folder(tmp_path, [10 * i for i in range(7)], corrupt=(2,))
    images = list_images(d, on_error="skip")
    work = ImageWork(fn=level_and_marks, settings={"scale": 2.0}, ragged=("marks",), batch=plus_one, images_per_task=per_task)
    ex = InlineExecutor() if executor == "inline" else LocalExecutor(2)
    with ex, h5py.File(tmp_path / "out.h5", "w") as f:
        table = write_images(f.create_group("reference"), ImageStream(_ctx(ex), images, work))
    with h5py.File(tmp_path / "out.h5", "r") as f:
        g = f["reference"]
        kept = [0, 1, 3, 4, 5, 6]
        assert list(g["index"][()]) == kept and list(table.index) == kept
        assert [n.decode() for n in g["names"][()]] == [f"f{i}.png" for i in kept]
        assert np.allclose(g["level"][()], [20.0 * i for i in kept])
        assert np.allclose(g["level_plus_one"][()], [20.0 * i + 1 for i in kept])
        assert list(g["offsets"][()]) == list(np.concatenate([[0], np.cumsum(kept)]))
        pieces = read_ragged(g, "marks")
        for i, piece in zip(kept, pieces):
            assert piece.shape == (i, 2) and np.array_equal(piece[:, 0], np.arange(i))
        skipped = [s.decode() for s in g["skipped"][()]]
        assert len(skipped) == 1 and "f2.png" in skipped[0]
        assert g.attrs["n_listed"] == 7 and g.attrs["source"] == str(d)


def test_a_rejected_image_is_skipped_or_stops_the_run_and_names_the_file(tmp_path):
    d = _folder(tmp_path, [10 * i for i in range(6)])
    work = ImageWork(fn=reject_level_30, settings={"scale": 1.0}, ragged=("marks",), images_per_task=2)
    stream = ImageStream(_ctx(InlineExecutor()), list_images(d, on_error="skip"), work)
    assert [r.original for r in stream] == [0, 1, 2, 4, 5]
    assert [r.local for r in ImageStream(_ctx(InlineExecutor()), list_images(d, on_error="skip"), work)] == [0, 1, 2, 3, 4]
    assert len(stream.skipped) == 1 and "level 30" in stream.skipped[0]
    with pytest.raises(ImageError, match="level 30"):
        list(ImageStream(_ctx(InlineExecutor()), list_images(d), work))


def test_same_size_keeps_the_first_size_and_obeys_on_error(tmp_path):
    d = _folder(tmp_path, [10, 20, 30, 40], sizes={2: (8, 10)})
    work = ImageWork(fn=level_and_marks, settings={"scale": 1.0}, ragged=("marks",), same_size=True)
    stream = ImageStream(_ctx(InlineExecutor()), list_images(d, on_error="skip"), work)
    results = list(stream)
    assert [r.original for r in results] == [0, 1, 3] and stream.first_shape == (8, 12)
    # the ragged rows of the images after the dropped one are still theirs
    assert [len(r.arrays["marks"]) for r in results] == [1, 2, 4]
    assert "f2.png: size 10x8 differs from the first image's 12x8" in stream.skipped[0]
    with pytest.raises(ImageError, match=r"f2.png: size 10x8 differs"):
        list(ImageStream(_ctx(InlineExecutor()), list_images(d), work))


def test_a_chunk_described_in_threads_equals_one_described_alone(tmp_path):
    d = _folder(tmp_path, [10 * i for i in range(9)])
    paths = [str(p) for p in list_images(d).paths]
    work = ImageWork(fn=level_and_marks, settings={"scale": 1.0}, ragged=("marks",))
    threaded = describe_chunk((paths, work, False, 4))
    alone = [describe_chunk(([p], work, False, 1)) for p in paths]
    assert np.array_equal(threaded.fixed["level"], np.concatenate([a.fixed["level"] for a in alone]))
    assert np.array_equal(threaded.ragged["marks"], np.concatenate([a.ragged["marks"] for a in alone]))
    assert list(threaded.counts) == list(range(9))


def opencv_pool(image: np.ndarray) -> dict[str, np.ndarray]:
    """The size of OpenCV's own thread pool while this image is described."""
    return {"pool": np.int64(cv2.getNumThreads())}


def test_one_thread_describes_with_one_opencv_thread_and_gives_the_pool_back(tmp_path):
    d = _folder(tmp_path, [10, 20, 30])
    paths = [str(p) for p in list_images(d).paths]
    work = ImageWork(fn=opencv_pool)
    before = cv2.getNumThreads()
    cv2.setNumThreads(3)
    try:
        alone = describe_chunk((paths, work, False, 1))
        assert list(alone.fixed["pool"]) == [1, 1, 1]  # OpenCV's pool only wakes threads for such frames
        assert cv2.getNumThreads() == 3  # given back
        threaded = describe_chunk((paths, work, False, 2))
        assert list(threaded.fixed["pool"]) == [3, 3, 3]  # our threads share the cores with OpenCV's pool
    finally:
        cv2.setNumThreads(before)


def test_index_maps_and_chunk_size():
    index = np.array([0, 1, 3, 4, 7])
    assert list(local_to_original(index, np.array([0, 2, -1, 4]))) == [0, 3, -1, 7]
    assert list(original_to_local(index, np.array([3, 2, 7, -1, 9]))) == [2, -1, 4, -1, -1]
    assert images_per_task(10, 1) == 3 and images_per_task(100_000, 2) == 64 and images_per_task(1, 16) == 1


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_exif_orientation_is_read_with_and_without_an_exif_block(tmp_path, suffix):
    """The reader's fast path (no EXIF block: Pillow is not asked) must not lose a rotation."""
    from PIL import Image

    from placeloc.core.images import exif_orientation, read_gray

    up = np.zeros((20, 40), np.uint8)
    up[:5, :] = 255                                   # bright top rows, upright
    stored = np.ascontiguousarray(np.rot90(up, 1))    # as a sensor turned 90 deg stores it (Orientation 6)
    plain, rotated = tmp_path / f"plain{suffix}", tmp_path / f"rotated{suffix}"
    Image.fromarray(up).save(plain, quality=100) if suffix == ".jpg" else Image.fromarray(up).save(plain)
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(stored).save(rotated, exif=exif.tobytes(), **({"quality": 100} if suffix == ".jpg" else {}))
    assert exif_orientation(plain.read_bytes()) == 1 and exif_orientation(rotated.read_bytes()) == 6
    for path in (plain, rotated):
        img = read_gray(path)
        assert img.shape == (20, 40) and img[:5].mean() > 200 and img[10:].mean() < 50


def test_common_sections_reach_a_stage_as_typed_parameters(tmp_path):
    """ctx.common is built from the validated config, with common_params.py's defaults for
    what the config leaves out (no query: its images are None)."""
    from pathlib import Path

    from placeloc.core.common_params import CommonParams, ExecutorParams, GroundTruthParams
    from placeloc.core.config import load_config
    from placeloc.core.runner import common_params

    demo = Path(__file__).resolve().parent.parent / "configs" / "demo.yaml"
    cfg = load_config(demo, ["executor.workers=3", "ground_truth.tolerance=4", "plots=false"])
    common = common_params(cfg)
    assert isinstance(common, CommonParams) and isinstance(common.executor, ExecutorParams)
    assert common.executor.workers == 3 and common.executor.kind == "local" and common.plots is False
    assert common.ground_truth.tolerance == 4 and common.ground_truth.radius == GroundTruthParams().radius
    assert common.reference.images == cfg["reference"]["images"] and common.reference.on_error == "stop"
    no_query = load_config(data={"method": "seqslam", "reference": {"images": cfg["reference"]["images"]}})
    assert common_params(no_query).query.images is None


def test_small_images_are_described_on_one_thread_larger_ones_on_the_cores(tmp_path, monkeypatch):
    import placeloc.core.imagework as imagework

    monkeypatch.setattr(imagework, "usable_cores", lambda: 4)
    small, large = tmp_path / "small.png", tmp_path / "large.png"
    cv2.imwrite(str(small), np.zeros((32, 64), np.uint8))  # 2048 pixels: decoding is cheaper than the GIL-held work
    cv2.imwrite(str(large), np.zeros((64, 128), np.uint8))  # 8192 pixels
    workers = SimpleNamespace(workers=2)
    assert imagework.worker_threads(workers, str(small)) == 1
    assert imagework.worker_threads(workers, str(large)) == 2  # the usable cores shared among the workers
    assert imagework.worker_threads(workers, str(tmp_path / "missing.png")) == 2  # no header: the default
    assert imagework.worker_threads(None) == 4


def test_a_folder_listed_twice_in_a_process_is_listed_again_when_its_entries_change(tmp_path):
    from placeloc.core.images import list_images

    for i in range(3):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), np.zeros((4, 4), np.uint8))
    first = list_images(tmp_path)
    first.paths.append(tmp_path / "not-there.png")  # a caller's copy: the kept listing is untouched
    assert [p.name for p in list_images(tmp_path).paths] == ["f0.png", "f1.png", "f2.png"]
    cv2.imwrite(str(tmp_path / "f3.png"), np.zeros((4, 4), np.uint8))
    (tmp_path / "f0.png").unlink()
    assert [p.name for p in list_images(tmp_path).paths] == ["f1.png", "f2.png", "f3.png"]


def test_an_image_edited_in_place_changes_the_fingerprint_of_a_listing_made_again(tmp_path):
    import os

    from placeloc.core.images import list_images

    for i in range(2):
        cv2.imwrite(str(tmp_path / f"f{i}.png"), np.zeros((4, 4), np.uint8))
    before = list_images(tmp_path).fingerprint()
    cv2.imwrite(str(tmp_path / "f1.png"), np.full((4, 4), 255, np.uint8))  # same name: the folder's entries are unchanged
    st = os.stat(tmp_path / "f1.png")
    os.utime(tmp_path / "f1.png", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert list_images(tmp_path).fingerprint() != before
