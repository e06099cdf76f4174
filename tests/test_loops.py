"""The loops contract: loop-closure ground truth in the formats the public sets ship, and
scoring by hand-computed answers (the evaluation kit's rules: exclusion of recent frames,
a tolerance of neighbouring frames, recall over the frames that close a loop)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import io as sio
from scipy import sparse

from placeloc.evaluation.ground_truth import GroundTruthError
from placeloc.evaluation.loops import loop_truth, read_matrix, score_loops
from placeloc.evaluation.metrics import pr_curve


def _truth(n: int = 12) -> np.ndarray:
    """Frames 8..11 revisit frames 0..3 (lower triangle: row = the later frame)."""
    m = np.zeros((n, n), np.uint8)
    for i in range(8, 12):
        m[i, i - 8] = 1
    return m


@pytest.mark.parametrize("fmt", ["npy", "npz", "mat", "mat-upper", "txt", "csv", "h5", "symmetric"])
def test_every_format_reads_to_the_same_lower_triangle(tmp_path, fmt):
    m = _truth()
    want = m.astype(bool)
    if fmt == "npy":
        np.save(path := tmp_path / "gt.npy", m)
    elif fmt == "npz":
        np.savez(path := tmp_path / "gt.npz", GThard=m)
    elif fmt == "mat":  # Lip6 / City Centre style: a named float or uint8 variable, lower triangle
        sio.savemat(path := tmp_path / "gt.mat", {"truth": m.astype(np.float64)})
    elif fmt == "mat-upper":  # New College (2624 frames) ships the upper triangle
        sio.savemat(path := tmp_path / "gt.mat", {"gt": m.T.copy()})
    elif fmt == "txt":
        np.savetxt(path := tmp_path / "gt.txt", m, fmt="%d")
    elif fmt == "csv":
        np.savetxt(path := tmp_path / "gt.csv", m, fmt="%d", delimiter=",")
    elif fmt == "h5":
        import h5py

        with h5py.File(path := tmp_path / "gt.h5", "w") as f:
            f["GT"] = m
    else:
        np.save(path := tmp_path / "gt.npy", m | m.T)
    assert (read_matrix(path, 12) == want).all()


def test_matrix_problems_are_one_clear_error(tmp_path):
    np.save(tmp_path / "big.npy", _truth(14))
    with pytest.raises(GroundTruthError, match=r"14 x 14 but the traverse has 12 frames"):
        read_matrix(tmp_path / "big.npy", 12)
    bad = _truth()
    bad[9, 1] = 2
    np.save(tmp_path / "bad.npy", bad)
    with pytest.raises(GroundTruthError, match=r"value 2 at \(9, 1\)"):
        read_matrix(tmp_path / "bad.npy", 12)
    sio.savemat(tmp_path / "two.mat", {"a": _truth(), "b": _truth()})
    with pytest.raises(GroundTruthError, match="expected one square N x N matrix"):
        read_matrix(tmp_path / "two.mat", 12)
    np.save(tmp_path / "rect.npy", np.zeros((12, 10)))
    with pytest.raises(GroundTruthError, match="square"):
        read_matrix(tmp_path / "rect.npy", 12)


def test_a_short_matrix_is_padded(tmp_path):
    """KITTI 06's matrix is three frames short of the sequence: the last frames close no loop."""
    np.save(tmp_path / "short.npy", _truth(12))
    m = read_matrix(tmp_path / "short.npy", 15)
    assert m.shape == (15, 15) and m.sum() == 4 and not m[12:].any()


def test_scoring_by_hand():
    """12 frames, frames 8..11 close loops with 0..3; exclusion 4, tolerance 1.

    frame 8 -> 0 right; 9 -> 2 right (within 1 of 1); 10 -> 6 wrong (truth 2); 11 -> 9
    ignored (inside the exclusion: 9 > 11 - 4); 5 -> 0 wrong (no loop); confidences 0.9,
    0.8, 0.7, 0.95, 0.6."""
    truth = sparse.csr_matrix(_truth().astype(bool))
    frames = np.arange(12)
    match = np.full(12, -1)
    conf = np.zeros(12)
    for f, j, c in ((8, 0, 0.9), (9, 2, 0.8), (10, 6, 0.7), (11, 9, 0.95), (5, 0, 0.6)):
        match[f], conf[f] = j, c
    cand, correct, has_loop, example = score_loops(truth, frames, match, exclude_recent=4, tolerance=1)
    assert cand.tolist() == [f in (5, 8, 9, 10) for f in range(12)]
    assert np.flatnonzero(correct).tolist() == [8, 9]
    assert np.flatnonzero(has_loop).tolist() == [8, 9, 10, 11]
    assert example[10] == 2 and example[11] == 3
    pr = pr_curve(conf, correct, n_queries=int(has_loop.sum()), has_match=cand)
    # thresholds 0.9, 0.8, 0.7, 0.6: precision 1, 1, 2/3, 1/2; recall 1/4, 2/4, 2/4, 2/4
    assert pr.precision.tolist() == pytest.approx([1, 1, 2 / 3, 1 / 2])
    assert pr.recall.tolist() == pytest.approx([0.25, 0.5, 0.5, 0.5])
    assert pr.recall_at_100_precision == 0.5


def test_positions_within_a_radius_give_the_pairs():
    import csv
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "poses.csv"
        xs = [0, 1, 2, 3, 4, 0.2, 2.1]  # frames 5 and 6 come back near 0 and 2
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["frame", "x", "y"])
            for i, x in enumerate(xs):
                w.writerow([i, x, 0.0])
        t = loop_truth({"kind": "poses", "path": str(path), "radius": 0.5}, [f"f{i}.png" for i in range(7)])
    assert sorted(zip(*t.nonzero())) == [(5, 0), (6, 2)]
