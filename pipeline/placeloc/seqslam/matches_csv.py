"""``matches.csv``: one row per query with its best reference, in the images' own numbering."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from placeloc.artifacts import atomic_open


def write_matches_csv(path: Path, *, best: np.ndarray, confidence: np.ndarray, query_index: np.ndarray,
                      query_names: list[str], reference_index: np.ndarray, reference_names: list[str]) -> None:
    """``best[q]`` is a position in the extracted reference list (-1 = no match); the CSV
    gives the original image positions and file names."""
    with atomic_open(path, newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "reference", "confidence", "query_image", "reference_image"])
        for q, (r, c) in enumerate(zip(best, confidence)):
            if r < 0:
                w.writerow([int(query_index[q]), "", "", query_names[q], ""])
            else:
                w.writerow([int(query_index[q]), int(reference_index[r]), f"{c:.6f}", query_names[q], reference_names[r]])
