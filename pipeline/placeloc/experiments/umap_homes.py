"""``placeloc experiment umap-homes``: the whole-panorama defaults chosen on development
homes by a stated rule, then reported on other homes, each for several grid origins.

1. Development homes (``placeloc synth home``, seeds 0-2, 20 panoramas each), each with the
   grid's origin shifted by 0, 0.1, 1/3, 0.55 and 2/3 of a step (:data:`ORIGINS`): every setting of
   :data:`SWEEP` runs the pipeline (the settings differ in localize keys only, so one run
   folder per home and origin re-runs localize and evaluate alone); the rule: the setting
   with the highest mean over the homes of each home's worst origin (its share within 1 m
   and 30 degrees at the origin where it did worst: the goal is a share "for any grid
   origin") wins; among settings within one panorama of one home (1/60) of it, the one whose
   answers move least with the grid's origin (the fewest frames whose answers over the
   origins lie more than 0.1 m apart, then more than 0.05 m: :func:`answer_moves`), then the
   cheapest (fewest refined candidates), then the earlier in :data:`SWEEP` (the plainer).
   Until 2026-11-27 the first criterion was the mean share over all fifteen runs; on the
   sweep's settings before ``refine_final_ties`` both choose the same one (docs/umap.md).
2. Test homes (seeds 20-24, never run before the defaults were fixed): the defaults at the
   same five origins; worst, median and best share within 1 m and 30 degrees over the
   25 runs, the worst origin per home, the answers that move with the origin, and the line
   statistics beside the real home's.
3. Why each wrong test answer at the first origin is wrong (:func:`wrong_answer_causes`):
   the search again over the grid within 1 m of the truth only; where its best pose scores
   below the answer the score prefers the wrong place, else the search missed the truth.
4. The test homes again with each photo's room named (``umap.room_hints``, the room at its
   true position: :func:`true_rooms`), as whoever took the photos knows it.

Writes ``OUT/dev.md``, ``OUT/table.md`` and ``OUT/summary.json``. Each run folder's
``index.h5`` (the map spectra, about 1.2 GB a home) is deleted once every setting has run at
its home and origin: kept, the 40 folders of a full run held 28 GB (a run here stopped on a
full disk after 13 minutes). A re-run draws an index again where it needs one.
"""

from __future__ import annotations

import csv
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.artifacts import atomic_open
from placeloc.core.config import load_config
from placeloc.core.runner import STAGES, read_metrics, run_stage
from placeloc.core.safe_io import read_run_table
from placeloc.experiments import write_summary
from placeloc.experiments.umap import home_table
from placeloc.geometry.floorplan import load_plan, model_bounds, rooms_at
from placeloc.synth import generate
from placeloc.umap.stages import load_model

log = logging.getLogger("placeloc")

