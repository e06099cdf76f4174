"""UMap parameters: the one home of their defaults, ranges and meaning.

The method is the Universal Map (line images of a 3-D wireframe pre-map against LSD line
images of the query) with Consistency Adjustment, from K. Takahashi, J. Takahashi,
T. Kaneko and Y. Tobe, "Improving pre-map indoor localization by comparing consecutive
images" (see docs/umap.md for what this project takes from it).
"""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.core.params import Params, param, section


@dataclass(frozen=True)
class CameraParams(Params):
    width: int = param(160, min=8, help="rendered and query image width in pixels")
    height: int = param(120, min=8, help="rendered and query image height in pixels")
    hfov_deg: float = param(60.0, min=1.0, max=179.0, help="horizontal field of view")


@dataclass(frozen=True)
class GridParams(Params):
    x: tuple[float, float, float] | None = param(None, min_len=3, help="x start, stop, step in metres (none: the model's plan bounds "
                                                            "at grid.step_m)")
    y: tuple[float, float, float] | None = param(None, min_len=3, help="y start, stop, step in metres (none: the model's plan bounds "
                                                            "at grid.step_m)")
    step_m: float = param(0.25, min=0.0, min_exclusive=True, help="grid spacing where x or y is left to the model")
    z: float | None = param(None, help="camera height in metres (none: the plan's camera_z, which the ZInD importer and "
                                       "the home generator write)")
    heights: tuple[float, ...] = param([], help="panoramas: camera heights in metres to search, for a camera whose "
                                               "height is not known (a phone held by hand, 1.2-1.7 m up): the grid is "
                                               "rendered at each and every panorama's answer is the best over them, "
                                               "with the height found in estimates.csv; localize costs as many times "
                                               "more ([] = the one height z)")
    ceilings: tuple[float, ...] = param([], help="panoramas with a floor plan: ceiling heights in metres to search, "
                                                "for a plan whose ceiling height is not known (a plan drawn from a "
                                                "listing's drawing; e.g. 2.3-3.0 every 0.1): each replaces every "
                                                "room's ceiling_z and the grid is rendered at each; the home's is the "
                                                "one whose grid table scores the run's panoramas best, refined between "
                                                "its neighbours, and only it is searched off the grid (ceiling_m in "
                                                "estimates.csv). The index costs as many times more, times the "
                                                "heights; localize about a fifth of a search more per ceiling. It "
                                                "needs about 10 photos of the home (a warning with fewer). "
                                                "It also makes up most of a plan drawn up to 10 % too large or "
                                                "too small (the ceiling found is then not the home's). "
                                                "With the camera's height unknown too, search the ceilings first, "
                                                "then give the one found alone with the heights ([] = the plan's "
                                                "own)")
    headings: tuple[float, ...] = param([45.0, 135.0, 225.0, 315.0], min_len=1, help="headings in degrees")
    inside_only: bool = param(True, help="keep only grid poses inside the floor plan")
    wall_margin_m: float = param(0.1, min=0.0, help="keep grid poses this far from the walls that span the camera "
                                                    "height (lintels over doorways do not count)")


@dataclass(frozen=True)
class CAParams(Params):
    formula: str = param("exact", choices=("exact", "paper"), help="CA step formula")
    wall_side: str = param("right", choices=("right", "left"), help="side of the wall the laser sees")
    phi_deg: float = param(0.0, help="camera yaw relative to the robot")
    error_mean_m: float = param(0.15, help="mean CA step error (metres)")
    error_std_m: float = param(0.3, min=0.0, min_exclusive=True, help="CA step error spread (metres)")
    bin_px: float = param(8.0, min=0.0, min_exclusive=True, help="vote histogram bin")
    min_matches: int = param(5, min=1, help="fewest feature matches for a CA step")
    fallback_radius_m: float = param(2.5, min=0.0, help="search radius when CA fails")
    akaze_threshold: float = param(0.00003, min=0.0, min_exclusive=True, help="AKAZE detector threshold")
    anchor: str = param("chain", choices=("best", "chain"), help="where CA steps start")
    keep_heading: bool = param(True, help="keep the previous heading across a CA step")
    tracker: str = param("robust", choices=("robust", "paper"), help="CA tracker")
    vote_tol_m: float = param(0.05, min=0.0, help="vote agreement tolerance (metres)")
    vote_rel_tol: float = param(0.03, min=0.0, help="vote agreement tolerance (relative)")
    reliable_matches: int = param(15, min=1, help="matches for a reliable CA step")
    reliable_ratio: float = param(1.5, min=1.0, help="winning/runner-up vote ratio for a reliable step")
    tie_tol: float = param(0.003, min=0.0, help="score tie tolerance")
    recover_ratio: float = param(1.15, min=1.0, help="score ratio to recover from a bad step")
    fallback_step_m: float | None = param(None, help="step length when CA fails (None: from the sensor)")
    laser_tol_m: float = param(0.15, min=0.0, help="laser-range consistency tolerance")
    use_laser: bool = param(True, help="check candidate poses against laser ranges")


