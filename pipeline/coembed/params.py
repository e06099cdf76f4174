"""Co-embedding parameters: the one home of their defaults, ranges and meaning."""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.params import Params, param


@dataclass(frozen=True)
class CoembedParams(Params):
    source: str = param("csv", choices=("csv", "aruco", "sift", "aruco+sift"), help="where observations come from")
    observations: str | None = param(None, path=True, help="long-form CSV t,feature,value[,value2...] (source csv)")
    images: str | None = param(None, path=True, help="folder of frames in time order (image sources)")
    image_values: str = param("x", choices=("x", "xy"), help="x: horizontal image coordinate (paper), xy: both")
    aruco_dictionary: str = param("DICT_4X4_50", help="OpenCV ArUco dictionary name")
    sift_features: int = param(1000, min=1, help="SIFT features per frame")
    sift_ratio: float = param(0.7, min=0.0, max=1.0, min_exclusive=True, help="Lowe ratio for SIFT tracking")
    sift_min_track: int = param(3, min=2, help="shortest SIFT track kept (frames)")
    sift_id_offset: int = param(100000, min=0, help="SIFT track ids start here when mixed with marker ids")
    landmarks: str | None = param(None, path=True, help="CSV feature,x,y[,z]: known positions")
    landmark_ids: tuple[int, ...] = param([], help="use only these rows of the landmark file ([] = all)")
    dim: int = param(2, choices=(2, 3), help="map dimension d")
    solver: str = param("coembed", choices=("coembed", "isomap", "pcamd"), help="mapper")
    alpha: float = param(1000.0, min=0.0, min_exclusive=True, help="landmark weight in the co-embedding cost")
    beta: float = param(1.0, min=0.0, help="path smoothness weight")
    poses: str | None = param(None, path=True, help="CSV t,x,y[,heading]: known poses (labels) and path truth")
    pose_label_every: int = param(0, min=0, help="steps t with t % k == 0 are labelled poses (0: no path)")
    isomap_neighbors: int = param(8, min=1, help="Isomap neighbours")
    isomap_min_common: int = param(1, min=1, help="steps two features must share to have a distance")
    pcamd_rank: int = param(3, min=1, help="PCAMD factor rank")
    pcamd_max_iter: int = param(200, min=1, help="PCAMD iterations at most")
    pcamd_tol: float = param(1e-6, min=0.0, help="PCAMD stops when the relative cost decrease falls below this")
    truth: str | None = param(None, path=True, help="CSV feature,x,y[,z][,...]: true positions for evaluate")