DEV_SEEDS = (0, 1, 2)
TEST_SEEDS = (20, 21, 22, 23, 24)
PANORAMAS = 20
GRID_STEP_M = 0.25            # umap.grid.step_m's default, the step the origins are shifted by
# 0, 1/3 and 2/3 give the beam's steps (a sixth of a grid step and finer) the same lattice of
# points, so their answers agree more than the grid's origin deserves; 0.1 and 0.55 do not
ORIGINS = (0.0, 0.1, 1.0 / 3.0, 0.55, 2.0 / 3.0)
# name -> umap.panorama settings; refine_candidates is the cost (8 renders each per panorama)
# the rounds before the precision half's rows (every row counts) and the beam's square
# (the beam climbs by 8 neighbours)
_PLAIN = {"orientation_bins": 1}           # the rounds before directions (umap.panorama.orientation_bins)
_ALL_ROWS = {"precision_polar_deg": 90.0, **_PLAIN}
_CLIMB = {"refine_square": 1, **_ALL_ROWS}
_SWEEP: dict[str, dict[str, Any]] = {
    "plain chamfer, 16 cells": {"chamfer_chance": "none", "refine_candidates": 16, "solid_angle": False, **_CLIMB},
    "area-corrected chamfer, 16 cells": {"chamfer_chance": "area", "refine_candidates": 16, "solid_angle": False, **_CLIMB},
    "yaw-corrected chamfer, 16 cells": {"chamfer_chance": "yaw", "refine_candidates": 16, "solid_angle": False, **_CLIMB},
    "plain chamfer, 32 cells": {"chamfer_chance": "none", "refine_candidates": 32, "solid_angle": False, **_CLIMB},
    "area-corrected chamfer, 32 cells": {"chamfer_chance": "area", "refine_candidates": 32, "solid_angle": False, **_CLIMB},
    # rows weighted by the solid angle they cover (umap.panorama.solid_angle)
    "solid-angle chamfer, 16 cells": {"chamfer_chance": "none", "refine_candidates": 16, "solid_angle": True, **_CLIMB},
    "solid-angle chamfer, 32 cells": {"chamfer_chance": "none", "refine_candidates": 32, "solid_angle": True, **_CLIMB},
    "solid-angle area-corrected chamfer, 32 cells": {"chamfer_chance": "area", "refine_candidates": 32, "solid_angle": True,
                                                     **_CLIMB},
    # query texture weighted down (umap.panorama.texture_radius_px)
    "solid-angle chamfer, texture r 1, 32 cells": {"refine_candidates": 32, "solid_angle": True, "texture_radius_px": 1,
                                                   **_CLIMB},
    "solid-angle chamfer, texture r 2, 32 cells": {"refine_candidates": 32, "solid_angle": True, "texture_radius_px": 2,
                                                   **_CLIMB},
    # the beam's cells searched whole (umap.panorama.refine_square)
    "solid-angle chamfer, 16 cells, beam's cells whole": {"refine_candidates": 16, "solid_angle": True, "refine_square": 3,
                                                          **_ALL_ROWS},
    "solid-angle chamfer, 32 cells, beam's cells whole": {"refine_candidates": 32, "solid_angle": True, "refine_square": 3,
                                                          **_ALL_ROWS},
    "solid-angle chamfer, texture r 1, 32 cells, beam's cells whole": {"refine_candidates": 32, "solid_angle": True,
                                                                       "texture_radius_px": 1, "refine_square": 3,
                                                                       **_ALL_ROWS},
    "solid-angle chamfer, texture r 2, 32 cells, beam's cells whole": {"refine_candidates": 32, "solid_angle": True,
                                                                       "texture_radius_px": 2, "refine_square": 3,
                                                                       **_ALL_ROWS},
    # the precision half over the rows within so many degrees of the horizon only
    # (umap.panorama.precision_polar_deg), the milder first
    **{f"solid-angle chamfer, precision within {deg} deg, 32 cells, beam's cells whole":
       {"refine_candidates": 32, "solid_angle": True, "refine_square": 3, "precision_polar_deg": float(deg), **_PLAIN}
       for deg in (80, 75, 70, 65)},
    # each half a mean log likelihood ratio against clutter (umap.panorama.chamfer_chance
    # likelihood), at three clutter shares
    **{f"solid-angle likelihood chamfer, clutter share {share}, precision within 75 deg, 32 cells, beam's cells whole":
       {"chamfer_chance": "likelihood", "clutter_share": share, "refine_candidates": 32, "solid_angle": True,
        "refine_square": 3, "precision_polar_deg": 75.0, **_PLAIN}
       for share in (0.2, 0.5, 0.8)},
    # the search: candidates as distinct places (no two within 0.4 m: a taken point's 8 grid
    # neighbours left out), every candidate climbing once before the beam
    # (umap.panorama.refine_separation_m, refine_climb)
    "solid-angle chamfer, precision within 75 deg, 32 cells 0.4 m apart, beam's cells whole":
        {"refine_candidates": 32, "solid_angle": True, "refine_square": 3, "precision_polar_deg": 75.0,
         "refine_separation_m": 0.4, **_PLAIN},
    "solid-angle chamfer, precision within 75 deg, 32 cells each climbing once, beam's cells whole":
        {"refine_candidates": 32, "solid_angle": True, "refine_square": 3, "precision_polar_deg": 75.0, "refine_climb": 1,
         **_PLAIN},
    "solid-angle chamfer, precision within 75 deg, 32 cells 0.4 m apart each climbing once, beam's cells whole":
        {"refine_candidates": 32, "solid_angle": True, "refine_square": 3, "precision_polar_deg": 75.0,
         "refine_separation_m": 0.4, "refine_climb": 1, **_PLAIN},
    # the oriented (directional) chamfer score: a line pixel near only to the other side's
    # lines of its direction bin or within spread bins of it (umap.panorama.orientation_bins,
    # orientation_spread), the fewer bins first
    **{f"oriented chamfer, {bins} bins, spread {spread}, precision within 75 deg, 32 cells, beam's cells whole":
       {"refine_candidates": 32, "solid_angle": True, "refine_square": 3, "precision_polar_deg": 75.0,
        "orientation_bins": bins, "orientation_spread": spread}
       for bins, spread in ((2, 0), (4, 1), (6, 1), (8, 1), (8, 2))},
}
# the rounds before the final search (umap.panorama.refine_final_m) ran without it
SWEEP: dict[str, dict[str, Any]] = {name: {"refine_final_m": 0.0, **over} for name, over in _SWEEP.items()}
_ORIENTED6 = {"refine_candidates": 32, "solid_angle": True, "refine_square": 3, "precision_polar_deg": 75.0,
              "orientation_bins": 6, "orientation_spread": 1}
