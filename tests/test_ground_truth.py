"""Ground truth in the forms users hold, each with a known answer, and the mistakes that
must fail before any stage runs."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from placeloc.core.config import ConfigError, load_config
from placeloc.evaluation.ground_truth import GroundTruth, GroundTruthError
from placeloc.evaluation.poses import latlon_to_utm, positions_from_names, read_poses, utm_zone_number

ROOT = Path(__file__).resolve().parent.parent
ROUTE = ROOT / "data-samples" / "route"
STEP = 6.0  # the route's reference step (pixels along the street, read here as metres)


def _route_ranges() -> GroundTruth:
    return GroundTruth.from_csv(ROUTE / "ground_truth.csv", 80, 81)


def _route_positions() -> tuple[np.ndarray, np.ndarray]:
    ref = read_poses_1d(ROUTE / "poses_reference.csv")
    query = read_poses_1d(ROUTE / "poses_query.csv")
    return ref, query


def read_poses_1d(path: Path) -> np.ndarray:
    with path.open() as fh:
        return np.array([float(r["position_px"]) for r in csv.DictReader(fh)])


def _dense(gt: GroundTruth) -> np.ndarray:
    return gt.block(0, gt.n_ref, 0, gt.n_query)


# ------------------------------------------------------------------ regressions
def test_every_listed_positive_counts(tmp_path):
    """A pairs file with several rows per query kept only the last row; all must count."""
    p = tmp_path / "pairs.csv"
    p.write_text("query,reference\n0,1\n0,5\n0,9\n1,4\n")
    gt = GroundTruth.from_csv(p, 10, 3)
    assert gt.correct(np.zeros(5, int), np.array([1, 5, 9, 3, -1])).tolist() == [True, True, True, False, False]
    assert gt.correct(np.array([1, 1]), np.array([4, 5])).tolist() == [True, False]
    assert gt.has_match().tolist() == [True, True, False]
    # with tolerance 1 each listed reference grows a band, and bands of one query merge
    gt = GroundTruth.from_csv(p, 10, 3, tolerance=1)
    assert np.flatnonzero(_dense(gt)[:, 0]).tolist() == [0, 1, 2, 4, 5, 6, 8, 9]


@pytest.mark.parametrize("text, match", [
    ("query,reference\n0,1\n7,2\n", r"pairs.csv:3: query index 7 is outside the query traverse \(0..2\)"),
    ("query,reference\n0,1\n1,12\n", r"pairs.csv:3: reference index 12 is outside the reference traverse \(0..9\)"),
    ("query,ref_first,ref_last\n0,11,14\n", r"pairs.csv:2: range 11..14 lies outside the reference traverse"),
    ("query,ref_first,ref_last\n0,5,2\n", "ref_first 5 > ref_last 2"),
    ("query,reference\n0,nosuch.png\n", r"pairs.csv:2: reference 'nosuch.png' is not an index"),
    ("q,r\n0,1\n", "header must be 'query,reference'"),
    ("query;reference\n0;1\n", r"got \['query;reference'\] \(this file separates its columns by semicolons: save it "
                                 r"comma-separated\)"),
    ("query\treference\n0\t1\n", "separates its columns by tabs"),
    ("query,reference,soft\n0,1,maybe\n", "soft is 'maybe'"),
])
def test_bad_csv_names_file_row_and_fix(tmp_path, text, match):
    p = tmp_path / "pairs.csv"
    p.write_text(text)
    with pytest.raises(GroundTruthError, match=match):
        GroundTruth.from_csv(p, 10, 3)


def test_matrix_must_be_boolean_or_0_1(tmp_path):
    m = np.zeros((4, 3), bool)
    m[2, 1] = m[0, 0] = True
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f["gt"] = m.astype(np.float64) * 0.7  # scores, not booleans: used to be cast to True silently
    with pytest.raises(GroundTruthError, match="holds float64 values; store a boolean"):
        GroundTruth.from_hdf5(tmp_path / "f.h5", 4, 3)
    with h5py.File(tmp_path / "i.h5", "w") as f:
        f["gt"] = m.astype(np.uint8)
    assert np.array_equal(_dense(GroundTruth.from_hdf5(tmp_path / "i.h5", 4, 3)), m)
    with h5py.File(tmp_path / "two.h5", "w") as f:
        f["gt"] = m.astype(np.int32) * 2
    with pytest.raises(GroundTruthError, match=r"value 2 at \(reference 0, query 0\)"):
        GroundTruth.from_hdf5(tmp_path / "two.h5", 4, 3)
    with pytest.raises(GroundTruthError, match="transposed"):
        GroundTruth.from_hdf5(tmp_path / "i.h5", 3, 4)


def test_negative_tolerance_and_radius_fail_at_config_time(route):
    with pytest.raises(ConfigError, match="ground_truth.tolerance: -3 is out of range; it must be >= 0"):
        load_config(route / "config.yaml", ["ground_truth.tolerance=-3"])
    with pytest.raises(ConfigError, match="ground_truth.radius: -1.0 is out of range"):
        load_config(route / "config.yaml", ["ground_truth.kind=poses", "ground_truth.radius=-1"])


def test_bad_ground_truth_fails_before_any_stage_with_one_line(route, tmp_path):
    import subprocess
    import sys

    (route / "bad.csv").write_text("query,reference\n0,0\n1,1\n500,3\n")
    with pytest.raises(GroundTruthError, match=r"bad.csv:4: query index 500 is outside the query traverse \(0..80\)"):
        load_config(route / "config.yaml", ["ground_truth.path=bad.csv"])
    run = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "placeloc.cli", "run", str(route / "config.yaml"), "-o", str(run), "-q",
                          "--set", "ground_truth.path=bad.csv"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "bad.csv:4" in lines[0] and "outside the query traverse" in lines[0], res.stderr
    assert not list(run.glob("*.h5"))  # nothing ran


# ------------------------------------------------------------------ forms
def test_pairs_and_ranges_by_file_name_equal_by_index(tmp_path):
    ranges = _route_ranges()
    dense = _dense(ranges)
    ref_names = [f"frame{i}.png" for i in range(80)]
    q_names = [f"frame{j}.png" for j in range(81)]
    pairs = tmp_path / "pairs.csv"
    with pairs.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "reference"])
        for r, q in np.argwhere(dense):
            w.writerow([q_names[q], ref_names[r]])
    gt = GroundTruth.from_csv(pairs, 80, 81, ref_names=ref_names, query_names=q_names)
    assert np.array_equal(_dense(gt), dense)
    by_name_ranges = tmp_path / "ranges.csv"
    lines = (ROUTE / "ground_truth.csv").read_text().splitlines()
    out = [lines[0]] + [f"frame{q}.png,frame{a}.png,frame{b}.png" for q, a, b in (ln.split(",") for ln in lines[1:])]
    by_name_ranges.write_text("\n".join(out) + "\n")
    gt = GroundTruth.from_csv(by_name_ranges, 80, 81, ref_names=ref_names, query_names=q_names)
    assert np.array_equal(_dense(gt), dense)


def test_positions_within_radius_equal_the_route_ranges(tmp_path):
    """The route's ranges are 'within 2 reference steps'; positions with radius 2 steps agree."""
    ref_x, q_x = _route_positions()
    p = tmp_path / "positions.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["traverse", "image", "x", "y"])
        w.writerows([["reference", f"frame{i}.png", x, 0.0] for i, x in enumerate(ref_x)])
        w.writerows([["query", f"frame{j}.png", x, 0.0] for j, x in enumerate(q_x)])
    names_r, names_q = [f"frame{i}.png" for i in range(80)], [f"frame{j}.png" for j in range(81)]
    gt = GroundTruth.from_config({"kind": "poses", "path": str(p), "radius": 2 * STEP}, 80, 81,
                                 ref_names=names_r, query_names=names_q)
    assert gt.form == "positions"
    assert np.array_equal(_dense(gt), _dense(_route_ranges()))
    # the default radius is 25 m (VPR-Bench, VPR-methods-evaluation)
    gt25 = GroundTruth.from_config({"kind": "poses", "path": str(p)}, 80, 81, ref_names=names_r, query_names=names_q)
    assert gt25.radius == 25.0 and gt25.correct(np.array([40]), np.array([44])).item() == (abs(ref_x[44] - q_x[40]) <= 25)


