"""``make seqslam-motion``: SeqSLAM following a query that stops, crawls, bursts and reverses.

The winter traverse of nordland-dev is resampled along a seeded speed profile (reference
frames per query frame, negative while it drives backwards) to make each motion; the
summer traverse is the reference. Query frame ``j`` sits at reference position ``x_j``
(``x_0 = 0``, ``x_{j+1} = x_j + speed_j``) and shows winter frame ``round(x_j)``; the route
ends when ``x`` first passes the last frame. Families (each seed names one profile):

- ``steady``: 1.0 throughout (the original query);
- ``varying``: 0.5x-2.0x, changing smoothly every 60 frames (``seqslam_speed``);
- ``fast``: one constant speed drawn from 2.25x-3.0x (past the old preset's 2.0x);
- ``stop``: 1.0x with three stops of 30-60 frames;
- ``crawl``: 1.0x with one stretch of 60-100 frames at 0.25x-0.4x;
- ``burst``: 1.0x with one stretch of 40-80 frames at 2.5x-4.0x;
- ``reverse``: 1.0x, one stretch of 60-150 frames driven backwards at 0.5x-1.5x, then on
  (0.5x-1.0x until 2026-11-26 17:00 UTC: widened before the backward family's speeds
  were limited, so that the choice of ``backward_v_max`` sees reversals past 1.0x).

Scoring uses a soft ground truth (:func:`shared_stops`): where both traverses stand still
(a train in a station), every frame of that stretch shows the same place, so a match
anywhere in it, +-2 frames, is right; elsewhere the match must be within +-2 frames.
Every figure is also given inside the motion's own stretch (``*_inside``).

The search runs on the enhanced difference matrix of the part (columns in the query's
order are exactly what ``localize`` searches, enhancement being per query column), with
the preset's settings and ``v_auto`` applied as ``localize`` applies it.
Costs are chosen on frames 1-600 (``tune``, seeds 0-2: twelve settings, about a minute on
2 cores) and reported on 601-1200 (seeds 200-204, drawn after the last choice; 100-104,
which earlier choices had seen, with ``--seeds 100-104``); ``--quick`` (CI) runs the
preset on frames 601-1050 with two seeds: 450 frames, so that a query 3x faster than the
reference (150 frames) still holds a 121-frame window. ``whole`` scores the preset on the
whole of nordland-dev (``placeloc run configs/nordland.yaml``) by the synchronous +-2
ground truth it is configured with, beside the preset without ``collapse_stops`` and with
the whole backward family: the rule's last check.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.experiments import shared_data_dir, write_summary

FAMILIES = ("steady", "varying", "fast", "stop", "crawl", "burst", "reverse")
MOTIONS = FAMILIES[2:]
TUNE_SEEDS = (0, 1, 2)
# held out: 200-204 drawn for the choice of collapse_stops' answers (2026-11-26), unseen
# before it; 100-104 were the held-out seeds of the rounds before, seen by that choice
REPORT_SEEDS = (200, 201, 202, 203, 204)
EARLIER_REPORT_SEEDS = (100, 101, 102, 103, 104)
TOLERANCE = 2
# the rule's check on the whole route: a switch may cost R@1 and recall at 100 % precision
# by the synchronous +-2 truth at most this much (the rule's tie band on the tuning part)
WHOLE_ROUTE_SLACK = 0.005
CONFIGS = Path(__file__).resolve().parents[3] / "configs"
# A frame pair is "still" when it changes less than this fraction of its traverse's
# median frame-to-frame change: nordland-dev's pairs fall in two groups, 0.03-0.05
# (standing) and 0.6-1.0 (moving), against a median of 0.8-0.85, so any fraction from
# 0.1 to 0.5 gives the same stretches.
STILL_FRACTION = 0.25
# The reverse family's backward speeds (reference frames per query frame, drawn per seed):
# 0.5x-1.5x since 2026-11-26 17:00 UTC, so that the choice of backward_v_max sees
# reversals past 1.0x; 0.5x-1.0x before (``--reverse-speeds 0.5-1.0``, for continuity).
REVERSE_SPEEDS = (0.5, 1.5)
# backward_v_max above every speed a search here tries (the fast family scales 4.0x by up
# to 2.7): the whole backward family, as backward_paths searched it before the limit
ALL_SPEEDS = 100.0


def motion_profile(family: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` query-frame speeds of one family and a mask of the frames inside its motion
    (the stops, the crawl, the burst, the backward stretch; all frames for steady,
    varying and fast)."""
    from placeloc.experiments.seqslam_speed import speed_profile

    rng = np.random.default_rng(seed)
    speeds = np.ones(n)
    inside = np.zeros(n, bool)
    if family in ("steady", "varying"):
        return (speed_profile(family, n, seed) if family == "varying" else speeds), ~inside
    if family == "fast":
        return np.full(n, rng.uniform(2.25, 3.0)), ~inside

    def stretch(lo: int, hi: int, earliest: int) -> slice:
        length = int(rng.integers(lo, hi + 1))
        start = int(rng.integers(earliest, earliest + 120))
        return slice(start, start + length)

    if family == "stop":
        at = 60
        for _ in range(3):
            s = stretch(30, 60, at)
            speeds[s], inside[s] = 0.0, True
            at = s.stop + 60
    elif family == "crawl":
        s = stretch(60, 100, 60)
        speeds[s], inside[s] = rng.uniform(0.25, 0.4), True
    elif family == "burst":
        s = stretch(40, 80, 60)
        speeds[s], inside[s] = rng.uniform(2.5, 4.0), True
    elif family == "reverse":
        length = int(rng.integers(60, 151))
        back = rng.uniform(*REVERSE_SPEEDS)
        start = int(rng.integers(int(length * back) + 20, int(length * back) + 140))  # far enough from the start
        speeds[start:start + length], inside[start:start + length] = -back, True
    else:
        raise ValueError(f"unknown motion family {family!r}; choose one of {', '.join(FAMILIES)}")
    return speeds, inside