# the beam's best pose climbing on by a pattern search down to 0.01 m, from the beam's answer
# at its finest step, or from the plan's own lattice of 0.08 m (refine_final_start_m); the
# share within 1 m and 30 deg ties them with the row without it on the development homes,
# and the answers that move with the grid's origin chose (docs/umap.md)
SWEEP.update({
    "oriented chamfer, 6 bins, spread 1, precision within 75 deg, 32 cells, beam's cells whole, final search from the "
    "beam's answer": {**_ORIENTED6, "refine_final_m": 0.01, "refine_final_start_m": 0.0, "refine_final_radius_m": 0.0},
    "oriented chamfer, 6 bins, spread 1, precision within 75 deg, 32 cells, beam's cells whole, final search from the "
    "plan's lattice of 0.08 m": {**_ORIENTED6, "refine_final_m": 0.01, "refine_final_start_m": 0.08,
                                 "refine_final_radius_m": 0.0},
    # from the best point of the plan's lattice of 0.04 m within 0.24 m of the beam's pose, its
    # end the answer (refine_final_radius_m)
    "oriented chamfer, 6 bins, spread 1, precision within 75 deg, 32 cells, beam's cells whole, final search from the "
    "best point of the plan's lattice within 0.24 m": {**_ORIENTED6, "refine_final_m": 0.01, "refine_final_start_m": 0.08,
                                                        "refine_final_radius_m": 0.24},
    # and the same search from every pose of the beam within 0.02 (the doubtful margin of its day) of its
    # best, the best end the answer (refine_final_ties)
    "oriented chamfer, 6 bins, spread 1, precision within 75 deg, 32 cells, beam's cells whole, final search from the "
    "best point of the plan's lattice within 0.24 m, near-tied places too": {
        **_ORIENTED6, "refine_final_m": 0.01, "refine_final_start_m": 0.08, "refine_final_radius_m": 0.24,
        "refine_final_ties": 0.02},
})
# the settings before refine_final_ties finished the beam's best pose only
for _over in SWEEP.values():
    _over.setdefault("refine_final_ties", 0.0)
# refine_beam_within is not swept: every row runs with its default, a cut of the search's
# cost whose gap was measured apart (it changes no answer of the chosen row on any generated
# home; docs/umap.md, "A beam of the places that can still win")


def _home(root: Path, seed: int) -> Path:
    d = root / "data" / f"home-seed{seed}-n{PANORAMAS}"
    if not (d / "poses.csv").is_file():
        log.info("generating the synthetic home (seed %d) in %s", seed, d)
        generate("home", d, seed=seed, panoramas=PANORAMAS)
    return d


