"""SeqSLAM parameters: the one home of their defaults, ranges and meaning."""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.core.params import Params, param
from placeloc.seqslam.comparisons import COMPARISONS

# Kept here (not imported from search.py) so reading the parameters never imports the search.
SEQUENCE_SHAPES = ("trajectory", "cone", "hybrid", "flexible")


@dataclass(frozen=True)
class SeqSLAMParams(Params):
    comparison: str = param("sad", choices=COMPARISONS, help="image comparison: sad|histeq|zncc|abs_zncc|isc|isc_ext|ocm|ocm_ext")
    descriptors_reference: str | None = param(None, path=True,
                                              help="descriptors computed elsewhere for the reference images (.npy "
                                                   "matrix, .h5/.hdf5, or a folder of one .npy per image; one row per "
                                                   "image in folder order): used instead of thumbnails")
    descriptors_query: str | None = param(None, path=True, help="the same for the query images")
    descriptor_distance: str = param("cosine", choices=("cosine", "l2"), help="distance between brought descriptors")
    thumbnail: tuple[int, int] = param([64, 32], min=4, min_len=2, help="thumbnail width, height in pixels")
    patch: int = param(8, min=1, help="patch normalisation block size (sad)")
    normalisation: str = param("minmax", choices=("minmax", "zscore"), help="patch normalisation: minmax (paper) or zscore (OpenSeqSLAM)")
    gaussian_sigma: float = param(1.0, min=0.0, help="Gaussian filter before isc*/ocm*")
    ocm_epsilon: float = param(5.0, min=0.0, help="OCM: |Sobel gradient| below this -> code 16 (ignored)")
    enhance_window: int = param(10, min=1, help="R_window: local contrast enhancement over +-R rows, and match separation")
    ds: int = param(10, min=1, help="sequence length (the window has ds + 1 query frames)")
    v_min: float = param(0.8, min=0.0, help="slowest trajectory slope (reference frames per query frame); 0 lets a "
                                            "flexible path stand still where the query does")
    v_max: float = param(1.2, min=0.0, min_exclusive=True, help="fastest trajectory slope")
    v_step: float = param(0.1, min=0.0, min_exclusive=True, help="slope step")
    v_reverse: float = param(0.0, min=0.0, help="flexible: fastest speed backwards (the forward speeds from v_min "
                                                "mirrored down to -v_reverse); 0: never drives backwards")
    v_auto: bool = param(False, help="scale v_min..v_max (and v_step) by n_reference / n_query, for traverses "
                                      "recorded at different frame rates or speeds")
    sequence_shape: str = param("trajectory", choices=SEQUENCE_SHAPES,
                                help="trajectory (straight lines, SeqSLAM), cone (best reference per frame inside the "
                                     "velocity cone) or hybrid (cone proposes, trajectories rank), as in OpenSeqSLAM2; "
                                     "flexible (a path of straight segments whose speed may change between them within "
                                     "v_min..v_max, at a cost: follows slow-downs, bursts and, with v_min 0, stops)")
    speed_change_cost: float = param(1.0, min=0.0, help="flexible: cost of a change of speed, per reference frame by "
                                                         "which it bends the path over one segment (enhanced z-score units)")
    stop_cost: float = param(2.0, min=0.0, help="flexible, speeds including 0: cost of standing still, per unit of the "
                                                "query's own change from frame to frame (about 0 where the query stops)")
    reverse_cost: float = param(0.5, min=0.0, help="flexible, negative speeds: cost of driving backwards, per frame")
    collapse_stops: bool = param(False, help="frames where the query stands still (within a quarter of a moving "
                                              "frame's change of their run's first frame) are searched again with "
                                              "both traverses' standing runs collapsed, and take that answer where it "
                                              "lies between the full search's answers around the run and a moving "
                                              "reference frame lies between it and the frame's own answer; query "
                                              "traverses only (not loop closure)")
    backward_paths: bool = param(False, help="flexible, forward speeds only: also score paths that drive backwards "
                                              "throughout the window (the speeds negated, reverse_cost per frame) and "
                                              "keep the better per reference")
    backward_v_max: float = param(1.5, min=0.0, min_exclusive=True,
                                  help="backward_paths: fastest speed of the backward family, in reference frames "
                                       "per query frame as counted (the search's speeds up to this, after v_auto's "
                                       "scaling, which this limit does not take: a query that backs out has more "
                                       "frames than the route, so the scale shrinks exactly for it); a vehicle "
                                       "backs out slowly, and the family costs in proportion to its speeds")
    edges: str = param("skip", choices=("skip", "shift"),
                       help="queries within ds/2 of a traverse end: skip (no match, as SeqSLAM) or shift (use the "
                            "ds + 1 frames nearest them)")
    search: str = param("causal", choices=("causal", "centred"), help="causal (paper: the window ends at the query) or centred (OpenSeqSLAM)")
    top_k: int = param(10, min=2, help="candidates kept per query (Recall@K)")
    images_per_task: int = param(256, min=1, affects_result=False, help="images per extraction task (bigger amortises process/Dask overhead)")
    block_size: int = param(1024, min=1, affects_result=False, help="query columns per difference-matrix block (bounds memory)")
    store_difference: bool = param(True, help="keep D in localize.h5 (needed for the dissimilarity ratio and the plot)")
