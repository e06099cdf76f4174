"""``make experiment-pirf-large``: the PIRF tables at a dictionary past 300,000 entries.

8,000 mapping frames (about 7.4 laps of the generated 216 m loop) and 400 unseen test
frames; to keep the run near half an hour on 2 cores only brute force and the default
index (faiss-hnsw) are compared for Table 3, and the m_t timing sweep covers brute force
and the two FAISS indexes. Each update is also mapped with the incremental HNSW graph
(``pirf.map_search: faiss-hnsw``) for Table 2's brute-force vs HNSW mapping rows. Measured
once, before those rows existed: 28 min, dictionary 491,095 (plain) / 480,996 (improved);
see docs/pirf.md.
"""

from __future__ import annotations

from pathlib import Path

from placeloc.experiments import pirf as experiment

LARGE = {"frames": 8000, "test_frames": 400}


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    return experiment.main(out_dir, quiet=quiet, spec=experiment.QUICK if quick else LARGE,
                           backends=("bruteforce", "faiss-hnsw"),
                           timing_backends=("bruteforce", "faiss-hnsw", "faiss-ivf"), hnsw_mapping=True)