def test_utm_against_published_coordinates():
    # GeographicLib's GeoConvert manual: 33.3 44.4 -> 38n 444140.54 3684706.36
    e, n = latlon_to_utm(33.3, 44.4, zone=utm_zone_number(33.3, 44.4), north=True)
    assert utm_zone_number(33.3, 44.4) == 38
    assert float(e) == pytest.approx(444140.54, abs=0.01) and float(n) == pytest.approx(3684706.36, abs=0.01)
    # AGI STK Connect manual: 33.5 74.75 -> 43S 476779 3706747 (metres)
    e, n = latlon_to_utm(33.5, 74.75, zone=43, north=True)
    assert round(float(e)) == 476779 and round(float(n)) == 3706747
    # southern hemisphere: false northing 10,000 km; Norway's zone 32 exception
    _, n_s = latlon_to_utm(-33.3, 44.4, zone=38, north=False)
    assert float(n_s) == pytest.approx(10_000_000 - 3684706.36, abs=0.01)
    assert utm_zone_number(60.0, 5.0) == 32


def test_latlon_positions_are_projected_to_metres(tmp_path):
    """A route laid north along a meridian in lat/lon: projected, its spacing is metres again."""
    ref_x, q_x = _route_positions()
    lat0, lon0 = 59.3, 18.0  # Stockholm, UTM zone 34 (central meridian 21 E)
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    rho = a * (1 - e2) / (1 - e2 * math.sin(math.radians(lat0)) ** 2) ** 1.5  # metres per radian of latitude
    p = tmp_path / "gps.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["traverse", "image", "latitude", "longitude"])
        for role, xs in (("reference", ref_x), ("query", q_x)):
            w.writerows([[role, f"frame{i}.png", f"{lat0 + math.degrees(x / rho):.10f}", lon0] for i, x in enumerate(xs)])
    poses = read_poses(p)
    assert poses.utm_zone == "34N"
    rows = poses.rows_for_names([f"frame{i}.png" for i in range(80)], traverse="reference")
    xy = poses.xy[rows]
    along = np.hypot(*(xy - xy[0]).T)
    # UTM scale factor at 3 degrees from the central meridian is ~0.9996 * 1.0007; distances stay within 0.1 %
    np.testing.assert_allclose(along[1:], ref_x[1:], rtol=1e-3)
    gt = GroundTruth.from_config({"kind": "poses", "path": str(p), "radius": 2 * STEP + 0.05}, 80, 81,
                                 ref_names=[f"frame{i}.png" for i in range(80)],
                                 query_names=[f"frame{j}.png" for j in range(81)])
    d = np.abs(ref_x[:, None] - q_x[None, :])
    clear = np.abs(d - (2 * STEP + 0.05)) > 0.05  # away from the radius, where a 0.1 % scale cannot flip an answer
    assert np.array_equal(_dense(gt)[clear], (d <= 2 * STEP + 0.05)[clear])


