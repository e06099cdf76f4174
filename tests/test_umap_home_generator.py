"""Known answers for the synthetic home generator's failure cases: the white bonus room,
kitchen clutter at wall height and cameras close to a wall."""

from __future__ import annotations

import numpy as np
import pytest

from placeloc.geometry.floorplan import blocking_faces, floor_plan_model, wall_distance
from placeloc.geometry.polygons import point_in_polygon
from placeloc.synth.home import cabinet_poses, line_agreement, near_wall_poses, plan, room_name


def _room(fp, name):
    return np.asarray(next(r["polygon"] for r in fp["rooms"] if r["name"] == name), float)


def test_kitchen_clutter_stands_at_wall_height():
    fp, clutter = plan(np.random.default_rng(3))
    kitchen = _room(fp, "kitchen")
    lo, hi = kitchen.min(axis=0), kitchen.max(axis=0)
    boxes = np.asarray(clutter["boxes"] + clutter["flat"], float)
    inside = (boxes[:, 0] >= lo[0] - 1e-6) & (boxes[:, 3] <= hi[0] + 1e-6) & (boxes[:, 1] >= lo[1] - 1e-6) & (boxes[:, 4] <= hi[1] + 1e-6)
    # between the floor line and the ceiling line (1.0-2.2 m): wall cabinets, hood, fridge, shelves, clock
    at_wall_height = inside & (boxes[:, 5] > 1.2) & (boxes[:, 2] < 2.2)
    assert at_wall_height.sum() >= 5


def test_the_bonus_room_is_white_and_has_a_fan():
    from placeloc.synth.home import scene_arrays

    rng = np.random.default_rng(4)
    fp, clutter = plan(rng)
    bonus = _room(fp, "bonus")
    scene = scene_arrays(fp, clutter, rng)
    white = [r["name"] for r, wt in zip(fp["rooms"], scene["rooms_white"]) if wt]
    assert white == ["bonus"]
    fans = np.asarray(clutter["fans"], float)
    centres = (fans[:, :2] + fans[:, 3:5]) / 2
    assert point_in_polygon(centres, bonus).any()
    assert room_name(fp, *bonus.mean(axis=0)) == "bonus"


def test_near_wall_cameras_stand_0_4_to_0_6_m_from_a_wall():
    rng = np.random.default_rng(5)
    fp, clutter = plan(rng)
    xy = near_wall_poses(fp, clutter, rng, 6, 1.5)
    assert len(xy) == 6
    walls = blocking_faces(floor_plan_model(fp).faces, 1.5)
    d = wall_distance(xy, walls)
    assert (d >= 0.4 - 1e-9).all() and (d <= 0.6 + 1e-9).all()
    rooms = [room_name(fp, *p) for p in xy]
    assert rooms == ["kitchen", "bonus"] * 3
    boxes = np.asarray(clutter["boxes"], float)
    for b in boxes:   # clear of the furniture
        assert not ((xy[:, 0] > b[0] - 0.15) & (xy[:, 0] < b[3] + 0.15) & (xy[:, 1] > b[1] - 0.15) & (xy[:, 1] < b[4] + 0.15)).any()


def test_cabinet_cameras_stand_in_front_of_the_counters():
    # 0.15-0.35 m in front of a counter run's front, the runs in turn, in the kitchen, clear of
    # the furniture that stands in front of the run
    fp, clutter = plan(np.random.default_rng(6))
    xy = cabinet_poses(fp, clutter, np.random.default_rng(7), 4, 1.5)
    assert len(xy) == 4 and all(room_name(fp, *p) == "kitchen" for p in xy)
    runs = np.asarray(clutter["counters"], float)
    for i, p in enumerate(xy):
        a, b, n = runs[i % len(runs), :2], runs[i % len(runs), 2:4], runs[i % len(runs), 4:]
        depth = float((p - a) @ n)
        along = float((p - a) @ (b - a)) / float(np.hypot(*(b - a)))
        assert 0.15 - 1e-9 <= depth <= 0.35 + 1e-9 and 0.3 - 1e-9 <= along <= np.hypot(*(b - a)) - 0.3 + 1e-9
    walls = blocking_faces(floor_plan_model(fp).faces, 1.5)
    assert (wall_distance(xy, walls) >= 0.3 - 1e-9).all()


