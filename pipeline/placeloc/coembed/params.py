"""Co-embedding parameters: the one home of their defaults, ranges and meaning."""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.core.params import Params, param


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
    landmark_count: int = param(0, min=0, help="0: every landmark row (or landmark_ids); n: choose n of them by farthest-point "
                                               "sampling on the known positions, starting from the most-seen")
    intrinsics: str | None = param(None, path=True, help="CSV f,cx,cy[,k1,k2,k3,p1,p2]: undistort and use normalised image "
                                                         "coordinates (needs image_values xy or two-value CSV sightings)")
    camera_model: str = param("linear", choices=("linear", "perspective", "pinhole"),
                              help="linear: the paper's model on the sightings as given; perspective: on depth-scaled "
                                   "directions (needs intrinsics), depths re-estimated in turn; pinhole: each step's map "
                                   "held to a calibrated camera pose (needs intrinsics, dim 3), fitted by reprojection error")
    perspective_iterations: int = param(5, min=0, help="depth re-estimation rounds for camera_model perspective")
    pinhole_prior: float = param(1e-6, min=0.0, help="camera_model pinhole: weight (relative to the point's best-determined "
                                                     "direction) pulling points with nearly parallel rays toward the linear map")
    pinhole_max_iter: int = param(100, min=0, help="camera_model pinhole: Levenberg-Marquardt iterations at most")
    pinhole_tol: float = param(1e-10, min=0.0, help="camera_model pinhole: stop when the relative cost decrease falls below this")
    dim: int = param(2, choices=(2, 3), help="map dimension d")
    solver: str = param("coembed", choices=("coembed", "isomap", "pcamd"), help="mapper")
    alpha: float = param(1000.0, min=0.0, min_exclusive=True, help="landmark weight in the co-embedding cost (alpha_select fixed)")
    alpha_select: str = param("loo", choices=("fixed", "loo"),
                              help="fixed: use alpha; loo: the alpha_grid value with the smallest leave-one-landmark-out error")
    alpha_grid: tuple[float, ...] = param([0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0, 3000.0, 10000.0],
                                          min=0.0, min_len=1, help="alpha candidates for alpha_select loo")
    beta: float = param(1.0, min=0.0, help="path smoothness weight")
    poses: str | None = param(None, path=True, help="CSV t,x,y[,heading]: known poses (labels) and path truth")
    pose_label_every: int = param(0, min=0, help="steps t with t % k == 0 are labelled poses (0: no path)")
    isomap_neighbors: int = param(8, min=1, help="Isomap neighbours (isomap_neighbors_select fixed)")
    isomap_neighbors_select: str = param("loo", choices=("fixed", "loo"),
                                         help="fixed: use isomap_neighbors; loo: the grid value with the smallest "
                                              "leave-one-landmark-out alignment error")
    isomap_neighbors_grid: tuple[int, ...] = param([3, 4, 5, 6, 8, 10, 12, 15, 20], min=1, min_len=1,
                                                   help="neighbour counts tried by isomap_neighbors_select loo")
    isomap_min_common: int = param(1, min=1, help="steps two features must share to have a distance")
    pcamd_rank: int = param(3, min=1, help="PCAMD factor rank: fixed by the sensor model (scalar sightings of a 2-D map: 3; "
                                          "image points of a 3-D map under an affine camera: 4)")
    pcamd_max_iter: int = param(200, min=1, help="PCAMD iterations at most")
    pcamd_tol: float = param(1e-6, min=0.0, help="PCAMD stops when the relative cost decrease falls below this")
    truth: str | None = param(None, path=True, help="CSV feature,x,y[,z][,...]: true positions for evaluate")
