"""Known answers for the UMap geometry: projection, near-plane clipping, hidden lines, model files, grids."""

from __future__ import annotations

import math

import numpy as np
import pytest

from placeloc.geometry import Camera, equirect_to_pinhole, pose_grid, project_segments
from placeloc.geometry.floorplan import ModelError, floor_plan_model, load_model
from placeloc.umap.bits import unpack
from placeloc.umap.render import render_packed

CAM = Camera(160, 120, 90.0)  # f = 80 px, principal point (79.5, 59.5)


def test_projection_by_hand():
    # A point 2 m ahead, 1 m to the left, 0.5 m up, camera at the origin looking along +x.
    uv, keep = project_segments(np.array([[2.0, 1.0, 0.5]]), np.array([[4.0, 0.0, 0.0]]), (0, 0, 0, 0), CAM)
    assert keep.tolist() == [0]
    assert uv[0] == pytest.approx([79.5 - 80 * 0.5, 59.5 - 80 * 0.25, 79.5, 59.5])
    # heading 90: the camera looks along +y; a point on +y is centred, +x is to the right.
    uv, _ = project_segments(np.array([[0.0, 2.0, 0.0]]), np.array([[1.0, 2.0, 0.0]]), (0, 0, 0, 90), CAM)
    assert uv[0] == pytest.approx([79.5, 59.5, 79.5 + 40.0, 59.5])


def test_segment_crossing_the_camera_plane_is_clipped_at_near():
    # From 1 m behind to 3 m in front, 1 m to the right: the behind part is cut at Z = 0.5.
    uv, keep = project_segments(np.array([[-1.0, -1.0, 0.0]]), np.array([[3.0, -1.0, 0.0]]), (0, 0, 0, 0), CAM, near=0.5)
    assert keep.tolist() == [0]
    assert uv[0] == pytest.approx([79.5 + 80 * 1 / 0.5, 59.5, 79.5 + 80 / 3, 59.5])
    # wholly behind the camera: dropped
    _, keep = project_segments(np.array([[-1.0, 0, 0]]), np.array([[-3.0, 0, 0]]), (0, 0, 0, 0), CAM)
    assert keep.size == 0


def test_renderer_matches_projection_and_clips_behind():
    seg = np.array([[2.0, -1.0, 0.5, 2.0, 1.0, 0.5],      # horizontal line 2 m ahead, 0.5 m up -> row 59.5 - 20
                    [-1.0, -1.0, 0.0, 3.0, -1.0, 0.0]])   # crosses the camera plane
    img = unpack(render_packed(seg, np.zeros((0, 6)), np.array([[0, 0, 0, 0.0]]), CAM, near=0.5), 120, 160)[0]
    rows, cols = np.nonzero(img)
    top = rows < 50
    assert set(rows[top]) <= {39, 40}
    assert cols[top].min() == 40 and cols[top].max() == 120  # u = 79.5 -+ 40, rounded half up
    # the clipped segment runs from u = 239.5 (outside) to 106.2 on row 59.5
    mid = rows >= 50
    assert set(rows[mid]) <= {59, 60} and cols[mid].min() in (106, 107) and cols[mid].max() == 159


def test_hidden_line_removal_in_a_box_room():
    # 4 x 4 m room with a 1 x 1 m pillar in the middle; the camera at (0.5, 2) looks along +x.
    plan = {"floor_z": 0.0, "ceiling_z": 2.5, "outline": [[0, 0], [4, 0], [4, 4], [0, 4]],
            "obstacles": [[[1.5, 1.5], [2.5, 1.5], [2.5, 2.5], [1.5, 2.5]]]}
    m = floor_plan_model(plan)
    assert len(m.faces) == 8 and len(m.segments) == 24
    pose = np.array([[0.5, 2.0, 1.2, 0.0]])
    # The far wall's vertical corner line through (4, 2) does not exist; use a probe: a vertical
    # segment on the far wall at y = 2 (behind the pillar) and one at y = 3.9 (its ray passes the pillar at y = 2.54).
    probe = np.array([[4.0, 2.0, 0.2, 4.0, 2.0, 2.3], [4.0, 3.9, 0.2, 4.0, 3.9, 2.3]])
    faces = m.faces
    vis = unpack(render_packed(probe, faces, pose, CAM), 120, 160)[0]
    u_hidden = round(79.5 + 80 * 0.0 / 3.5)
    u_vis = round(79.5 - 80 * 1.9 / 3.5)
    assert vis[:, u_hidden - 1:u_hidden + 2].sum() == 0            # behind the pillar: not drawn
    assert vis[:, u_vis - 1:u_vis + 2].sum() >= 30                  # beside it: drawn
    no_hl = unpack(render_packed(probe, faces, pose, CAM, hidden=False), 120, 160)[0]
    assert no_hl[:, u_hidden - 1:u_hidden + 2].sum() >= 30
    # the pillar's own front edges stay visible (points on a face are not hidden by it)
    full = unpack(render_packed(m.segments, faces, pose, CAM), 120, 160)[0]
    u_corner = round(79.5 - 80 * 0.5 / 1.0)  # pillar corner (1.5, 2.5) is 1 m ahead, 0.5 m left
    assert full[:, u_corner - 1:u_corner + 2].sum() >= 30


