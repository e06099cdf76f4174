"""The equirectangular map renderer (placeloc.geometry.panorama.render_panoramas) against a
slow per-sample reference of its drawing rules, cases checked by hand, and the shortcuts it
takes (certified pixel tests, the hidden-line test with per-pose face terms) against the
plain computations they stand for."""

from __future__ import annotations

import math

import numpy as np
import pytest

from placeloc.geometry.floorplan import floor_plan_model
from placeloc.geometry.panorama import (
    EDGE_HEAD_MAX,
    _col_certified,
    _col_of,
    _row_certified,
    _row_of,
    orientation_bit,
    render_panoramas,
)
from placeloc.geometry.rays import face_terms, occluded, occluded_terms
from placeloc.umap.bits import unpack

# An L-shaped room with a pillar: walls hide parts of one another from most positions.
PLAN = {"floor_z": 0.0, "ceiling_z": 2.6, "outline": [[0, 0], [6, 0], [6, 4], [3.5, 4], [3.5, 7], [0, 7]],
        "obstacles": [[[1.5, 2.0], [2.2, 2.0], [2.2, 2.6], [1.5, 2.6]]]}
W, H = 144, 72


def _reference(segs: np.ndarray, faces: np.ndarray, pose, width: int, height: int, bins: int, hidden: bool) -> np.ndarray:
    """(H, W) uint8 image by the drawing rules, one sample at a time in plain Python: each
    segment sampled at t = i / n (n from its nearest distance: two samples a pixel there),
    each sample's pixel from its azimuth and elevation, its bit from the image direction of
    the segment there (:func:`orientation_bit`, the arctangent form), drawn unless some wall
    face (every face tested, no shortcuts) crosses the plan ray to it strictly before it,
    5 mm clear, at a height inside the face."""
    px, py, pz, hd = (float(x) for x in pose)
    head = math.radians(hd)
    step = 2.0 * math.pi / width
    img = np.zeros(height * width, np.uint8)
    for s in segs:
        ax, ay, az = s[0] - px, s[1] - py, s[2] - pz
        ex, ey, ez = s[3] - s[0], s[4] - s[1], s[5] - s[2]
        ll = math.sqrt(ex * ex + ey * ey + ez * ez)
        if ll < 1e-9:
            continue
        t0 = min(max(-(ax * ex + ay * ey + az * ez) / (ll * ll), 0.0), 1.0)
        cx, cy, cz = ax + t0 * ex, ay + t0 * ey, az + t0 * ez
        dmin = max(math.sqrt(cx * cx + cy * cy + cz * cz), 0.05)
        n = min(int(math.ceil(2.0 * ll / dmin / step)) + 1, 20000)
        for i in range(n + 1):
            t = i / n
            qx, qy, qz = ax + t * ex, ay + t * ey, az + t * ez
            r = math.sqrt(qx * qx + qy * qy)
            fu = ((math.pi - (math.atan2(qy, qx) - head)) / (2.0 * math.pi) % 1.0) * width - 0.5
            u = int(math.floor(fu + 0.5)) % width
            v = int(math.floor((math.pi / 2.0 - math.atan2(qz, r)) / math.pi * height - 0.5 + 0.5))
            pix = min(max(v, 0), height - 1) * width + u
            bit = 1
            if bins > 1:
                rr = max(r, 1e-9)
                du = -width / (2.0 * math.pi) * (qx * ey - qy * ex) / (rr * rr)
                dv = -height / math.pi * (rr * ez - qz * (qx * ex + qy * ey) / rr) / (rr * rr + qz * qz)
                bit = orientation_bit.py_func(du, dv, bins)
            if img[pix] & bit:
                continue
            if hidden and _hidden_by_any(px, py, pz, px + qx, py + qy, pz + qz, faces):
                continue
            img[pix] |= bit
    return img.reshape(height, width)


def _hidden_by_any(px, py, pz, qx, qy, qz, faces) -> bool:  # noqa: ANN001
    dx, dy = qx - px, qy - py
    length = math.sqrt(dx * dx + dy * dy)
    if length < 1e-9:
        return False
    tmax = 1.0 - 0.005 / length
    for x0, y0, x1, y1, z0, z1 in faces:
        ex, ey = x1 - x0, y1 - y0
        den = dx * ey - dy * ex
        if abs(den) < 1e-12:
            continue
        wx, wy = x0 - px, y0 - py
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
        if t <= 1e-9 or t >= tmax or u < 0.0 or u > 1.0:
            continue
        if z0 <= pz + t * (qz - pz) <= z1:
            return True
    return False