def test_line_agreement_by_hand():
    m = np.zeros((18, 36), np.uint8)
    m[9, :] = 1                              # a map line on the horizon: 36 pixels
    q = np.zeros_like(m)
    q[10, :18] = 1                           # 18 detected pixels one row below it (on the map within 1 px)
    q[17, :12] = 1                           # 12 clutter pixels in the last row (elevation -85 deg)
    q[4, :6] = 1                             # 6 clutter pixels at +40 deg
    on_map, found, below = line_agreement(q, m)
    assert on_map == 18 / 36
    assert found == 19 / 36                  # columns 0-18 of the map line lie within 1 px of a detection
    assert below == 12 / 18


def test_the_experiment_rule_picks_the_highest_mean_then_the_cheapest():
    # placeloc experiment umap-homes: highest mean over the homes of each home's worst origin
    # (here nine runs, each a home of its own: the mean share); among settings within one
    # panorama of one home of it, the fewest answers moving, then the fewest candidate cells,
    # then the earlier (plainer) in the sweep
    from placeloc.experiments.umap_homes import PANORAMAS, SWEEP, choose
    from placeloc.umap.params import PanoramaParams

    names = list(SWEEP)
    climb32 = "solid-angle chamfer, 32 cells"
    square16 = "solid-angle chamfer, 16 cells, beam's cells whole"
    square32 = "solid-angle chamfer, 32 cells, beam's cells whole"
    texture_square32 = "solid-angle chamfer, texture r 1, 32 cells, beam's cells whole"
    assert {climb32, square16, square32, texture_square32} <= set(names)
    nine = [0.95] * 9
    one = 1.0 / (PANORAMAS * 9)                               # one panorama of one of the nine homes
    results = {climb32: nine, square32: [0.975] * 9, texture_square32: [0.975] * 9, square16: nine}
    assert choose(results) == square32                        # a tie on 32 cells: the earlier in the sweep
    assert names.index(square32) < names.index(texture_square32)
    results[square16] = [0.975 - one] * 9                     # one panorama below on fewer cells: the cheaper
    assert choose(results) == square16
    results[square16] = [0.975 - 2 * one] * 9                 # two panoramas below: the best
    assert choose(results) == square32
    # within one panorama, the answers that move least with the grid's origin come first
    # (more than 0.1 m, then more than 0.05 m), before the cost
    results[square16] = [0.975 - one] * 9
    moves = {square32: (2, 9), texture_square32: (1, 9), square16: (2, 3), climb32: (0, 0)}
    assert choose(results, moves) == texture_square32
    moves[texture_square32] = (2, 9)
    assert choose(results, moves) == square16                 # equal beyond 0.1 m: fewer beyond 0.05 m
    # three homes at three origins: each home's worst origin counts, not the mean over the runs.
    # square32 has the higher mean (0.967 against 0.95) but one home at 0.85 at one origin
    # (worst origins 1, 1, 0.85: mean 0.95); square16 is 0.95 everywhere (mean of worst 0.95):
    # a tie, within one panorama of one home (1/60): the fewer answers moving wins
    results = {square32: [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.85, 1.0, 0.85], square16: [0.95] * 9}
    assert choose(results, {square32: (1, 1), square16: (0, 0)}, origins=3) == square16
    assert choose(results, {square32: (0, 0), square16: (1, 1)}, origins=3) == square32
    results[square16] = [0.9] * 9                             # one home's worst 0.05 lower each: the best
    assert choose(results, {square32: (1, 1), square16: (0, 0)}, origins=3) == square32
    # the settings before refine_final_ties finished the beam's best pose only; the last the default
    assert all(SWEEP[k]["refine_final_ties"] == 0.0 for k in names[:-1])
    assert SWEEP[names[-1]]["refine_final_ties"] == 0.02 == PanoramaParams().refine_final_ties


def test_answer_moves_by_hand():
    from placeloc.experiments.umap_homes import answer_moves

    # frame a: 0.06 m apart at most; b: 0.12 m (3-4-5 triangle scaled); c: one origin only
    positions = {"a": [(0, 0), (0.06, 0), (0.03, 0)], "b": [(0, 0), (0.072, 0.096)], "c": [(5, 5)]}
    assert answer_moves(positions) == (1, 2)


