"""Single-image retrieval: the nearest neighbours against a brute-force answer, and the
pipeline on descriptors whose right answer is known by construction."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from placeloc.retrieval.neighbours import nearest, prepare


def _brute(ref: np.ndarray, qry: np.ndarray, distance: str) -> np.ndarray:
    r, q = prepare(ref, distance).astype(np.float64), prepare(qry, distance).astype(np.float64)
    if distance == "cosine":
        return np.argsort(-(q @ r.T), axis=1, kind="stable")
    return np.argsort(((q[:, None, :] - r[None, :, :]) ** 2).sum(-1), axis=1, kind="stable")


@pytest.mark.parametrize("distance", ["cosine", "l2"])
@pytest.mark.parametrize("use_faiss", [False, True])
def test_nearest_equals_brute_force(distance, use_faiss):
    rng = np.random.default_rng(3)
    ref, qry = rng.normal(size=(300, 24)), rng.normal(size=(57, 24))
    idx, score = nearest(ref, qry, k=7, distance=distance, use_faiss=use_faiss, block_size=10)
    want = _brute(ref, qry, distance)[:, :7]
    assert (idx == want).all()
    r, q = prepare(ref, distance), prepare(qry, distance)
    if distance == "cosine":
        assert np.allclose(score, np.einsum("qd,qkd->qk", q, r[idx]), atol=1e-5)
        assert (np.diff(score, axis=1) <= 1e-6).all()
    else:
        assert np.allclose(score, np.linalg.norm(q[:, None, :] - r[idx], axis=-1), atol=1e-4)
        assert (np.diff(score, axis=1) >= -1e-5).all()


def test_fewer_references_than_k_pads():
    idx, score = nearest(np.eye(3), np.eye(3), k=5, distance="cosine")
    assert (idx[:, 0] == [0, 1, 2]).all() and (idx[:, 3:] == -1).all() and np.isnan(score[:, 3:]).all()


def test_pipeline_on_descriptors_with_a_known_answer(tmp_path):
    """Query j is reference perm[j] plus small noise: every best match is perm[j], so Recall@1
    is the share of queries whose ground truth names perm[j] (all but the 5 given a wrong one)."""
    import cv2

    from placeloc.core.config import load_config
    from placeloc.core.runner import run_all

    rng = np.random.default_rng(0)
    n_ref, n_q = 40, 30
    ref = rng.normal(size=(n_ref, 16)).astype(np.float32)
    perm = rng.permutation(n_ref)[:n_q]
    qry = ref[perm] + 0.01 * rng.normal(size=(n_q, 16)).astype(np.float32)
    for role, n in (("ref", n_ref), ("q", n_q)):
        (tmp_path / role).mkdir()
        for i in range(n):
            cv2.imwrite(str(tmp_path / role / f"{role}{i}.png"), np.full((8, 8), i * 5, np.uint8))
    np.save(tmp_path / "ref.npy", ref)
    np.save(tmp_path / "q.npy", qry)
    with open(tmp_path / "gt.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "reference"])
        for j in range(n_q):
            w.writerow([j, perm[j] if j >= 5 else (perm[j] + 20) % n_ref])  # the first 5: a wrong "truth"
    cfg = load_config(data={"method": "retrieval", "reference": {"images": str(tmp_path / "ref")},
                            "query": {"images": str(tmp_path / "q")},
                            "ground_truth": {"kind": "csv", "path": str(tmp_path / "gt.csv"), "tolerance": 0},
                            "retrieval": {"descriptors_reference": str(tmp_path / "ref.npy"),
                                          "descriptors_query": str(tmp_path / "q.npy"), "top_k": 5}},
                      base_dir=tmp_path)
    run_all(cfg, tmp_path / "run", quiet=True)
    m = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert m["recall_at_1"] == pytest.approx(25 / 30)
    assert "separated_recall_at_1" not in m and "standard_recall_at_1" not in m
    assert m["features"] == "retrieval, descriptors ref.npy (cosine)"
    rows = list(csv.DictReader((tmp_path / "run" / "matches.csv").open()))
    assert [int(r["reference"]) for r in rows] == perm.tolist()