def _render(m, poses, bins: int, width: int = W, height: int = H, hidden: bool = True) -> np.ndarray:  # noqa: ANN001
    out = render_panoramas(m.segments, m.faces, np.asarray(poses, float), width=width, height=height, hidden=hidden,
                           orientation_bins=bins)
    return out if bins else unpack(out, height, width)


@pytest.mark.parametrize("bins", [0, 6])
def test_renders_equal_the_per_sample_reference(bins):
    m = floor_plan_model(PLAN)
    rng = np.random.default_rng(7)
    poses = [[4.0, 2.0, 1.5, 0.0], [1.0, 5.5, 1.2, 37.5], [2.9, 3.8, 1.6, 211.0],
             [2.2 + 0.004, 2.3, 1.5, 90.0],      # 4 mm from the pillar's face
             [3.5 - 0.12, 4.0 + 0.12, 1.5, 0.0],  # beside the L's inner corner
             [1.5, 2.3, 1.5, 1e5]]               # beyond EDGE_HEAD_MAX: every pixel by arctangents
    poses += [[*rng.uniform([0.2, 0.2], [3.3, 6.8]), rng.uniform(0.3, 2.4), rng.uniform(0, 360)] for _ in range(3)]
    assert math.radians(1e5) > EDGE_HEAD_MAX
    got = _render(m, poses, bins)
    for pose, img in zip(poses, got):
        ref = _reference(m.segments, m.faces, pose, W, H, bins, hidden=True)
        assert ref.any()
        assert np.array_equal(img if bins else img.astype(np.uint8), ref if bins else (ref > 0).astype(np.uint8)), pose


def test_generated_home_equals_the_reference_with_doors_and_lintels():
    # rooms joined by doors (lintel faces above them), the camera in a doorway and near walls
    from placeloc.synth.home import plan as home_plan

    fp, _ = home_plan(np.random.default_rng(0), 3)
    m = floor_plan_model({**fp, "camera_z": 1.5})
    gap = m.gaps[0]
    mid = (gap[:2] + gap[2:]) / 2.0
    wall = m.faces[3]
    e = (wall[2:4] - wall[:2]) / np.hypot(*(wall[2:4] - wall[:2]))
    near = (wall[:2] + wall[2:4]) / 2.0 + 0.1 * np.array([-e[1], e[0]])
    poses = [[*mid, 1.5, 0.0], [*near, 1.5, 72.5]]
    got = _render(m, poses, 6)
    for pose, img in zip(poses, got):
        assert np.array_equal(img, _reference(m.segments, m.faces, pose, W, H, 6, hidden=True)), pose


def test_a_vertical_corner_lands_in_its_column_with_the_vertical_bit():
    # a lone vertical line 2 m ahead, at azimuth 31.25 deg to the left: column
    # (180 - 31.25) / 360 * 144 - 0.5 = 59; from the floor (elevation atan(-1.5 / d) = -32.7 deg,
    # row 49) to 2.5 m (atan(1 / d) = 23.2 deg, row 26), d = 2 / cos(31.25 deg) = 2.339 m;
    # its image direction is vertical: bin 3 of 6 (90 deg), bit 8
    y = 2.0 * math.tan(math.radians(31.25))
    segs = np.array([[2.0, y, 0.0, 2.0, y, 2.5]])
    img = render_panoramas(segs, np.zeros((0, 6)), np.array([[0.0, 0.0, 1.5, 0.0]]), width=W, height=H,
                           hidden=True, orientation_bins=6)[0]
    rows, cols = np.nonzero(img)
    assert set(cols) == {59}
    assert rows.min() == 26 and rows.max() == 49 and len(rows) == 24
    assert set(img[rows, cols]) == {8}
    # turned 10 columns (25 deg) to the left, the line moves 10 columns to the right
    turned = render_panoramas(segs, np.zeros((0, 6)), np.array([[0.0, 0.0, 1.5, 25.0]]), width=W, height=H,
                              hidden=True, orientation_bins=6)[0]
    assert np.array_equal(turned, np.roll(img, 10, axis=1))


def test_a_line_on_a_column_edge_takes_the_arctangent_path():
    # a vertical line straight to the left (azimuth 90 deg) lies on the edge between columns
    # 35 and 36 (36.0 exactly by the arctangents, which put it in column 36)
    segs = np.array([[0.0, 2.0, 0.0, 0.0, 2.0, 2.5], [1.0, 2.0, 0.2, -1.0, 2.0, 0.2]])
    img = unpack(render_panoramas(segs[:1], np.zeros((0, 6)), np.array([[0.0, 0.0, 1.5, 0.0]]), width=W, height=H,
                                  hidden=False), H, W)[0]
    assert set(np.nonzero(img)[1]) == {36}
    both = render_panoramas(segs, np.zeros((0, 6)), np.array([[0.0, 0.0, 1.5, 0.0]]), width=W, height=H,
                            hidden=False, orientation_bins=6)[0]
    assert np.array_equal(both, _reference(segs, np.zeros((0, 6)), [0.0, 0.0, 1.5, 0.0], W, H, 6, hidden=False))