def _with_things(seed):
    return plan(np.random.default_rng(seed), 3, things_rng=np.random.default_rng([seed, 2]))


def _inside(t, b, pad):
    """Box t's plan footprint lies inside box b's, grown by pad."""
    return b[0] - pad <= t[0] and t[3] <= b[3] + pad and b[1] - pad <= t[1] and t[4] <= b[4] + pad


def _on_a_wall(t, lo, hi):
    """Box t is flat (at most 0.03 m thick) and within 3 mm of a wall of the room lo..hi."""
    return ((t[4] - t[1] <= 0.03 and min(abs(t[1] - lo[1]), abs(t[4] - hi[1])) <= 0.003)
            or (t[3] - t[0] <= 0.03 and min(abs(t[0] - lo[0]), abs(t[3] - hi[0])) <= 0.003))


def test_kitchen_things_stand_on_the_counters_and_against_the_cabinets():
    # the things the map lacks stand where a kitchen has them: appliances on a counter top
    # (0.9 m up, at most 1.3 m), inside a counter's footprint; handles and door panels on a
    # cabinet's front (within 0.03 m of it); the window over the sink in the gap of the wall
    # cabinets; nothing outside the furniture's footprints by more than 0.03 m but flat things
    # on a wall, so the cameras' clearances (0.15-0.3 m from the furniture, 0.3-0.5 m from the
    # walls) are those of the home without them
    from placeloc.synth.home import COUNTER_THINGS

    on_counter = {name for name, *_ in COUNTER_THINGS}
    for seed in range(5):
        fp, clutter = _with_things(seed)
        boxes = np.asarray(clutter["boxes"], float)
        things = np.asarray(clutter["things"], float)
        names = clutter["thing_names"]
        assert len(names) == len(things) and on_counter & set(names) and "handle" in names
        counters = boxes[(boxes[:, 2] == 0.0) & (boxes[:, 5] == 0.9) & (boxes[:, 6] == 0.45)]
        assert len(counters) == 2

        lo, hi = _room(fp, "kitchen").min(axis=0), _room(fp, "kitchen").max(axis=0)
        for name, t in zip(names, things):
            assert any(_inside(t, b, 0.03) for b in boxes) or _on_a_wall(t, lo, hi), name
            if name in on_counter:
                assert t[2] == 0.9 and t[5] <= 1.3 and any(_inside(t, c, 0.0) for c in counters), name
        wall_cabinets = boxes[(boxes[:, 2] == 1.45) & (boxes[:, 5] == 2.15)]
        frame = things[names.index("window frame")]
        assert frame[2] >= 0.9 and frame[5] <= 2.15
        south = wall_cabinets[wall_cabinets[:, 1] == frame[1]]
        assert len(south) >= 1 and all(b[3] <= frame[0] or b[0] >= frame[3] for b in south)


def test_kitchen_things_leave_the_plan_and_the_other_clutter_as_they_were():
    for seed in range(3):
        fp0, c0 = plan(np.random.default_rng(seed), 3)
        fp1, c1 = _with_things(seed)
        assert fp0 == fp1
        assert all(c0[k] == c1[k] for k in c0 if k not in ("boxes", "things", "thing_names"))
        assert c0["things"] == [] and c0["thing_names"] == []
        # the boxes differ only in the south wall cabinets, split around the window over the sink
        old = [b for b in c0["boxes"] if b not in c1["boxes"]]
        new = [b for b in c1["boxes"] if b not in c0["boxes"]]
        assert len(old) == 1 and 1 <= len(new) <= 2
        assert all(b[1:3] == old[0][1:3] and b[4:] == old[0][4:] and old[0][0] <= b[0] and b[3] <= old[0][3] for b in new)