def shifted_grid(plan: Path, frac: float, step: float = GRID_STEP_M) -> dict[str, list[float]]:
    """``umap.grid`` x and y of the model's own grid (its plan bounds, the first point half a
    step in) with the origin moved by ``frac`` of a step along both axes."""
    lo, hi = model_bounds(load_model(str(plan)))
    return {"x": [float(lo[0]) + step * (0.5 + frac), float(hi[0]), step],
            "y": [float(lo[1]) + step * (0.5 + frac), float(hi[1]), step]}


def _run(root: Path, name: str, data: Path, panorama: dict[str, Any], frac: float, quiet: bool,
         plan: Path | None = None, grid: dict[str, Any] | None = None, room_hints: Path | None = None,
         reuse: Sequence[Path] = ()) -> dict[str, Any]:
    # only what a user of a real home gives (the model, the images, the query kind, the
    # truth) and the grid origin; ``plan``: another file of the same plan (default the home's
    # own floor_plan.yaml), so that runs of one home's variants share a map and index;
    # ``grid``: umap.grid settings beside the origin's x and y (the ceilings searched);
    # ``room_hints``: each photo's room named (umap.room_hints); ``reuse``: run folders whose
    # stages with the same stamp are linked, not computed again (the map and its index)
    plan = plan or data / "floor_plan.yaml"
    cfg = load_config(data={"method": "umap", "query": {"images": str(data / "panoramas")},
                            "ground_truth": {"kind": "poses", "path": str(data / "poses.csv")},
                            "umap": {"model": str(plan), "query_kind": "panorama", "panorama": panorama,
                                     "grid": {**shifted_grid(plan, frac), **(grid or {})},
                                     **({"room_hints": str(room_hints)} if room_hints else {})},
                            "executor": {"workers": 1}, "plots": False}, base_dir=root)
    run_stage(cfg, root / name, STAGES[-1], quiet=quiet, reuse=reuse)
    return {**read_metrics(root / name), "line_stats": json.loads((data / "line_stats.json").read_text()), "origin": frac}


def true_rooms(data: Path) -> Path:
    """``data/rooms.csv``: each panorama's room, read off the plan at its true position (a
    :mod:`placeloc.umap.room_hints` file: what the person who took the photos knows)."""
    plan = load_plan(data / "floor_plan.yaml")
    rows = list(csv.DictReader(open(data / "poses.csv", newline="")))
    rooms = rooms_at(np.array([[float(r["x"]), float(r["y"])] for r in rows]),
                     [np.asarray(r["polygon"], float) for r in plan["rooms"]], [str(r["name"]) for r in plan["rooms"]])
    out = data / "rooms.csv"
    with atomic_open(out, newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "room"])
        w.writerows([r["frame"], room] for r, room in zip(rows, rooms))
    return out


MOVE_LIMITS_M = (0.1, 0.05)   # answers further apart than these over the origins count as moved


def answer_moves(positions: dict[Any, list[tuple[float, float]]]) -> tuple[int, ...]:
    """Frames whose answers (frame -> the plan positions answered at each grid origin) lie
    more than each of :data:`MOVE_LIMITS_M` apart (the largest distance between two)."""
    spreads = []
    for xy in positions.values():
        a = np.asarray(xy, float).reshape(-1, 2)
        spreads.append(float(np.max(np.hypot(*(a[:, None] - a[None]).transpose(2, 0, 1)))) if len(a) > 1 else 0.0)
    return tuple(int(sum(d > limit for d in spreads)) for limit in MOVE_LIMITS_M)


def worst_origin_mean(shares: Sequence[float], origins: int) -> float:
    """The mean over the homes of each home's worst origin: ``shares`` within 1 m and 30 deg
    per run, home by home, ``origins`` runs a home (the rule's first criterion)."""
    return float(np.mean(np.asarray(shares, float).reshape(-1, origins).min(axis=1)))