def test_floor_plan_doors_and_inside():
    plan = {"ceiling_z": 2.6, "outline": [[0, 0], [10, 0], [10, 2], [0, 2]],
            "doors": [{"from": [3, 0], "to": [4, 0], "height": 2.0}]}
    m = floor_plan_model(plan)
    assert len(m.segments) == 4 * 3 + 3
    assert [3, 0, 2.0, 4, 0, 2.0] in m.segments.tolist()
    assert m.inside(np.array([[5, 1], [5, 3], [-1, 1]])).tolist() == [True, False, False]


def test_model_files(tmp_path):
    (tmp_path / "w.yaml").write_text("segments:\n  - [0, 0, 0, 1, 0, 0]\nfaces:\n  - [0, 1, 1, 1, 0, 2]\n")
    m = load_model(tmp_path / "w.yaml")
    assert m.segments.shape == (1, 6) and m.faces.shape == (1, 6)
    (tmp_path / "w.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nl 1 2 3\n")
    assert load_model(tmp_path / "w.obj").segments.tolist() == [[0, 0, 0, 1, 0, 0], [1, 0, 0, 1, 1, 0]]
    (tmp_path / "bad.yaml").write_text("segments:\n  - [0, 0, 0, 1, 0]\n")
    with pytest.raises(ModelError, match=r"bad.yaml: segments\[0\].*malformed"):
        load_model(tmp_path / "bad.yaml")
    (tmp_path / "bad.obj").write_text("v 0 0 0\nl 1 5\n")
    with pytest.raises(ModelError, match=r"bad.obj:2"):
        load_model(tmp_path / "bad.obj")
    (tmp_path / "bad.json").write_text('{"segments": [[0, 0, 0, 1, 0, "x"]]}')
    with pytest.raises(ModelError, match="malformed"):
        load_model(tmp_path / "bad.json")


def test_pose_grid_counts_and_empty():
    g = pose_grid([0.0, 1.0, 0.5], [0.0, 0.2, 0.2], 1.14, [45.0, 135.0])
    assert g.shape == (3 * 2 * 2, 4)
    assert g[:, 0].tolist()[:4] == [0.0, 0.0, 0.0, 0.0] and set(g[:, 3]) == {45.0, 135.0}
    with pytest.raises(ValueError, match="empty"):
        pose_grid([1.0, 0.0, 0.1], [0, 1, 0.2], 1.0, [0.0])
    with pytest.raises(ValueError, match="headings"):
        pose_grid([0.0, 1.0, 0.1], [0, 1, 0.2], 1.0, [])


def test_equirect_cut_looks_the_right_way():
    # A panorama whose brightness encodes azimuth: column c has azimuth 180 - 360 (c + 0.5) / W.
    w, h = 720, 360
    az = 180.0 - 360.0 * (np.arange(w) + 0.5) / w
    pano = np.tile(((az + 180.0) / 360.0 * 250).astype(np.float32), (h, 1))
    for heading in (0.0, 90.0, -45.0):
        view = equirect_to_pinhole(pano, heading, Camera(64, 48, 60.0))
        centre = view[24, 31:33].mean() / 250 * 360 - 180
        assert math.isclose(centre, heading, abs_tol=1.0)
        # to the right of the centre lies a smaller azimuth (azimuth grows counter-clockwise)
        assert view[24, 50] < view[24, 10]