def _pixel_ray(u, v, width, height, heading_deg):
    # the renderer's convention (render_panorama): column u, row v -> (azimuth, elevation)
    az = np.radians(heading_deg) + np.pi - 2 * np.pi * (u + 0.5) / width
    el = np.pi / 2 - np.pi * (v + 0.5) / height
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def test_a_rendered_pixel_hits_the_kettle_where_it_stands():
    # a camera 0.8 m in front of the kettle, 1.5 m up, looking at it: the pixel whose ray meets
    # the kettle's front face (by hand: the plane's crossing lies inside the face) shows the
    # kettle's grey (0.88 + 0.03 * noise in [0, 1]) dimmed by the distance (1 + 0.02 t);
    # without the kitchen things the same pixel sees the splashback or the wall behind
    from placeloc.synth.home import render_panorama, scene_arrays

    seed = next(s for s in range(20) if "kettle" in _with_things(s)[1]["thing_names"])
    fp, clutter = _with_things(seed)
    box = np.asarray(clutter["things"][clutter["thing_names"].index("kettle")], float)
    south = -min(p[1] for r in fp["rooms"] for p in r["polygon"])
    if box[1] < -south + 0.7:    # on the south run: its front faces north (+y)
        normal, face, centre = np.array([0.0, 1.0]), 4, np.array([(box[0] + box[3]) / 2, box[4]])
    else:                        # on the east run: its front faces west (-x)
        normal, face, centre = np.array([-1.0, 0.0]), 0, np.array([box[0], (box[1] + box[4]) / 2])
    cam = centre + 0.8 * normal
    pose = np.array([cam[0], cam[1], 1.5, np.degrees(np.arctan2(-normal[1], -normal[0]))])
    width, height = 512, 256
    u = width // 2
    el = np.arctan2((box[2] + box[5]) / 2 - 1.5, 0.8)
    v = int(round((np.pi / 2 - el) * height / np.pi - 0.5))
    d = _pixel_ray(u, v, width, height, pose[3])
    axis = 1 if face == 4 else 0
    t = (box[face] - pose[axis]) / d[axis]
    hit = pose[:3] + t * d
    assert box[0] <= hit[0] <= box[3] and box[1] <= hit[1] <= box[4] and box[2] <= hit[2] <= box[5]
    img = render_panorama(pose, scene_arrays(fp, clutter, np.random.default_rng(0)), width, height)
    assert 0.88 / (1 + 0.02 * t) - 1e-9 <= img[v, u] <= 0.91 / (1 + 0.02 * t) + 1e-9
    fp0, c0 = plan(np.random.default_rng(seed), 3)
    bare = render_panorama(pose, scene_arrays(fp0, c0, np.random.default_rng(0)), width, height)
    assert abs(bare[v, u] - img[v, u]) > 0.1


def _through_door(pose, door, width, height, door_top):
    """Pixels whose ray crosses the (east-west) door segment below its top."""
    v, u = np.mgrid[0:height, 0:width]
    el = np.pi / 2 - np.pi * (v + 0.5) / height
    az = np.radians(pose[3]) + np.pi - 2 * np.pi * (u + 0.5) / width
    dx, dy, dz = np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)
    (ax, ay), (bx, _) = door
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ay - pose[1]) / dy
        x, z = pose[0] + t * dx, pose[2] + t * dz
    return (t > 0) & (x >= min(ax, bx)) & (x <= max(ax, bx)) & (z >= 0) & (z <= door_top)