def near_the_best(results: dict[Any, Sequence[float]], origins: int) -> list[Any]:
    """The settings (key -> shares per run, as :func:`worst_origin_mean` takes them) whose
    mean of the homes' worst origins lies within one panorama of one home of the best, in
    ``results``' order: those the rule's later criteria choose among."""
    worst = {k: worst_origin_mean(v, origins) for k, v in results.items()}
    homes = len(next(iter(results.values()))) // origins
    top = max(worst.values())
    return [k for k in results if worst[k] >= top - 1.0 / (PANORAMAS * homes) - 1e-12]


def within_goal(row: dict[str, str]) -> bool:
    """Whether a row of a run's ``per_query.csv`` lies within 1 m and 30 degrees of the truth."""
    return float(row["error_m"]) <= 1.0 and float(row["yaw_error_deg"]) <= 30.0


def choose(results: dict[str, list[float]], moves: dict[str, tuple[int, ...]] | None = None, origins: int = 1) -> str:
    """The rule of the module docstring: name -> shares within 1 m and 30 deg per run (home by
    home, ``origins`` runs a home), and (optional) name -> :func:`answer_moves` over the
    origins. Near the best: a mean of the homes' worst origins within one panorama of one
    home of the best (``origins`` 1: each run a home of its own; :func:`near_the_best`)."""
    near = [k for k in near_the_best(results, origins) if k in SWEEP]
    moved = moves or {}
    return min(near, key=lambda k: (moved.get(k, (0,) * len(MOVE_LIMITS_M)), SWEEP[k]["refine_candidates"],
                                    list(SWEEP).index(k)))


NEAR_TRUTH_M = 1.0   # a wrong answer's search again: the grid within this of the truth only


def wrong_answer_causes(run_dir: Path, data: Path, panorama: dict[str, Any]) -> list[tuple[str, float, float]]:
    """Each wrong answer (beyond 1 m or 30 deg) of a run of home ``data`` with the panorama
    settings ``panorama``: (frame, the answer's score, the best score the search finds over
    the grid within :data:`NEAR_TRUTH_M` of the truth, :func:`placeloc.umap.panorama.search_near`).
    The second below the first: the score prefers the wrong place (a score failure); above:
    the search missed a better pose near the truth (a search failure)."""
    from dataclasses import replace

    import h5py

    from placeloc.core.artifacts import read_strings
    from placeloc.umap.artifacts import query_seen_rows
    from placeloc.umap.panorama import search_near
    from placeloc.umap.params import PanoramaParams, UMapParams
    from placeloc.umap.stages import query_line_images

    rows = list(csv.DictReader(read_run_table(run_dir, "per_query.csv")))
    wrong = [r for r in rows if not within_goal(r)]
    if not wrong:
        return []
    up = UMapParams()
    pp = replace(PanoramaParams(), **panorama)
    model = load_model(str(data / "floor_plan.yaml"))
    with h5py.File(run_dir / "extract.h5", "r") as ex:
        names = read_strings(ex["names"])
        ks = [names.index(r["frame"]) for r in wrong]
        queries = [query_line_images(ex, int(pp.orientation_bins), slice(k, k + 1)) for k in ks]
        # the rows each photo covered, as localize scores them (photo spheres stored cropped)
        seen = [query_seen_rows(ex, queries[0].shape[-2], slice(k, k + 1)) for k in ks]
    out = []
    for r, lines, rows in zip(wrong, queries, seen):
        near = search_near(lines, np.array([float(r["true_x"]), float(r["true_y"])]), model, pp, radius_m=NEAR_TRUTH_M,
                           step_m=GRID_STEP_M, z=None, tolerance_px=int(up.tolerance_px),
                           wall_margin_m=float(up.grid.wall_margin_m), hidden=bool(up.hidden_lines), seen=rows)
        out.append((r["frame"], float(r["score"]), float(near.score[0])))
    return out