def test_pinhole_views_from_kept_maps_equal_views_from_fresh_ones():
    # equirect_to_pinhole keeps its sampling maps per panorama size, heading, pitch and camera:
    # interleaved sizes, headings and cameras give what maps built afresh for each call give
    import placeloc.geometry as geometry

    rng = np.random.default_rng(3)
    panos = [rng.integers(0, 256, (64, 128), dtype=np.uint8), rng.integers(0, 256, (96, 192), dtype=np.uint8)]
    calls = [(p, hd, cam, pitch) for p in panos for hd in (0.0, 37.5) for cam in (Camera(32, 24, 60.0), Camera(40, 40, 90.0))
             for pitch in (0.0, -90.0)]
    fresh = []
    for p, hd, cam, pitch in calls:
        geometry._MAPS.clear()
        fresh.append(equirect_to_pinhole(p, hd, cam, pitch))
    kept = [equirect_to_pinhole(p, hd, cam, pitch) for p, hd, cam, pitch in calls + calls[::-1]]
    assert all(np.array_equal(a, b) for a, b in zip(fresh + fresh[::-1], kept))
    assert len({a.tobytes() for a in fresh}) == len(calls)   # every call's view is its own
    map_x, _ = geometry._pinhole_maps(64, 128, 0.0, Camera(32, 24, 60.0), 0.0)
    assert not map_x.flags.writeable
    # kept within their budget: the oldest go first, the newest stays
    budget = geometry.PINHOLE_MAPS_BYTES
    try:
        geometry.PINHOLE_MAPS_BYTES = 3 * 2 * 32 * 24 * 4
        for hd in range(10):
            equirect_to_pinhole(panos[0], float(hd), Camera(32, 24, 60.0))
        assert [k[2] for k in geometry._MAPS] == [7.0, 8.0, 9.0]
    finally:
        geometry.PINHOLE_MAPS_BYTES = budget


def _face_line_image_by_segment(segs, cam, hd, pitch, width, height, bins):
    """The reference: one segment at a time, as the query's line image was drawn before."""
    import math

    from placeloc.geometry.panorama import _face_rays, orientation_bits

    img = np.zeros((height, width), np.uint8)
    for x0, y0, x1, y1 in segs:
        n = int(math.ceil(2.0 * math.hypot(x1 - x0, y1 - y0))) + 1
        t = np.linspace(0.0, 1.0, n)
        az, el = _face_rays(x0 + t * (x1 - x0), y0 + t * (y1 - y0), cam, hd, pitch)
        fu = ((math.pi - az) / (2 * math.pi) % 1.0) * width
        fv = (math.pi / 2 - el) / math.pi * height
        u = np.floor(fu).astype(np.int64) % width
        v = np.clip(np.floor(fv).astype(np.int64), 0, height - 1)
        if bins >= 1:
            du = np.gradient(np.unwrap(fu, period=width)) if n > 1 else np.zeros(1)
            dv = np.gradient(fv) if n > 1 else np.zeros(1)
            np.bitwise_or.at(img, (v, u), orientation_bits(du, dv, bins))
        else:
            img[v, u] = 1
    return img


def test_face_samples_all_at_once_equal_one_segment_at_a_time():
    # random segments on every cube face, the back face's (heading 180) crossing the
    # panorama's seam, short ones (one to three samples) among them: the same pixels and
    # orientation bits as the loop over segments
    from placeloc.geometry.panorama import CUBE_FACES, face_samples, orientation_bits

    rng = np.random.default_rng(5)
    cam = Camera(256, 256, 90.0)
    for hd, pitch in CUBE_FACES:
        segs = rng.uniform(0, 255, (60, 4))
        segs[:5, 2:] = segs[:5, :2] + rng.uniform(-0.6, 0.6, (5, 2))    # one to three samples
        segs[5:10] = [[20, 128, 240, 130], [128, 10, 128, 250], [0, 0, 255, 255], [127.5, 0, 127.5, 255], [255, 0, 0, 255]]
        for bins in (6, 0):
            want = _face_line_image_by_segment(segs, cam, hd, pitch, 144, 72, bins)
            v, u, du, dv, seg = face_samples(segs, cam, hd, pitch, 144, 72)
            assert np.array_equal(np.bincount(seg, minlength=len(segs)), [int(np.ceil(2 * np.hypot(*(s[2:] - s[:2])))) + 1 for s in segs])
            got = np.zeros((72, 144), np.uint8)
            if bins:
                np.bitwise_or.at(got, (v, u), orientation_bits(du, dv, bins))
            else:
                got[v, u] = 1
            assert np.array_equal(got, want), (hd, pitch, bins)


def test_rooms_at_names_the_room_of_each_point():
    from placeloc.geometry.floorplan import floor_plan_model, rooms_at

    plan = {"floor_z": 0.0, "ceiling_z": 2.5,
            "rooms": [{"name": "kitchen", "polygon": [[0, 0], [4, 0], [4, 3], [0, 3]]},
                      {"polygon": [[4, 0], [7, 0], [7, 3], [4, 3]]}]}
    m = floor_plan_model(plan)
    assert m.room_names == ["kitchen", "room 1"]   # a room without a name is named by its place in the list
    pts = np.array([[1.0, 1.0], [5.5, 2.0], [9.0, 1.0], [np.nan, 1.0]])
    assert rooms_at(pts, m.polygons, m.room_names) == ["kitchen", "room 1", "", ""]