@dataclass(frozen=True)
class PanoramaParams(Params):
    width: int = param(144, min=8, help="equirectangular line image width in pixels (yaw step = 360 / width degrees)")
    height: int = param(72, min=4, help="equirectangular line image height in pixels")
    face_px: int = param(256, min=32, help="size of the six cube faces LSD runs on")
    lsd_min_length_px: float = param(8.0, min=0.0, help="shortest LSD line kept, in face pixels")
    equalize_clip: float = param(1.0, min=0.0, max=40.0,
                                 help="each cube face's contrast equalised locally (CLAHE, tiles of 32 face pixels) "
                                      "before LSD, at this clip limit, so that faint junctions (a white wall under a "
                                      "white ceiling) reach LSD's fixed gradient threshold; 1, 2 and 4 placed the "
                                      "same photos on generated homes, 15 wrong of 1,300 against 33 off, and 0 of 500 "
                                      "against 5 on test homes (placeloc experiment umap-contrast); 0: off")
    level_max_deg: float = param(20.0, min=0.0, max=45.0,
                                 help="level each panorama first: its zenith found where the great circles of its "
                                      "vertical lines meet, within this many degrees of the image's, and its lines "
                                      "turned upright before they are drawn (a hand-held 360 degree photo is rarely "
                                      "level, and a few degrees of tilt cost answers; tilts under 0.5 degrees, a level "
                                      "panorama's own scatter, are left as they are); 0: off, the images taken as level")
    score: str = param("chamfer", choices=("iou", "chamfer"),
                       help="iou: eq. (1) of the paper; chamfer: truncated distance-transform score (clutter and unseen "
                            "map lines cost little)")
    chamfer_tau_px: float = param(3.0, min=0.0, min_exclusive=True, help="chamfer truncation distance in pixels")
    chamfer_chance: str = param("none", choices=("area", "yaw", "none", "likelihood"),
                                help="what each half of the chamfer score is corrected for, as (score - chance) / (1 - "
                                     "chance): area, the share of the image the other side's closeness covers (a view "
                                     "drawing much map earns no more for clutter near it); yaw, the half's mean over all "
                                     "headings; likelihood, each half the mean log likelihood ratio of its line pixels "
                                     "drawn by the other side's lines or clutter (clutter_share) against clutter alone; "
                                     "none, the plain halves")
    clutter_share: float = param(0.5, min=0.0, max=0.99, min_exclusive=True,
                                 help="chamfer_chance likelihood: the share of line pixels taken as clutter spread evenly "
                                      "over the sphere (the rest lie near the other side's lines, as its closeness says)")
    recall_weight: float = param(0.5, min=0.0, max=1.0,
                                 help="chamfer score: the weight of its recall half (the map's drawn lines near the "
                                      "photo's lines); the precision half (the photo's lines near the map's) weighs the "
                                      "rest; 0.5: their mean. 0.4 placed more photos on development homes but fewer on "
                                      "test homes (placeloc experiment umap-halves), so the mean stays")
    texture_radius_px: int = param(0, min=0, max=8,
                                   help="chamfer score: each query line pixel weighs two lines' worth of pixels in the "
                                        "(2r + 1)-pixel square around it over the line pixels there (at most 1), so "
                                        "that dense texture the map lacks (blinds, sunlight stripes, tiles) counts "
                                        "about as two lines; 0: every line pixel weighs 1")
    precision_polar_deg: float = param(75.0, min=0.0, max=90.0,
                                       help="chamfer score: the precision half counts only the query's line pixels "
                                            "within this many degrees of the horizon (the floor at the camera's foot: "
                                            "tripod, rugs, sunlight stripes; the ceiling over it: a fan or lamp); the "
                                            "recall half keeps every row; 90: all")
    orientation_bins: int = param(6, min=1, max=8,
                                  help="chamfer score: bins of the line pixels' direction in the image (180 / bins "
                                       "degrees each, the map's exact from its segments, the query's from its LSD "
                                       "segments); a pixel is near only to the other side's lines of a compatible bin "
                                       "(orientation_spread), so clutter matches the map only where its direction "
                                       "agrees; 1: directions ignored; more than 1 needs chamfer_chance none")
    orientation_spread: int = param(1, min=0, max=3,
                                    help="orientation_bins > 1: a line pixel of direction bin b counts as near to the "
                                         "other side's lines of bins b - spread .. b + spread (0: its own bin only)")
    polar_deg: float = param(60.0, min=0.0, max=90.0, help="rows more than this far above or below the horizon count with "
                                                        "polar_weight in the chamfer score")
    polar_weight: float = param(1.0, min=0.0, max=1.0, help="weight of the rows beyond polar_deg (floor under the camera: "
                                                           "sunlight stripes, rugs, tripod; ceiling fans)")
    solid_angle: bool = param(True, help="weight each row by the cosine of its elevation, the solid angle its pixels "
                                          "cover, so that both halves of the chamfer score are means over the sphere of "
                                          "directions, not over the image's pixels (whose rows near the floor and "
                                          "ceiling poles are oversampled); multiplies polar_weight")
    refine_candidates: int = param(32, min=0, help="distinct best grid positions whose cells are searched off the grid "
                                                   "(8 points a third of a grid step around each), for either score (0: "
                                                   "grid only)")
    refine_separation_m: float = param(0.3, min=0.0, help="least distance between two refined candidates")
    coarse_candidates: int = param(8, min=0, help="of the refine_candidates, how many are chosen by a tolerant score "
                                                  "(chamfer, chance none: the query's closeness at coarse_tau_px, its "
                                                  "line pixels blurred by coarse_blur_px), after the rest by the exact "
                                                  "one, so that a peak narrower than the grid step still has its grid "
                                                  "point among them; the search after the choice scores exactly (0: "
                                                  "all by the exact score, as with the IoU score or a chamfer_chance other than none)")
    coarse_tau_px: float = param(8.0, min=0.0, min_exclusive=True,
                                 help="coarse_candidates: the tolerant score's truncation, in pixels, of the query's "
                                      "closeness (the recall half)")
    coarse_blur_px: int = param(2, min=0, max=8, help="coarse_candidates: the tolerant score's precision half counts "
                                                      "each query line pixel spread over the (2r + 1)-pixel square "
                                                      "around it")
    refine_top: int = param(0, min=0, help="the best grid positions by the table's own rank (each at its best yaw) "
                                           "that a pose of the beam kept out of the candidates (within "
                                           "refine_separation_m of it) get their cell stage after the beam is chosen; "
                                           "each that beats that pose joins the beam, so that a narrow peak one grid "
                                           "step from a better-ranked place is reached (8 renders each, and a beam "
                                           "pose's climb each that joins; 0: none)")
    refine_climb: int = param(0, min=0, max=4, help="after the cell stage, 8-neighbour climbs at a sixth of a grid step "
                                                    "that every candidate makes before the beam is chosen (8 renders "
                                                    "each per candidate and climb; 0: none)")
    refine_beam: int = param(4, min=1, help="best poses after the cell stage that go on coarse to fine")
    refine_beam_within: float = param(0.05, min=0.0, help="of the refine_beam poses, only those scoring within this of "
                                                          "the best after the cell stage go on: on generated homes the "
                                                          "place that won was never more than 0.019 behind there, and "
                                                          "each pose kept costs 64 renders (docs/umap.md, \"A beam of "
                                                          "the places that can still win\"; chamfer score only; 0: every one)")
    refine_square: int = param(3, min=1, max=6, help="at the beam's first step (a sixth of a grid step) each pose first "
                                                     "samples the square of this many steps either side of it (3: its "
                                                     "whole grid cell; 1: only its 8 neighbours); chamfer score only")
    refine_step_m: float = param(0.02, min=0.0, min_exclusive=True, help="the local search's finest step")
    refine_final_m: float = param(0.01, min=0.0, help="the finest step, in metres, of a pattern search (8 neighbours a "
                                                      "move, the step halved) made last, near the beam's best pose "
                                                      "(chamfer score only; 0: off). It steadies answers against the "
                                                      "grid's origin (generated homes 0-12 at five origins: answers "
                                                      "moving by more than 0.05 m 69 -> 22, and 2 with "
                                                      "refine_final_radius_m)")
    refine_final_start_m: float = param(0.08, min=0.0, help="refine_final_m > 0: that search's first step in metres, "
                                                            "started from the nearest point of the plan's own lattice of "
                                                            "it (0: the beam's finest step, from the beam's best pose)")
    refine_final_radius_m: float = param(0.24, min=0.0, help="refine_final_start_m > 0: that search starts from the best "
                                                           "point of the plan's own lattice of half its first step "
                                                           "(0.04 m) within this many metres of the beam's best pose, "
                                                           "and its end is the answer, so that the grid's origin moves "
                                                           "no answer between bumps of the score closer than this "
                                                           "(about 110 renders a panorama at 0.24 m; 0: from the "
                                                           "lattice point nearest the beam's pose, kept where higher)")
    refine_final_ties: float = param(0.02, min=0.0, help="refine_final_m > 0: every pose of the beam scoring within "
                                                         "this of its best (and further than refine_final_radius_m "
                                                         "from one taken) gets that search too, and the best end is "
                                                         "the answer: places the grid's phase ranks either way are "
                                                         "compared on the plan's own lattice (0: the best pose only)")
    refine_yaw_cols: int = param(3, min=0, help="column shifts either side of a candidate's best heading scored at each "
                                                "local pose")
    margin_distance_m: float = param(1.0, min=0.0, min_exclusive=True,
                                     help="an answer's margin (estimates.csv, the poses contract's confidence) is its "
                                          "score minus the best score the search saw of a rival: a pose more than "
                                          "this far away, or nearer at a heading more than margin_yaw_deg off")
    margin_yaw_deg: float = param(30.0, min=0.0, max=180.0, help="see margin_distance_m")
    doubtful_margin: float = param(0.05, min=0.0, help="answers whose margin is below this are marked doubtful in "
                                                        "estimates.csv and named in the log (in the score's units: "
                                                        "the 5th percentile of the right answers' margins on "
                                                        "generated development homes, rounded, so that about 1 in 20 "
                                                        "right answers is flagged: 0.05 since the photos' contrast is "
                                                        "equalised, which raised the margins; 0.02 before. "
                                                        "docs/umap.md; the IoU score's margins are smaller: set your "
                                                        "own)")
    height_layers: int = param(0, min=0, help="with several umap.grid.heights (chamfer score): each panorama is "
                                              "searched whole in only this many layers, those whose grid table "
                                              "(every position and yaw) scores it best (0: every layer)")