def cause_line(causes: dict[int, list[tuple[str, float, float]]], origin: float) -> str:
    """One line of the table: how many wrong test answers are score failures (the best pose
    near the truth scores below the answer), and by how much."""
    every = [(seed, f, a, b) for seed, c in causes.items() for f, a, b in c]
    if not every:
        return f"Wrong test answers at grid origin {origin:g}: none."
    score = [(seed, f, a - b) for seed, f, a, b in every if b < a]
    text = (f"Wrong test answers at grid origin {origin:g}, searched again over the grid within {NEAR_TRUTH_M:g} m of "
            f"the truth: {len(score)} of {len(every)} are the score's (the best pose there scores below the "
            f"answer")
    if score:
        lo, hi = f"{min(g for *_, g in score):.4f}", f"{max(g for *_, g in score):.4f}"
        text += f", by {lo if lo == hi else f'{lo}-{hi}'}: " + ", ".join(f"home {s} {f}" for s, f, _ in score)
    search = [(seed, f) for seed, f, a, b in every if b >= a]
    text += ")"
    if search:
        text += "; the search's (a better pose near the truth was missed): " + ", ".join(f"home {s} {f}" for s, f in search)
    return text + "."


def homes_scope(out_dir: Path, quick: bool, origins: tuple[float, ...]) -> tuple[Path, tuple[int, ...], tuple[float, ...]]:
    """What an experiment on the test homes covers: its output folder (absolute), the test
    seeds and the grid origins; ``quick`` (a smoke run): the first two homes at the first
    origin."""
    return Path(out_dir).resolve(), (TEST_SEEDS[:2] if quick else TEST_SEEDS), (origins[:1] if quick else origins)


def _drop_index(run_dir: Path) -> None:
    """Delete a finished run folder's index (module docstring: the disk it takes)."""
    (run_dir / "index.h5").unlink(missing_ok=True)