def test_a_segment_behind_a_wall_face_is_not_drawn():
    wall = np.array([[2.0, -1.0, 2.0, 1.0, 0.0, 2.5]])          # x = 2, y -1..1, floor to 2.5 m
    behind = [3.0, -0.3, 1.0, 3.0, 0.3, 1.0]                    # at 1 m height behind its middle
    beside = [3.0, 1.6, 1.0, 3.0, 2.2, 1.0]                     # behind the plane but past its end
    lintel = np.array([[2.0, -1.0, 2.0, 1.0, 2.0, 2.5]])        # only 2.0-2.5 m: the line is seen below it
    pose = np.array([[0.0, 0.0, 1.5, 0.0]])
    for segs, faces, drawn in (([behind], wall, False), ([beside], wall, True), ([behind], lintel, True),
                               ([behind], np.zeros((0, 6)), True)):
        img = render_panoramas(np.array(segs), faces, pose, width=W, height=H, hidden=True, orientation_bins=6)[0]
        assert img.any() == drawn, (segs, faces)
    # hidden=False draws it through the wall
    assert render_panoramas(np.array([behind]), wall, pose, width=W, height=H, hidden=False, orientation_bins=6).any()


def test_certified_pixels_equal_the_arctangent_path():
    # random directions, and directions exactly on pixel edges, several sizes and headings:
    # a certified column or row is the arctangents' one, and most random ones are certified
    rng = np.random.default_rng(3)
    for width, height in ((144, 72), (96, 48), (512, 256), (10, 5)):
        col_angle = math.pi - 2.0 * math.pi * np.arange(width + 1) / width
        row_angle = math.pi / 2.0 - math.pi * np.arange(height + 1) / height
        row_x, row_y = np.cos(row_angle), np.sin(row_angle)
        for head in (0.0, math.radians(37.5), math.radians(-400.0), 12.34):
            edge_x = np.cos(col_angle) * math.cos(head) - np.sin(col_angle) * math.sin(head)
            edge_y = np.sin(col_angle) * math.cos(head) + np.cos(col_angle) * math.sin(head)
            ang = np.r_[rng.uniform(-np.pi, np.pi, 400), col_angle + head]
            dist = np.r_[rng.uniform(0.01, 30.0, 400), np.full(width + 1, 2.0)]
            certified = 0
            for a, d in zip(ang, dist):
                qx, qy = d * math.cos(a), d * math.sin(a)
                exact = _col_of(qx, qy, head, width)
                r = math.sqrt(qx * qx + qy * qy)
                for start in (exact, (exact + 2) % width, (exact - 3) % width):
                    got = _col_certified(qx, qy, r, start, edge_x, edge_y, width)
                    assert got in (-1, exact)
                    certified += got == exact
            assert certified > 0.9 * 3 * 400
            for el in np.r_[rng.uniform(-np.pi / 2, np.pi / 2, 300), row_angle, [np.pi / 2, -np.pi / 2]]:
                r, qz = 3.0 * math.cos(el), 3.0 * math.sin(el)
                r = abs(r)
                exact = _row_of(qz, r, height)
                for start in (exact, min(exact + 2, height - 1), max(exact - 1, 0)):
                    assert _row_certified(qz, r, start, row_x, row_y, height) in (-1, exact)