@dataclass(frozen=True)
class UMapParams(Params):
    model: str | None = param(None, path=True, help="wireframe (.yaml/.json/.obj), floor plan (.yaml) or a Zillow Indoor "
                                                    "Dataset zind_data.json")
    floor: str | None = param(None, help="the floor of a zind_data.json model, e.g. floor_02 (none: its only floor with "
                                         "a scale; an error naming the floors when it has several)")
    camera: CameraParams = section(CameraParams)
    grid: GridParams = section(GridParams)
    near_m: float = param(0.05, min=0.0, min_exclusive=True, help="near clipping distance")
    hidden_lines: bool = param(True, help="remove hidden lines when rendering")
    block: int = param(2048, min=1, affects_result=False, help="database views scored per block")
    tolerance_px: int = param(2, min=0, help="line dilation for matching")
    query_kind: str = param("pinhole", choices=("pinhole", "equirect", "panorama"),
                            help="pinhole images; equirect: panoramas cut into views at the grid headings, best single "
                                 "view kept; panorama: whole 360 degree panoramas, yaw searched")
    panorama: PanoramaParams = section(PanoramaParams)
    lsd_min_length_px: float = param(6.0, min=0.0, help="shortest LSD line kept")
    query_thickness_px: int = param(1, min=1, help="query line thickness")
    mode: str = param("umap", choices=("umap", "umap+ca"),
                      help="umap: every image on its own; umap+ca: a sequence with Consistency Adjustment (needs sensor_csv)")
    sensor_csv: str | None = param(None, path=True, help="odometry/laser CSV for CA")
    room_hints: str | None = param(None, path=True, help="panoramas with a floor plan of rooms: a CSV with the columns "
                                                         "frame, room naming the room each photo was taken in, where "
                                                         "you know it (a room's name, or its label in parentheses: "
                                                         "kitchen for 'complete_room_3 (kitchen)'; every room of that "
                                                         "name counts; an empty room or a missing frame: anywhere). "
                                                         "Each such photo is searched in that room only, so a "
                                                         "look-alike room elsewhere is no rival, and its margin is "
                                                         "over the room's other places and headings")
    room_hint_margin_m: float = param(0.3, min=0.0, help="umap.room_hints: how far outside its room's outline a photo "
                                                         "may still stand: a camera in a doorway counts for both "
                                                         "rooms (the grid's doorways reach 0.25 m either side of the "
                                                         "wall line); kept small, as twin rooms share a wall")
    room_hint_check: float = param(0.02, min=0.0, help="umap.room_hints: warn where the best grid place outside a "
                                                       "photo's named room scores more than this above its answer "
                                                       "inside it: the name may be wrong (0.02, the "
                                                       "doubtful margin when it was measured, before the photos' "
                                                       "contrast was equalised: an outside place that far ahead is "
                                                       "no near tie; docs/umap.md)")
    ca: CAParams = section(CAParams)