def query_positions(family: str, n_frames: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference position (frame) of every query frame until the route's end, and which
    frames are inside the motion."""
    speeds, inside = motion_profile(family, 6 * n_frames, seed)
    x = np.concatenate([[0.0], np.cumsum(speeds)])[:len(speeds)]
    past = np.flatnonzero((x > n_frames - 1) | (x < 0))
    end = int(past[0]) if len(past) else len(x)
    return np.floor(x[:end] + 0.5).astype(np.int64), inside[:end]


def shared_stops(reference: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Soft ground truth from features of two synchronous traverses: ``(lo, hi)`` per
    position, the reference frames a match for that position may land on. Where both
    traverses stand still (both frame pairs still, :data:`STILL_FRACTION`), the whole
    stretch shows one place: ``lo``/``hi`` are its ends; elsewhere the position itself.
    The tolerance is added by the caller."""
    n = min(len(reference), len(query))
    still = np.ones(n - 1, bool)
    for f in (reference[:n], query[:n]):
        change = np.abs(f[1:].astype(np.float64) - f[:-1]).mean(axis=1)
        still &= change < STILL_FRACTION * np.median(change)
    lo, hi = np.arange(n), np.arange(n)
    i = 0
    while i < n - 1:
        if not still[i]:
            i += 1
            continue
        j = i
        while j < n - 1 and still[j]:
            j += 1
        lo[i:j + 1], hi[i:j + 1] = i, j  # pairs i..j-1 still: frames i..j show one place
        i = j
    return np.stack([lo, hi], axis=1)


def recall_at_100_precision(correct: np.ndarray, confidence: np.ndarray) -> float:
    """Share of all queries accepted above the most confident wrong match (ties with it
    rejected): the recall at which precision is still 100 %."""
    wrong = confidence[~correct]
    if len(wrong) == 0:
        return float(correct.mean())
    return float((correct & (confidence > wrong.max())).sum() / len(correct))


# ---------------------------------------------------------------------------------------
# the data: features and the enhanced matrix of one part, with the preset's settings
# ---------------------------------------------------------------------------------------
def preset() -> dict[str, Any]:
    """The seqslam section of ``configs/nordland.yaml`` over the parameter defaults."""
    import yaml

    from placeloc.seqslam.params import SeqSLAMParams

    with open(CONFIGS / "nordland.yaml") as fh:
        section = yaml.safe_load(fh)["seqslam"]
    return {**dataclasses.asdict(SeqSLAMParams()), **section}


def part(lo: int, hi: int) -> dict[str, Any]:
    """Features of nordland-dev frames lo..hi-1 (summer, winter), the differences
    ``D[summer frame, winter frame]`` and their enhancement, query-major
    (``E[winter frame, summer frame]``), and the soft ground truth."""
    from placeloc.core.images import list_images
    from placeloc.seqslam.comparisons import difference_block
    from placeloc.seqslam.features import image_features
    from placeloc.seqslam.search import enhance

    p = preset()
    nd = shared_data_dir() / "nordland-dev"
    feats = {}
    for season in ("summer", "winter"):
        paths = [str(x) for x in list_images(nd / season).paths[lo:hi]]
        feats[season], _, _, _ = image_features(
            paths, on_error="raise", thumbnail_size=tuple(p["thumbnail"]), comparison=p["comparison"], patch=p["patch"],
            normalisation=p["normalisation"], gaussian_sigma=p["gaussian_sigma"], ocm_epsilon=p["ocm_epsilon"])
    d = difference_block(feats["summer"], feats["winter"], p["comparison"])
    return {"difference": d, "enhanced": np.ascontiguousarray(enhance(d, int(p["enhance_window"])).T),
            "truth": shared_stops(feats["summer"], feats["winter"]), "query_features": feats["winter"],
            "reference_features": feats["summer"]}


def kept_reference(data: dict[str, Any], comparison: str, enhance_window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For ``collapse_stops``: the summer frames kept (:func:`placeloc.seqslam.matching.standing_runs`
    with ``comparison``), every summer frame's run among them, and the differences to the
    kept frames alone, enhanced as ``localize`` enhances them (over the kept references,
    ``enhance_window``), query-major; computed once per comparison and window."""
    from placeloc.seqslam.matching import standing_runs
    from placeloc.seqslam.search import enhance

    key = ("kept_reference", comparison, int(enhance_window))
    if key not in data:
        ref_first, ref_run_of = standing_runs(data["reference_features"], comparison)
        data[key] = (ref_first, ref_run_of,
                     np.ascontiguousarray(enhance(data["difference"][ref_first], int(enhance_window)).T))
    return data[key]


def search(data: dict[str, Any], pos: np.ndarray, setting: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Best reference and confidence per query of the resampled query ``pos``, with the
    preset's settings overridden by ``setting`` (``v_auto``, ``collapse_stops`` and
    ``backward_paths`` as ``localize`` applies them: the search over every frame, then
    the collapsed search and :func:`placeloc.seqslam.matching.stop_answers`)."""
    from placeloc.seqslam.matching import search_velocities, standing_runs, stop_answers
    from placeloc.seqslam.search import confidence, sequence_search

    p = {**preset(), **setting}

    def run(et: np.ndarray, n_ref: int, backward: bool) -> tuple[np.ndarray, np.ndarray]:
        vels = search_velocities(p["v_min"], p["v_max"], p["v_step"], p["v_auto"], n_ref, len(et), p["v_reverse"])
        best, scores = sequence_search(et, 0, len(et), int(p["ds"]), vels, p["search"], int(p["enhance_window"]),
                                       int(p["top_k"]), None, 0, shape=p["sequence_shape"], edges=p["edges"],
                                       speed_change_cost=p["speed_change_cost"], stop_cost=p["stop_cost"],
                                       reverse_cost=p["reverse_cost"], backward_paths=backward,
                                       backward_v_max=p["backward_v_max"])
        return best[:, 0], confidence(scores)

    et = np.ascontiguousarray(data["enhanced"][pos])
    best, conf = run(et, et.shape[1], bool(p["backward_paths"]))
    if p["collapse_stops"]:
        first, run_of = standing_runs(data["query_features"][pos], p["comparison"])
        ref_first, ref_run_of, enhanced_kept = kept_reference(data, p["comparison"], p["enhance_window"])
        kept_best, kept_conf = run(np.ascontiguousarray(enhanced_kept[pos[first]]), len(ref_first), False)
        stop_best = np.where(kept_best >= 0, ref_first[np.maximum(kept_best, 0)], -1)[run_of]
        take = stop_answers(best, stop_best, first, run_of, ref_run_of)
        best, conf = np.where(take, stop_best, best), np.where(take, kept_conf[run_of], conf)
    return best, conf


def score(data: dict[str, Any], pos: np.ndarray, inside: np.ndarray, best: np.ndarray,
          conf: np.ndarray) -> dict[str, float]:
    """R@1 (soft ground truth), recall at 100 % precision, and R@1 inside the motion."""
    lo, hi = data["truth"][pos, 0] - TOLERANCE, data["truth"][pos, 1] + TOLERANCE
    ok = (best >= lo) & (best <= hi)
    return {"recall_at_1": float(ok.mean()), "recall_at_100_precision": recall_at_100_precision(ok, conf),
            "recall_at_1_inside": float(ok[inside].mean()), "recall_at_1_exact_truth": float((np.abs(best - pos) <= TOLERANCE).mean())}


def run_setting(data: dict[str, Any], n_frames: int, setting: dict[str, Any], seeds: tuple[int, ...],
                families: tuple[str, ...] = FAMILIES, quiet: bool = True) -> dict[str, list[dict[str, float]]]:
    """Every family (one profile for steady, one per seed otherwise) -> its scores per seed."""
    out: dict[str, list[dict[str, float]]] = {}
    for fam in families:
        for seed in ((seeds[0],) if fam == "steady" else seeds):
            pos, inside = query_positions(fam, n_frames, seed)
            t0 = time.perf_counter()
            best, conf = search(data, pos, setting)
            s = {**score(data, pos, inside, best, conf), "seconds": time.perf_counter() - t0, "seed": seed,
                 "n_queries": len(pos)}
            out.setdefault(fam, []).append(s)
            if not quiet:
                print(f"  {fam:8s} seed {seed:3d}: R@1 {s['recall_at_1']:.3f} inside {s['recall_at_1_inside']:.3f} "
                      f"R@100P {s['recall_at_100_precision']:.3f} ({len(pos)} queries, {s['seconds']:.1f} s)", flush=True)
    return out


def _cell(rows: list[dict[str, float]], key: str) -> str:
    v = [r[key] for r in rows]
    return f"{v[0]:.3f}" if len(v) == 1 else f"{np.median(v):.3f} ({min(v):.3f}-{max(v):.3f})"


# ---------------------------------------------------------------------------------------
# choosing the costs on frames 1-600; reporting on 601-1200
# ---------------------------------------------------------------------------------------
def tune_grid() -> list[dict[str, Any]]:
    """The path models compared on the tuning part (all flexible, ds 120, v_step 0.1,
    ``v_auto``): moving only over the old speeds (0.5-2.0) and over crawls to bursts
    (0.3-4.0); the latter allowed to back out (to -1.0) at two costs of driving
    backwards; the whole model, standing still too (v_min 0); and 0.3-4.0 with the frames
    of the query's standing runs answered by a search over both traverses' runs collapsed
    (``collapse_stops``), with a family of paths driven backwards throughout
    (``backward_paths``) at three costs, and with both; all of these with the whole
    backward family (``backward_v_max`` :data:`ALL_SPEEDS`). Then the preset with the
    backward family limited to 1.0, 1.5 and 2.0 (its cost is proportional to its speeds)."""
    grid: list[dict[str, Any]] = [{"v_min": 0.5, "v_max": 2.0}, {"v_min": 0.3, "v_max": 4.0}]
    grid += [{"v_min": 0.3, "v_max": 4.0, "v_reverse": 1.0, "reverse_cost": r} for r in (0.0, 0.25)]
    grid += [{"v_min": 0.0, "v_max": 4.0, "v_reverse": 1.0, "reverse_cost": 0.0}]
    grid += [{"v_min": 0.3, "v_max": 4.0, "collapse_stops": True}]
    grid += [{"v_min": 0.3, "v_max": 4.0, "backward_paths": True, "reverse_cost": r} for r in (0.0, 0.25, 0.5)]
    grid += [{"v_min": 0.3, "v_max": 4.0, "collapse_stops": True, "backward_paths": True, "reverse_cost": r}
             for r in (0.0, 0.25, 0.5)]
    grid += [{"v_min": 0.3, "v_max": 4.0, "collapse_stops": True, "backward_paths": True, "reverse_cost": 0.0,
              "backward_v_max": v} for v in (1.0, 1.5, 2.0)]
    return [{"v_auto": True, "stop_cost": 2.0, "reverse_cost": 0.5, "v_reverse": 0.0, "collapse_stops": False,
             "backward_paths": False, "backward_v_max": ALL_SPEEDS, **g} for g in grid]


def backward_speeds(row: dict[str, Any]) -> int:
    """Speeds of the backward family a setting searches (0 without ``backward_paths``):
    what it adds to the search's cost, in forward families' speeds."""
    from placeloc.seqslam.search import backward_velocities, velocities

    if not row.get("backward_paths"):
        return 0
    return len(backward_velocities(velocities(row["v_min"], row["v_max"], 0.1), row.get("backward_v_max", ALL_SPEEDS)))


def choose(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The rule: among settings keeping steady R@1 >= 0.99 and steady recall at 100 %
    precision >= 0.99 (the issue's goal for confidence), the best worst family (the
    lowest median R@1 of any motion family); within 0.005 of it, the best median over
    the motion families; within 0.005 of that too, the best worst seed (the lowest R@1 of
    any family and seed), and within 0.005 of that, the fewest backward speeds (the
    cheaper search). The last two ties were added 2026-11-26 for ``backward_v_max``; no
    earlier pick had a second row within both earlier bands. The fewest speeds was
    written before the tuning rows were measured; the worst seed before it, after they
    were read (docs/seqslam.md says so): a median over three seeds cannot see a loss on
    one, and with the fewest speeds straight after the median the limit 1.0 won and lost
    the one tuning seed that reverses faster than 1.0x (seed 1, 1.45x: 0.915 -> 0.851).
    The rule's second step, on the whole route, is :func:`whole`."""
    ok = [r for r in rows if r["steady"] >= 0.99 and r.get("steady_r100p", 1.0) >= 0.99] or rows
    best = max(r["worst_family"] for r in ok)
    near = [r for r in ok if r["worst_family"] >= best - 0.005]
    top = max(round(r["median"], 3) for r in near)
    tied = [r for r in near if round(r["median"], 3) >= top - 0.005]
    floor = max(round(r["worst"], 3) for r in tied)
    tied = [r for r in tied if round(r["worst"], 3) >= floor - 0.005]
    return min(tied, key=lambda r: (backward_speeds(r), -round(r["median"], 3)))


def _fastest(v: float) -> str:
    return "all" if v >= ALL_SPEEDS else f"{v:g}"


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def tune(out: Path, quick: bool = False, quiet: bool = False) -> dict[str, Any]:
    n = 450 if quick else 600
    data = part(0, n)
    seeds = TUNE_SEEDS[:2] if quick else TUNE_SEEDS
    rows = []
    # rows already measured (one JSON line each) are read back, so a stopped tuning resumes
    done_path = out / "tune_rows.jsonl"
    done = {}
    if done_path.exists():
        for line in done_path.read_text().splitlines():
            row = json.loads(line)
            done[json.dumps({k: row[k] for k in tune_grid()[0]}, sort_keys=True)] = row
    out.mkdir(parents=True, exist_ok=True)
    for setting in tune_grid():
        key = json.dumps(setting, sort_keys=True)
        if key in done and not quick:
            rows.append(done[key])
            continue
        r = run_setting(data, n, setting, seeds, quiet=True)
        motion = [x["recall_at_1"] for fam in FAMILIES[1:] for x in r[fam]]
        row = {**setting, "steady": r["steady"][0]["recall_at_1"],
               "steady_r100p": r["steady"][0]["recall_at_100_precision"],
               "steady_exact": r["steady"][0]["recall_at_1_exact_truth"], "worst": min(motion),
               "median": float(np.median([np.median([x["recall_at_1"] for x in r[f]]) for f in FAMILIES[1:]]))}
        row.update({f"{fam}_median": float(np.median([x["recall_at_1"] for x in r[fam]])) for fam in FAMILIES})
        row.update({f"{fam}_inside": float(np.median([x["recall_at_1_inside"] for x in r[fam]])) for fam in MOTIONS})
        row["worst_family"] = min(row[f"{fam}_median"] for fam in FAMILIES[1:])
        rows.append(row)
        if not quick:
            with open(done_path, "a") as fh:
                fh.write(json.dumps(row) + "\n")
        if not quiet:
            print(json.dumps({k: round(v, 3) for k, v in row.items()}), flush=True)
    chosen = choose(rows)
    lines = [f"R@1 median over seeds {', '.join(map(str, seeds))} (inside the motion in brackets)\n",
             "| v | collapse_stops | backward_paths (fastest) | reverse_cost | steady (R@100P) | "
             "steady, exact +-2 truth | worst seed | " + " | ".join(FAMILIES[1:]) + " |",
             "|---|---|---|---|---|---|---|" + "---|" * len(FAMILIES[1:])]
    for r in rows:
        lines.append(f"| {r['v_min']:g}..{r['v_max']:g}, back to -{r['v_reverse']:g} | {_yes(r['collapse_stops'])} | "
                     f"{_yes(r['backward_paths'])}"
                     + (f" ({_fastest(r.get('backward_v_max', ALL_SPEEDS))})" if r["backward_paths"] else "")
                     + f" | {r['reverse_cost']:g} | "
                     f"{r['steady']:.3f} ({r.get('steady_r100p', float('nan')):.3f}) | "
                     f"{r.get('steady_exact', float('nan')):.3f} | {r['worst']:.3f} | "
                     + " | ".join(f"{r[f + '_median']:.3f}" + (f" ({r[f + '_inside']:.3f})" if f in MOTIONS else "")
                                  for f in FAMILIES[1:]) + " |")
    lines.append(f"\nchosen (rule in `choose`): v {chosen['v_min']:g}..{chosen['v_max']:g}, v_reverse "
                 f"{chosen['v_reverse']:g}, reverse_cost {chosen['reverse_cost']:g}, collapse_stops "
                 f"{_yes(chosen['collapse_stops'])}, backward_paths {_yes(chosen['backward_paths'])}"
                 + (f" up to {_fastest(chosen['backward_v_max'])}" if chosen["backward_paths"] else ""))
    out.mkdir(parents=True, exist_ok=True)
    (out / "tune.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return chosen


def report_settings() -> dict[str, dict[str, Any]]:
    """The preset as shipped (``collapse_stops``, ``backward_paths`` at ``reverse_cost``
    0, the backward family up to ``backward_v_max``); with every backward speed (the
    previous preset); without ``collapse_stops``, without ``backward_paths``, and
    without both (the preset before those); the flexible preset before that; straight
    lines over the preset's own speeds and window (what ``sequence_shape: trajectory``
    gives); and the whole path model (standing still and backing out too) that tuning
    turned down."""
    off = {"collapse_stops": False, "backward_paths": False}
    return {
        "preset (configs/nordland.yaml): flexible 0.3x-4.0x, v_auto, collapse_stops, backward_paths": {},
        "preset with the whole backward family (the previous preset)": {"backward_v_max": ALL_SPEEDS},
        "preset without collapse_stops": {"collapse_stops": False},
        "preset without backward_paths": {"backward_paths": False},
        "preset without either switch": off,
        "flexible, v 0.5-2.0, no v_auto, no switches": {"v_min": 0.5, "v_max": 2.0, "v_auto": False, **off},
        "straight trajectories, same speeds and window": {"sequence_shape": "trajectory", **off},
        "preset standing still and backing out (v_min 0, v_reverse 1, reverse_cost 0), no switches": {
            "v_min": 0.0, "v_reverse": 1.0, "reverse_cost": 0.0, **off},
    }


def report(out: Path, quick: bool = False, quiet: bool = False, seeds: tuple[int, ...] = REPORT_SEEDS) -> Path:
    """Every setting of :func:`report_settings` on frames 601-1200 (held out), each family
    with ``seeds``. Writes ``report.md`` and ``summary.json``."""
    lo, hi = (600, 1050) if quick else (600, 1200)
    data = part(lo, hi)
    seeds = seeds[:2] if quick else seeds
    settings = report_settings()
    if quick:
        settings = dict(list(settings.items())[:1])
    summary: dict[str, Any] = {}
    lines = [f"# SeqSLAM following stops, crawls, bursts and reversing: nordland-dev frames {lo + 1}-{hi} (held out)\n",
             f"R@1 (+-{TOLERANCE} frames; shared stops scored softly); median (min-max) over seeds "
             f"{', '.join(map(str, seeds))}; inside = the frames of the motion itself; "
             "R@100P = recall at 100 % precision.\n"]
    for name, setting in settings.items():
        if not quiet:
            print(name, flush=True)
        r = run_setting(data, hi - lo, setting, seeds, quiet=quiet)
        summary[name] = r
        lines += [f"## {name}\n", "| query | R@1 | R@1 inside | R@100P | R@1, exact +-2 truth | queries |",
                  "|---|---|---|---|---|---|"]
        for fam in FAMILIES:
            lines.append(f"| {fam} | {_cell(r[fam], 'recall_at_1')} | {_cell(r[fam], 'recall_at_1_inside')} | "
                         f"{_cell(r[fam], 'recall_at_100_precision')} | {_cell(r[fam], 'recall_at_1_exact_truth')} | "
                         f"{int(np.median([x['n_queries'] for x in r[fam]]))} |")
        seconds = sum(x["seconds"] for rows in r.values() for x in rows)
        base = sum(x["seconds"] for rows in summary[next(iter(settings))].values() for x in rows)
        lines.append(f"\nsearch time, every query of every family: {seconds:.1f} s wall "
                     f"({seconds / base:.2f}x the first setting's, in this run)\n")
    out.mkdir(parents=True, exist_ok=True)
    write_summary(out, summary)
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return out / "report.md"


def whole(out: Path, quiet: bool = True) -> Path:
    """The rule's last check: ``configs/nordland.yaml`` on the whole of nordland-dev,
    scored as the config scores it (+-2 frames of the synchronous frame), and the same
    without ``collapse_stops`` and with the whole backward family (``backward_v_max``
    :data:`ALL_SPEEDS`); the preset keeps a change only if R@1 and recall at 100 % precision fall by at
    most :data:`WHOLE_ROUTE_SLACK`. Writes ``whole.md``."""
    from placeloc.core.config import load_config
    from placeloc.core.runner import read_metrics, run_all

    out = Path(out).resolve()
    rows = {"preset": [], "preset without collapse_stops": ["seqslam.collapse_stops=false"],
            "preset with the whole backward family": [f"seqslam.backward_v_max={ALL_SPEEDS:g}"]}
    metrics = {}
    for name, overrides in rows.items():
        run_dir = out / ("whole-" + name.replace(" ", "-"))
        run_all(load_config(CONFIGS / "nordland.yaml", overrides + ["plots=false"]), run_dir, quiet=quiet)
        metrics[name] = read_metrics(run_dir)
    keys = ("recall_at_1", "auc_pr", "recall_at_100_precision")
    lines = ["# configs/nordland.yaml on the whole of nordland-dev (1200 + 1200 frames), synchronous +-2 truth\n",
             "| run | R@1 | AUC | R@100P |", "|---|---|---|---|"]
    lines += [f"| {name} | " + " | ".join(f"{m[k]:.3f}" for k in keys) + " |" for name, m in metrics.items()]
    now = metrics["preset"]
    for change, against in (("collapse_stops", "preset without collapse_stops"),
                            ("the limited backward family (backward_v_max)", "preset with the whole backward family")):
        fall = {k: metrics[against][k] - now[k] for k in ("recall_at_1", "recall_at_100_precision")}
        verdict = "passes" if max(fall.values()) <= WHOLE_ROUTE_SLACK else "fails"
        lines.append(f"\n{change} {verdict} the check: R@1 falls by {fall['recall_at_1']:.4f}, recall at 100 % "
                     f"precision by {fall['recall_at_100_precision']:.4f} (at most {WHOLE_ROUTE_SLACK} allowed)")
    out.mkdir(parents=True, exist_ok=True)
    (out / "whole.md").write_text("\n".join(lines) + "\n")
    return out / "whole.md"


def main(out_dir: Path | str = Path("runs/seqslam-motion"), quick: bool = False, quiet: bool = False,
         seeds: tuple[int, ...] = REPORT_SEEDS) -> Path:
    """The held-out report (``report.md``); needs nordland-dev in the shared data folder."""
    data = shared_data_dir()
    if data is None or not (data / "nordland-dev").is_dir():
        raise SystemExit("needs nordland-dev in the shared data folder (../shared/data or $PLACELOC_SHARED_DATA)")
    path = report(Path(out_dir), quick=quick, quiet=quiet, seeds=seeds)
    if not quiet:
        print(path.read_text())
    return path


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", nargs="?", choices=("report", "tune", "whole"), default="report")
    ap.add_argument("--out", type=Path, default=Path("runs/seqslam-motion"))
    ap.add_argument("--quick", action="store_true", help="450 frames, two seeds, the preset only (CI)")
    ap.add_argument("--seeds", choices=("200-204", "100-104"), default="200-204",
                    help="held-out profiles: 200-204 (unseen before the last choice) or 100-104 (the earlier rounds')")
    ap.add_argument("--reverse-speeds", choices=("0.5-1.5", "0.5-1.0"), default="0.5-1.5",
                    help="the reverse family's backward speeds: 0.5-1.5 (now) or 0.5-1.0 (the rounds before)")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args()
    REVERSE_SPEEDS = tuple(float(x) for x in args.reverse_speeds.split("-"))  # type: ignore[assignment]
    if args.what == "tune":
        tune(args.out, quick=args.quick, quiet=args.quiet)
    elif args.what == "whole":
        if shared_data_dir() is None or not (shared_data_dir() / "nordland-dev").is_dir():
            raise SystemExit("needs nordland-dev in the shared data folder (../shared/data or $PLACELOC_SHARED_DATA)")
        print(whole(args.out, quiet=args.quiet).read_text())
    else:
        main(args.out, quick=args.quick, quiet=args.quiet,
             seeds=REPORT_SEEDS if args.seeds == "200-204" else EARLIER_REPORT_SEEDS)
