"""Bring-your-own descriptors: sequence matching on rows computed elsewhere (known answers)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from placeloc.core.config import load_config
from placeloc.core.runner import run_all, run_stage
from placeloc.seqslam.descriptors import DescriptorError, load_descriptors


def _traverse(folder: Path, n: int) -> None:
    folder.mkdir(parents=True)
    for i in range(n):  # the images are only listed (names, order), never read
        cv2.imwrite(str(folder / f"frame{i}.png"), np.zeros((4, 4), np.uint8))


def _planted(tmp_path: Path, n: int = 60, d: int = 32) -> tuple[Path, np.ndarray, np.ndarray]:
    """Reference descriptors, and query descriptors of the same places with strong noise:
    single images are often wrong, sequences are not."""
    rng = np.random.default_rng(7)
    ref = rng.normal(size=(n, d)).astype(np.float32)
    query = (ref + rng.normal(scale=2.5, size=(n, d))).astype(np.float32)
    _traverse(tmp_path / "ref", n)
    _traverse(tmp_path / "query", n)
    return tmp_path, ref, query


def _config(root: Path, ref_desc: Path, q_desc: Path, distance: str) -> dict:
    return load_config(data={
        "method": "seqslam", "plots": False,
        "reference": {"images": str(root / "ref")}, "query": {"images": str(root / "query")},
        "ground_truth": {"kind": "synchronous", "tolerance": 1},
        "seqslam": {"descriptors_reference": str(ref_desc), "descriptors_query": str(q_desc),
                    "descriptor_distance": distance, "ds": 10, "enhance_window": 5, "search": "centred",
                    "v_min": 1.0, "v_max": 1.0}})


def test_cosine_descriptors_from_npy_and_a_folder_of_npy(tmp_path):
    root, ref, query = _planted(tmp_path)
    np.save(root / "ref.npy", ref)
    (root / "qdesc").mkdir()
    for i, row in enumerate(query):  # one .npy per image; natural order (frame2 before frame10)
        np.save(root / "qdesc" / f"frame{i}.npy", row)
    run = root / "run"
    run_all(_config(root, root / "ref.npy", root / "qdesc", "cosine"), run, quiet=True)
    with h5py.File(run / "localize.h5") as f:
        d = f["difference"][()]
        best = f["candidates"][:, 0]
    unit = lambda m: m / np.linalg.norm(m, axis=1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(d, 1.0 - unit(ref) @ unit(query).T, atol=1e-5)
    m = json.loads((run / "metrics.json").read_text())
    # every query whose 11-frame window fits in the traverse (5 lost at each end) is right
    assert (best[5:-5] == np.arange(5, 55)).all() and (best[:5] == -1).all()
    assert m["recall_at_1"] == pytest.approx(50 / 60)
    assert m["single_image_recall_at_1"] < 0.9  # the sequence is what makes it right
    # one's own descriptors are named after their source, never after the image comparison they bypass
    assert m["comparison"] == "descriptors ref.npy (cosine)"


def test_own_descriptors_named_after_their_source_in_the_legend_and_title(tmp_path, monkeypatch):
    from placeloc.evaluation import plots

    root, ref, query = _planted(tmp_path)
    np.save(root / "ref.npy", ref)
    np.save(root / "q.npy", query)
    seen: list[str] = []
    monkeypatch.setattr(plots, "plot_pr_curves", lambda curves, path, title="": seen.extend(curves))
    monkeypatch.setattr(plots, "plot_difference_matrices", lambda panels, path, **k: seen.append(k["title"]))
    cfg = _config(root, root / "ref.npy", root / "q.npy", "l2")
    cfg["plots"] = True
    run_all(cfg, root / "run", quiet=True)
    assert "SeqSLAM descriptors ref.npy (l2) ds=10" in seen
    assert any(t.startswith("SeqSLAM descriptors ref.npy (l2): ds=10") for t in seen)
    assert not any("sad" in t for t in seen)


def test_l2_descriptors_from_hdf5_and_errors_name_the_file(tmp_path):
    root, ref, query = _planted(tmp_path)
    for name, mat in (("ref.h5", ref), ("query.h5", query)):
        with h5py.File(root / name, "w") as f:
            f["descriptors"] = mat
    run = root / "run"
    run_stage(_config(root, root / "ref.h5", root / "query.h5", "l2"), run, "localize", quiet=True)
    with h5py.File(run / "localize.h5") as f:
        d = f["difference"][()]
        best = f["candidates"][:, 0]
    np.testing.assert_allclose(d, np.linalg.norm(ref[:, None] - query[None], axis=2), rtol=1e-4, atol=1e-4)
    assert (best[5:-5] == np.arange(5, 55)).all()

    np.save(root / "short.npy", ref[:50])
    with pytest.raises(DescriptorError, match=r"short.npy: 50 descriptor rows for 60 reference images"):
        load_descriptors(root / "short.npy", 60, "reference")
    with h5py.File(root / "two.h5", "w") as f:
        f["a"], f["b"] = ref, ref
    with pytest.raises(DescriptorError, match=r"two.h5: expected a dataset named 'descriptors'"):
        load_descriptors(root / "two.h5", 60, "reference")