def test_positions_from_at_utm_file_names(tmp_path):
    names = ["@0543256.96@4178906.42@10@S@037.75643@-122.50943@.jpg", "@0543300.00@4178906.42@x@.jpg",
             "@0543256.96@4178990.00@.jpg"]
    xy = positions_from_names(names)
    np.testing.assert_allclose(xy[0], [543256.96, 4178906.42])
    folder = tmp_path / "db"
    folder.mkdir()
    gt = GroundTruth.from_positions(folder, 3, 2, radius=25.0, ref_names=names,
                                    query_names=["@0543260.00@4178910.00@.jpg", "@0543290.00@4178970.00@.jpg"])
    assert _dense(gt).tolist() == [[True, False], [False, False], [False, False]]
    assert gt.example_positive().tolist() == [0, -1]
    from placeloc.evaluation.poses import PoseError

    with pytest.raises(PoseError, match="does not start with @UTM_east@UTM_north@"):
        positions_from_names(["frame1.png"])


def test_pose_file_problems_name_the_fix(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("frame,x,y\n0,0,0\n1,1,0\n")
    with pytest.raises(GroundTruthError, match="add a traverse column"):
        GroundTruth.from_positions(p, 2, 2, radius=5.0, ref_names=["a.png", "b.png"], query_names=["c.png", "d.png"])
    p.write_text("image,x,y\na.png,0,0\nb.png,1,0\nc.png,5,0\n")
    with pytest.raises(GroundTruthError, match=r"no pose for 1 of 2 query images \(first: d.png\)"):
        GroundTruth.from_positions(p, 2, 2, radius=5.0, ref_names=["a.png", "b.png"], query_names=["c.png", "d.png"])
    p.write_text("traverse,image,lat,lon\nreference,a.png,95,10\n")
    with pytest.raises(Exception, match="outside the UTM grid"):
        read_poses(p)


def test_soft_ground_truth_from_csv_and_npz(tmp_path):
    p = tmp_path / "soft.csv"
    p.write_text("query,reference,soft\n0,2,0\n0,3,1\n1,5,\n1,4,yes\n")
    gt = GroundTruth.from_csv(p, 10, 3)
    q = np.array([0, 0, 1, 1, 2])
    r = np.array([2, 3, 5, 4, 4])
    assert gt.correct(q, r).tolist() == [True, False, True, False, False]
    assert gt.soft_only(q, r).tolist() == [False, True, False, True, False]
    hard = _dense(gt)
    soft = hard.copy()
    soft[3, 0] = soft[4, 1] = True
    np.savez(tmp_path / "gt.npz", GThard=hard, GTsoft=soft)
    g2 = GroundTruth.from_hdf5(tmp_path / "gt.npz", 10, 3)
    assert g2.soft_only(q, r).tolist() == gt.soft_only(q, r).tolist()


def test_loop_closure_pairs_by_name(tmp_path):
    """No query folder: query names are the reference names."""
    p = tmp_path / "lc.csv"
    p.write_text("query,reference\nf5.png,f1.png\nf6.png,f2.png\n")
    names = [f"f{i}.png" for i in range(8)]
    gt = GroundTruth.from_config({"kind": "csv", "path": str(p), "tolerance": 0}, 8, 8, ref_names=names)
    assert gt.correct(np.array([5, 6, 6]), np.array([1, 2, 1])).tolist() == [True, True, False]


def test_a_pairs_csv_is_exact_unless_a_tolerance_is_set(route, tmp_path):
    """The config's default tolerance is the ground truth's (0): a pair marks one reference."""
    pairs = tmp_path / "pairs.csv"
    pairs.write_text("query,reference\n3,3\n10,12\n")
    cfg = load_config(route / "config.yaml", ["ground_truth.kind=csv", f"ground_truth.path={pairs}"])
    assert cfg["ground_truth"]["tolerance"] == 0
    n_ref, n_query = 80, 81
    exact = GroundTruth.from_config(cfg["ground_truth"], n_ref, n_query)
    assert np.flatnonzero(_dense(exact)[:, 10]).tolist() == [12]
    assert np.flatnonzero(_dense(exact)[:, 3]).tolist() == [3]
    cfg = load_config(route / "config.yaml", ["ground_truth.kind=csv", f"ground_truth.path={pairs}",
                                              "ground_truth.tolerance=2"])
    banded = GroundTruth.from_config(cfg["ground_truth"], n_ref, n_query)
    assert np.flatnonzero(_dense(banded)[:, 10]).tolist() == [10, 11, 12, 13, 14]


def test_shared_settings_have_one_home():
    """Config defaults, the ground truth's and the metrics' defaults all come from CommonParams."""
    from placeloc.core import params as P
    from placeloc.core.common_params import CommonParams, GroundTruthParams
    from placeloc.evaluation import ground_truth, metrics

    gt = P.defaults(CommonParams)["ground_truth"]
    assert gt == {"kind": "none", "tolerance": 0, "path": None, "radius": 25.0, "recall_at": [1, 5, 10, 20],
                  "exclude_recent": None}
    assert ground_truth.DEFAULT_RADIUS_M == GroundTruthParams().radius
    assert ground_truth.DEFAULT_TOLERANCE == GroundTruthParams().tolerance
    assert list(metrics.DEFAULT_RECALL_N) == gt["recall_at"]
    # a section without a tolerance scores like the validated config's default
    assert GroundTruth.from_config({"kind": "synchronous"}, 5, 5).tolerance == gt["tolerance"]


def test_headings_in_degrees_under_a_radians_name_are_warned_about(tmp_path, caplog):
    """`heading` and `yaw` are radians; a column of them reaching 350 is degrees (read as
    radians, every yaw error would be noise): the reader says which name to use."""
    import logging

    p = tmp_path / "poses.csv"
    p.write_text("image,x,y,yaw\nframe0.png,0,0,10\nframe1.png,1,0,350\n")
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        read_poses(p)
    assert [r.getMessage() for r in caplog.records] == [
        f"poses: {p}: the yaw column is read in radians, but its values reach 350, more than a turn: if they are "
        "degrees, name the column yaw_deg"]
    caplog.clear()
    p.write_text("image,x,y,yaw\nframe0.png,0,0,0.1\nframe1.png,1,0,-3.1\n")
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        poses = read_poses(p)
    assert caplog.records == [] and poses.heading[1] == -3.1