def test_panoramas_outside_the_kitchen_change_only_through_its_door(tmp_path):
    # one small home generated with and without the kitchen things: the same plan and poses;
    # a panorama whose camera stands outside the kitchen changes only in pixels whose ray
    # passes the kitchen's door (3 px of blur allowed), so that other rooms are unchanged
    import csv

    import cv2
    import yaml

    from placeloc.synth.home import generate

    kw = {"seed": 1, "panoramas": 8, "width": 256, "stats_width": 128, "cabinet_share": 0.125}
    generate(tmp_path / "bare", kitchen_things=False, **kw)
    generate(tmp_path / "things", kitchen_things=True, **kw)
    for name in ("floor_plan.yaml", "poses.csv"):
        assert (tmp_path / "bare" / name).read_bytes() == (tmp_path / "things" / name).read_bytes()
    fp = yaml.safe_load((tmp_path / "things" / "floor_plan.yaml").read_text())
    kitchen = _room(fp, "kitchen")
    door = next((o["from"], o["to"]) for o in fp["openings"] if o["from"][1] == 0 == o["to"][1]
                and kitchen[:, 0].min() <= o["from"][0] <= kitchen[:, 0].max())
    changed, same = {"kitchen": 0, "elsewhere": 0}, {"kitchen": 0, "elsewhere": 0}
    for row in csv.DictReader(open(tmp_path / "things" / "poses.csv")):
        a = cv2.imread(str(tmp_path / "bare" / "panoramas" / row["frame"]), cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(str(tmp_path / "things" / "panoramas" / row["frame"]), cv2.IMREAD_GRAYSCALE)
        pose = [float(row[k]) for k in ("x", "y", "z", "heading_deg")]
        where = "kitchen" if room_name(fp, pose[0], pose[1]) == "kitchen" else "elsewhere"
        changed[where] += int((a != b).any())
        same[where] += int((a == b).all())
        if where == "elsewhere":
            seen = cv2.dilate(_through_door(pose, door, b.shape[1], b.shape[0], 2.05).astype(np.uint8), np.ones((7, 7), np.uint8))
            assert not ((a != b) & (seen == 0)).any(), row["frame"]
    # this home: every kitchen camera sees the things; of the five elsewhere, four are
    # byte-identical and bedroom 3's camera sees them through its door and the kitchen's
    assert changed["kitchen"] == 3 and same["kitchen"] == 0
    assert same["elsewhere"] == 4 and changed["elsewhere"] == 1


def test_cameras_held_by_hand_each_stand_at_their_own_height(tmp_path):
    # z_spread 0.25 around 1.45 m: the cameras' heights spread over 1.2-1.7 m (a phone held
    # by hand) while the plan keeps camera_z 1.45; the default 0.03 is a tripod's, and the same
    # random draws scaled: the plan, the positions and the headings are the same in both
    import csv

    import yaml

    from placeloc.synth.home import generate

    kw = {"seed": 3, "panoramas": 8, "width": 128, "stats_width": 64, "z": 1.45}
    generate(tmp_path / "tripod", **kw)
    generate(tmp_path / "phone", z_spread=0.25, **kw)
    rows = {k: list(csv.DictReader(open(tmp_path / k / "poses.csv"))) for k in ("tripod", "phone")}
    tz, pz = (np.array([float(r["z"]) for r in rows[k]]) for k in ("tripod", "phone"))
    assert np.all(np.abs(tz - 1.45) <= 0.03) and np.all(np.abs(pz - 1.45) <= 0.25) and np.ptp(pz) > 0.2
    assert np.allclose((pz - 1.45) / 0.25, (tz - 1.45) / 0.03, atol=0.005)   # poses.csv keeps 4 decimals
    for a, b in zip(*rows.values()):
        assert (a["frame"], a["x"], a["y"], a["heading_deg"]) == (b["frame"], b["x"], b["y"], b["heading_deg"])
    for k in ("tripod", "phone"):
        assert yaml.safe_load((tmp_path / k / "floor_plan.yaml").read_text())["camera_z"] == 1.45


def test_another_ceiling_changes_only_what_lies_above_the_cameras(tmp_path):
    # ceiling 2.8 instead of 2.5: the same plan but for ceiling_z, the same poses, and each
    # panorama the same bytes below the horizon (rays going down never reach the ceiling; the
    # fans and lamps hang from it), other above it
    import csv

    import cv2
    import yaml

    from placeloc.synth.home import generate

    kw = {"seed": 2, "panoramas": 4, "width": 128, "stats_width": 64}
    generate(tmp_path / "low", **kw)
    generate(tmp_path / "high", ceiling=2.8, **kw)
    assert (tmp_path / "low" / "poses.csv").read_bytes() == (tmp_path / "high" / "poses.csv").read_bytes()
    low, high = (yaml.safe_load((tmp_path / k / "floor_plan.yaml").read_text()) for k in ("low", "high"))
    assert (low["ceiling_z"], high["ceiling_z"]) == (2.5, 2.8)
    assert {**low, "ceiling_z": 2.8} == high
    for row in csv.DictReader(open(tmp_path / "low" / "poses.csv")):
        a, b = (cv2.imread(str(tmp_path / k / "panoramas" / row["frame"]), cv2.IMREAD_GRAYSCALE) for k in ("low", "high"))
        h = a.shape[0]
        assert np.array_equal(a[h // 2 + 3:], b[h // 2 + 3:]), row["frame"]   # 3 rows: the blur's reach
        assert (a[: h // 2 - 3] != b[: h // 2 - 3]).mean() > 0.05, row["frame"]
    with pytest.raises(ValueError, match="ceiling 2.1"):
        generate(tmp_path / "bad", ceiling=2.1, **kw)