def _answers(run_dir: Path) -> dict[str, tuple[float, float]]:
    """frame -> the answered plan position, from a run's per_query.csv."""
    return {r["frame"]: (float(r["x"]), float(r["y"])) for r in csv.DictReader(read_run_table(run_dir, "per_query.csv"))}


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out_dir = Path(out_dir).resolve()
    dev: dict[str, list[float]] = {}
    answers: dict[str, dict[tuple[int, str], list[tuple[float, float]]]] = {}   # setting -> (home, frame) -> per origin
    runs: dict[str, dict[str, Any]] = {}
    sweep = dict(list(SWEEP.items())[:2]) if quick else SWEEP
    origins = ORIGINS[:1] if quick else ORIGINS
    for seed in DEV_SEEDS[:1] if quick else DEV_SEEDS:
        data = _home(out_dir, seed)
        for i, frac in enumerate(origins):
            for name, over in sweep.items():
                m = _run(out_dir, f"dev-home{seed}-origin{i}", data, over, frac, quiet)
                runs[f"dev-home{seed}-origin{i}-{name}"] = m
                dev.setdefault(name, []).append(m["within_1m_30deg"])
                for frame, xy in _answers(out_dir / f"dev-home{seed}-origin{i}").items():
                    answers.setdefault(name, {}).setdefault((seed, frame), []).append(xy)
            _drop_index(out_dir / f"dev-home{seed}-origin{i}")
    moves = {name: answer_moves(a) for name, a in answers.items()}
    chosen = choose(dev, moves, len(origins))
    lines = ["Development homes (seeds " + ", ".join(map(str, DEV_SEEDS)) + "), grid origins shifted by "
             + ", ".join(f"{f:.2f}" for f in origins) + " of a step; share within 1 m and 30 deg:", "",
             "| setting | per home and origin | mean | worst | each home's worst origin (mean) "
             "| frames whose answers move > 0.1 / 0.05 m |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {k} | {' / '.join(f'{x:.0%}' for x in v)} | {np.mean(v):.1%} | {min(v):.0%} | "
              f"{worst_origin_mean(v, len(origins)):.1%} | "
              f"{' / '.join(map(str, moves.get(k, ())))} |" for k, v in dev.items()]
    lines += ["", "Chosen by the rule (the highest mean of each home's worst origin; within one panorama of one home of "
              "it, the fewest answers moving with the origin, then the fewest refined candidates, then the plainer): "
              f"**{chosen}**"]
    (out_dir / "dev.md").write_text("\n".join(lines) + "\n")
    homes: dict[str, dict[str, Any]] = {}
    test_answers: dict[tuple[int, str], list[tuple[float, float]]] = {}
    hinted: dict[str, dict[str, Any]] = {}
    for seed in TEST_SEEDS[:2] if quick else TEST_SEEDS:
        data = _home(out_dir, seed)
        for i, frac in enumerate(origins):
            # the chosen setting, named in full (the defaults are set to it: docs/umap.md)
            homes[f"home{seed}-origin{i}-panorama-chamfer"] = _run(out_dir, f"home{seed}-origin{i}", data, SWEEP[chosen], frac,
                                                                   quiet)
            for frame, xy in _answers(out_dir / f"home{seed}-origin{i}").items():
                test_answers.setdefault((seed, frame), []).append(xy)
            # each photo's room named, as its taker knows it (umap.room_hints): in a folder of its own
            # beside it, the stages before localize linked from it
            hinted[f"home{seed}-origin{i}"] = _run(out_dir, f"home{seed}-origin{i}-rooms", data, SWEEP[chosen], frac,
                                                   quiet, room_hints=true_rooms(data),
                                                   reuse=[out_dir / f"home{seed}-origin{i}"])
            _drop_index(out_dir / f"home{seed}-origin{i}")
            _drop_index(out_dir / f"home{seed}-origin{i}-rooms")
    # why the test homes' wrong answers are wrong (at the first origin): the score or the search
    causes = {seed: wrong_answer_causes(out_dir / f"home{seed}-origin0", _home(out_dir, seed), SWEEP[chosen])
              for seed in (TEST_SEEDS[:2] if quick else TEST_SEEDS)}
    write_summary(out_dir, {**runs, **homes, **{f"{k}-rooms": m for k, m in hinted.items()}, "chosen": {"setting": chosen},
                            "wrong_answer_causes": {str(s): [{"frame": f, "score": a, "best_near_truth": b}
                                                             for f, a, b in c] for s, c in causes.items()}})
    seeds = TEST_SEEDS[:2] if quick else TEST_SEEDS

    def per_home(key: str, missing: float | None = None) -> str:
        """Each test home's ``key`` share at each origin (``missing``, if given, where a run
        has none: runs from before the rival metrics)."""
        return "; ".join(f"{s}: " + " / ".join(f"{m[key] if missing is None else m.get(key, missing):.0%}"
                                                for k, m in homes.items() if k.startswith(f"home{s}-")) for s in seeds)

    table = lines + ["", "Test homes (seeds " + ", ".join(map(str, seeds)) + "), the chosen setting, each grid origin:", ""]
    table += home_table(homes)
    table += ["", "Per test home, share within 1 m and 30 deg at each origin: " + per_home("within_1m_30deg")]
    # what a user who checks both places of every doubtful answer finds (docs/umap.md)
    table += ["", "Per test home, the answer or (doubtful answers) its rival within 1 m and 30 deg: "
              + per_home("within_1m_30deg_or_rival", float("nan"))]
    table += ["", f"Test frames whose answers move with the grid's origin by more than "
              f"{' / '.join(f'{x:g}' for x in MOVE_LIMITS_M)} m: "
              f"{' / '.join(map(str, answer_moves(test_answers)))} of {len(test_answers)}"]
    table += ["", cause_line(causes, origin=origins[0])]
    share = np.array([m["within_1m_30deg"] for m in hinted.values()])
    table += ["", "With each test photo's room named (umap.room_hints, the room at its true position): within 1 m and "
              f"30 deg worst / median / best {share.min():.0%} / {np.median(share):.0%} / {share.max():.0%} over the "
              f"{len(share)} runs; per home at each origin: "
              + "; ".join(f"{s}: " + " / ".join(f"{m['within_1m_30deg']:.0%}" for k, m in hinted.items()
                                                 if k.startswith(f"home{s}-")) for s in seeds)]
    (out_dir / "table.md").write_text("\n".join(table) + "\n")
    if not quiet:
        print("\n".join(table))
    return out_dir / "summary.json"