def test_occlusion_with_face_terms_equals_the_plain_test():
    # random rays and faces, with degenerate ones: parallel and collinear faces, rays ending
    # on a face, the camera on a face's line, faces of zero length
    rng = np.random.default_rng(5)
    faces = rng.uniform(-5, 5, (40, 6))
    faces[:, 4:] = np.sort(rng.uniform(0, 3, (40, 2)), axis=1)
    faces[0] = [1.0, 0.0, 3.0, 0.0, 0.0, 3.0]     # along the x axis, through the origin's line
    faces[1] = [2.0, -1.0, 2.0, 1.0, 0.0, 3.0]    # across it at x = 2
    faces[2] = [2.0, 2.0, 2.0, 2.0, 0.0, 3.0]     # a point
    every = np.arange(len(faces), dtype=np.int64)
    for trial in range(300):
        p = rng.uniform(-5, 5, 3) if trial % 3 else np.array([0.0, 0.0, 1.5])
        q = rng.uniform(-5, 5, 3)
        if trial % 7 == 0:
            q[:2] = [2.0, rng.uniform(-1, 1)]        # on face 1
        if trial % 11 == 0:
            q[1] = p[1] = 0.0                        # along face 0's line
        terms = np.empty((len(faces), 6))
        face_terms(p[0], p[1], faces, terms)
        for k in range(len(faces)):
            one = every[k:k + 1]
            assert occluded_terms(*p, *q, faces, terms, one, 1) == occluded(*p, *q, faces, one, 1)
        nearest_first = np.argsort(terms[:, 5])
        assert occluded_terms(*p, *q, faces, terms, nearest_first, len(faces)) == occluded(*p, *q, faces, every,
                                                                                           len(every))


def test_nearest_first_scan_stops_only_past_every_hit():
    # the hidden-line test scans the faces nearest first and stops at the first one beyond the
    # point: on a generated home, from cameras all over it and within centimetres of walls, at
    # points along every segment (and on the walls themselves), it answers as the plain test
    # over every face, and the distance bound is a bound
    from placeloc.geometry.floorplan import plan_grid
    from placeloc.synth.home import plan as home_plan

    fp, _ = home_plan(np.random.default_rng(1), 3)
    m = floor_plan_model({**fp, "camera_z": 1.5})
    faces = np.ascontiguousarray(m.faces, np.float64)
    every = np.arange(len(faces), dtype=np.int64)
    rng = np.random.default_rng(2)
    cams = plan_grid(m, step_m=0.8)[0][:, :3]
    f = faces[rng.integers(0, len(faces), 20)]
    along = f[:, :2] + rng.uniform(0, 1, (20, 1)) * (f[:, 2:4] - f[:, :2])
    e = f[:, 2:4] - f[:, :2]
    normal = np.c_[-e[:, 1], e[:, 0]] / np.hypot(*e.T)[:, None]
    cams = np.r_[cams, np.c_[along + rng.choice([-1, 1], (20, 1)) * rng.uniform(0.001, 0.05, (20, 1)) * normal,
                             np.full(20, 1.5)]]
    ts = np.linspace(0.0, 1.0, 9)
    hidden = 0
    for px, py, pz in cams:
        terms = np.empty((len(faces), 6))
        face_terms(px, py, faces, terms)
        order = np.argsort(terms[:, 5])
        for s in np.r_[m.segments, faces[:, [0, 1, 4, 2, 3, 4]]]:
            for q in s[:3] + ts[:, None] * (s[3:] - s[:3]):
                plain = occluded(px, py, pz, *q, faces, every, len(every))
                assert occluded_terms(px, py, pz, *q, faces, terms, order, len(order)) == plain
                hidden += plain
        d = faces[:, :2] - [px, py]
        ends = np.minimum(np.hypot(*d.T), np.hypot(*(faces[:, 2:4] - [px, py]).T))
        used = terms[:, 5] >= 0
        assert (terms[used, 5] <= ends[used] ** 2).all()
    assert hidden > 1000


def test_whole_segment_test_over_the_first_ends_column_equals_every_face():
    # the renderer runs the whole-segment hidden test over the faces listed for the column of
    # the segment's first end; over a generated home's grid and headings it must answer as
    # over every face, and skip segments often enough to matter
    from placeloc.geometry.floorplan import plan_grid
    from placeloc.geometry.panorama import _segment_hidden, _segment_hidden_among, column_faces
    from placeloc.synth.home import plan as home_plan

    fp, _ = home_plan(np.random.default_rng(0), 3)
    m = floor_plan_model({**fp, "camera_z": 1.5})
    faces = np.ascontiguousarray(m.faces, np.float64)
    hidden = 0
    for i, (px, py, pz, _) in enumerate(plan_grid(m, step_m=0.7)[0]):
        head = math.radians(37.5 * i)
        counts = np.zeros(W, np.int64)
        lists = np.empty((W, len(faces)), np.int64)
        column_faces(faces, px, py, head, W, counts, lists, np.arange(len(faces)))
        for s in m.segments:
            a = (s[0] - px, s[1] - py, s[2], s[3] - px, s[4] - py, s[5])
            col = _col_of(a[0], a[1], head, W)
            whole = _segment_hidden(*a, faces, px, py, pz)
            assert _segment_hidden_among(*a, faces, px, py, pz, lists[col], counts[col]) == whole
            hidden += whole
    assert hidden > 500
