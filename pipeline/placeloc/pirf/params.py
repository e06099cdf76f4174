"""PIRF-nav2 parameters: the one home of their defaults, ranges and meaning.

Defaults marked "table 1" are the values of Table 1 in H. Sasaki and T. Hamagami,
"Construction of feature space for speeding up self-localization using time series
omnidirectional images" (PIRF-nav2 itself: Kawewong, Tongprasit and Hasegawa).
"""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.core.params import Params, param
from placeloc.pirf.ann import BACKENDS
from placeloc.pirf.features import FEATURE_TYPES


@dataclass(frozen=True)
class PirfParams(Params):
    features: str = param("sift", choices=FEATURE_TYPES, help="local feature type")
    n_features: int = param(1000, min=1, help="features per frame at most")
    # Every real video has frames without features (a blank wall, a tunnel, a lens cap): they
    # are kept as frames without PIRFs, counted and named in the log and in metrics.json.
    blank_frames: str = param("empty", choices=("empty", "stop"), help="a frame with no features: keep it as a frame "
                              "without PIRFs (counted and reported), or stop the run there")
    ratio: float = param(0.7, min=0.0, max=1.0, min_exclusive=True, help="D_surf ratio test (table 1), below 1")
    w_size_default: int = param(3, min=2, help="sliding window size (table 1)")
    w_size_max: int = param(30, min=2, help="largest adaptive window")
    n_pmin: int = param(40, min=1, help="fewest PIRFs per window (table 1)")
    n_pmax: int = param(200, min=1, help="most PIRFs per window (table 1)")
    eps: float = param(30, min=1, help="epsilon (table 1)")
    sigma: float = param(2.0, min=0.0, min_exclusive=True, help="Gaussian sigma of the score (table 1)")
    tau: float = param(0.015, min=0.0, help="tau (table 1)")
    direction_correction: bool = param(True, help="correct loop-closure nodes for the PIRF track lag on "
                                       "opposite-direction revisits (not in the paper; false: as matched; see docs/pirf.md)")
    verify_frames: int = param(5, min=0, help="geometric check of each loop closure: keep it when its bearing parallax is no "
                               "larger than that between the matched node and the map frames this many frames away "
                               "(5: about 1 m at the paper's 5 frames/s and walking pace; 0: off; not in the paper, see docs/pirf.md)")
    verify_min_matches: int = param(8, min=2, help="fewest ratio-test feature matches between a closure's two frames for "
                                    "the geometric check to keep it")
    update: str = param("improved", choices=("plain", "improved"), help="dictionary update")
    map_search: str = param("bruteforce", choices=("bruteforce", "faiss-hnsw"),
                            help="nearest neighbours while mapping: exact, or an HNSW graph grown with the dictionary")
    map_ef_search: int = param(64, min=1, help="HNSW efSearch while mapping (map_search: faiss-hnsw)")
    map_hnsw_m: int = param(32, min=2, help="HNSW M while mapping (map_search: faiss-hnsw)")
    map_ef_construction: int = param(40, min=1, help="HNSW efConstruction while mapping (map_search: faiss-hnsw)")
    index: str = param("faiss-hnsw", choices=BACKENDS, help="ANN backend for m_t")
    checks: int = param(512, min=1, help="FLANN checks")
    # M 16 / efConstruction 200 (hnswlib's recommended graph) rather than faiss's default 40:
    # on the 8,000-frame dictionary (481k words) the efConstruction-40 graph left the query
    # run's m_t precision at 0.98 whatever efSearch, and its recall needed efSearch 96-128.
    hnsw_m: int = param(16, min=2, help="HNSW M (the index searched at localize)")
    hnsw_ef_construction: int = param(200, min=1, help="HNSW efConstruction (the index searched at localize)")
    ef_search: int = param(32, min=1, help="HNSW efSearch")
    ivf_nlist: int = param(1024, min=1, help="IVF lists")
    ivf_nprobe: int = param(16, min=1, help="IVF lists probed")
    kmeans_branching: int = param(32, min=2, help="FLANN k-means branching")
    kdtree_trees: int = param(4, min=1, help="FLANN kd-trees")
    index_recall: float | None = param(0.97, min=0.0, max=1.0, help="tune the index's search setting to meet this recall "
                                       "against exact search (null: use ef_search / ivf_nprobe / checks as given)")
    index_jaccard: float = param(0.95, min=0.0, max=1.0, help="and this m_t Jaccard agreement with exact search "
                                 "(with index_recall)")
    index_tune_sample: int = param(2000, min=10, help="dictionary entries searched to tune the index (grown until "
                                   "400 of them pass the ratio test, up to 20,000)")
    index_tune_queries: bool = param(True, help="at localize, re-tune the search setting on a random sample of the query "
                                     "run's own PIRFs (searched exactly: a fixed cost, at most a tenth of brute force), so "
                                     "index_recall / index_jaccard hold for the queries searched; the dictionary's own "
                                     "entries are easier (with index_recall)")
    compare_bf: bool = param(True, help="also time brute force at localize and report agreement")
    query_poses: str | None = param(None, path=True, help="CSV of the query frames' poses (the reference's: ground_truth.path)")


# Every backend's settings, and the parameters of the index stage.
BACKEND_SETTINGS = ("checks", "hnsw_m", "hnsw_ef_construction", "ef_search", "ivf_nlist", "ivf_nprobe", "kmeans_branching",
                    "kdtree_trees")
INDEX_KEYS = ("index", "index_recall", "index_jaccard", "index_tune_sample", *BACKEND_SETTINGS)


def index_settings(p: PirfParams) -> dict[str, int]:
    """The backend settings of ``p`` as the keyword dict :class:`placeloc.pirf.ann.AnnIndex` takes."""
    return {k: getattr(p, k) for k in BACKEND_SETTINGS}
