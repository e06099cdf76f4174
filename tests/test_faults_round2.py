"""Hostile inputs, second round: each case sets up one fault on tiny data and asserts the
clean outcome (what docs/reliability.md promises). ``make faults`` runs these with
tests/test_faults.py and prints one table row per case."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from placeloc.config import load_config
from placeloc.images import ImageError, list_images, read_gray, read_rgb

ROOT = Path(__file__).resolve().parent.parent
PLACELOC = [sys.executable, "-m", "placeloc.cli"]


def _cli(args: list[str], **env: str):
    import logging

    from typer.testing import CliRunner

    from placeloc.cli import app

    root = logging.getLogger()
    saved = (root.handlers[:], root.level)
    try:
        return CliRunner().invoke(app, args, env=env or None)
    finally:
        root.handlers[:], root.level = saved


def _err(result) -> str:
    return getattr(result, "stderr", "") or result.output


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


# ----------------------------------------------------------------- 1. EXIF orientation

def _upright() -> np.ndarray:
    """A 60 x 90 RGB picture with no symmetry: a turned or mirrored copy differs a lot."""
    y, x = np.mgrid[0:60, 0:90]
    img = np.stack([(x * 255 // 89), (y * 255 // 59), ((x + 2 * y) % 64) * 4], axis=-1).astype(np.uint8)
    img[5:20, 5:30] = (255, 255, 255)
    return img


def _jpeg_with_orientation(path: Path, stored_rgb: np.ndarray, orientation: int) -> None:
    from PIL import Image

    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored_rgb).save(path, quality=98, exif=exif.tobytes())


@pytest.mark.parametrize("orientation,stored", [(3, lambda u: np.rot90(u, 2)), (6, lambda u: np.rot90(u, 1))])
def test_exif_rotated_jpeg_reads_as_the_upright_image(tmp_path, orientation, stored):
    """A camera that stores the sensor's pixels and sets Orientation=3 (turned 180 deg) or 6
    (turn 90 deg clockwise to view) must read like the upright picture."""
    import cv2

    up = _upright()
    path = tmp_path / f"o{orientation}.jpg"
    _jpeg_with_orientation(path, np.ascontiguousarray(stored(up)), orientation)
    gray = read_gray(path)
    want = cv2.cvtColor(up, cv2.COLOR_RGB2GRAY)
    assert gray.shape == want.shape
    assert np.abs(gray.astype(int) - want).mean() < 3  # JPEG loss only; a turned copy differs by ~60
    assert np.abs(read_rgb(path).astype(int) - up).mean() < 4


def test_all_eight_exif_orientations_match_pillows_transpose(tmp_path):
    from PIL import Image, ImageOps

    stored = _upright()
    for o in range(1, 9):
        path = tmp_path / f"o{o}.jpg"
        _jpeg_with_orientation(path, stored, o)
        with Image.open(path) as im:
            want = np.asarray(ImageOps.exif_transpose(im).convert("RGB"))
        got = read_rgb(path)
        assert got.shape == want.shape, o
        assert np.abs(got.astype(int) - want).mean() < 2, o


def test_every_image_read_in_the_package_goes_through_the_one_reader():
    """No module but images.py calls cv2.imread (which ignores EXIF with IMREAD_UNCHANGED)."""
    offenders = []
    for path in (ROOT / "pipeline" / "placeloc").rglob("*.py"):
        if path.name == "images.py" or "experiments" in path.parts:
            continue
        text = path.read_text()
        if "cv2.imread(" in text or "IMREAD_" in text:
            offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_seqslam_on_exif_rotated_queries_matches_the_plain_run(route, tmp_path):
    """End to end: the query frames stored turned 180 deg with Orientation=3 give the same
    Recall@1 as the same frames stored upright."""
    import cv2

    from placeloc.runner import read_metrics, run_all

    results = {}
    for kind in ("plain", "rotated"):
        folder = tmp_path / kind
        folder.mkdir()
        for png in sorted((route / "query").glob("*.png")):
            up = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
            if kind == "plain":
                _jpeg_with_orientation(folder / (png.stem + ".jpg"), up, 1)
            else:
                _jpeg_with_orientation(folder / (png.stem + ".jpg"), np.ascontiguousarray(np.rot90(up, 2)), 3)
        cfg = load_config(route / "config.yaml", ["plots=false", f"query.images={folder}"])
        run_all(cfg, tmp_path / f"run-{kind}", quiet=True)
        results[kind] = read_metrics(tmp_path / f"run-{kind}")["recall_at_1"]
    assert results["plain"] > 0.5 and results["rotated"] == pytest.approx(results["plain"], abs=0.02), results


# ----------------------------------------------------------------- 6/7. bad image files

def _truncated_jpeg(path: Path) -> None:
    import cv2

    ok, data = cv2.imencode(".jpg", (np.random.default_rng(0).random((64, 96)) * 255).astype(np.uint8))
    path.write_bytes(data.tobytes()[: len(data) // 2])


def test_truncated_jpeg_is_an_error_and_skipped_with_on_error_skip(route, tmp_path):
    from placeloc.runner import run_stage

    bad = route / "query" / "zz_truncated.jpg"
    _truncated_jpeg(bad)
    with pytest.raises(ImageError, match="truncated JPEG"):
        read_gray(bad)
    res = _cli(["extract", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"])
    assert res.exit_code == 2 and "zz_truncated.jpg: truncated JPEG" in _err(res) and "on_error: skip" in _err(res)
    cfg = load_config(route / "config.yaml", ["plots=false", "query.on_error=skip"])
    import h5py

    run_stage(cfg, tmp_path / "s", "extract", quiet=True)
    with h5py.File(tmp_path / "s" / "extract.h5") as f:
        skipped = [s.decode() for s in f["query/skipped"][()]]
    assert len(skipped) == 1 and "zz_truncated.jpg" in skipped[0]


def test_symlink_loop_names_the_link_and_on_error_skip_skips_it(route, tmp_path):
    loop = route / "query" / "loop.png"
    os.symlink(loop.name, loop)
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert "loop.png: is a symbolic link that points to itself" in lines[0] and "Errno" not in lines[0]
    images = list_images(route / "query", on_error="skip")
    assert loop not in images.paths and len(images.skipped) == 1
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "s"), "-q", "--set", "query.on_error=skip"])
    assert res.exit_code == 0, _err(res)
