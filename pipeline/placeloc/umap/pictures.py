"""UMap's pictures of its answers, one PNG a panorama (``panorama_<photo>.png``: the photo's
lines against the map at its answer, and at the truth or the rival), which panoramas get one
and in what order (wrong answers first, then doubtful ones, then others spread over the
run), the captions report.html gives them, and ``ceiling_scores.png``: what evaluate draws
and what ``placeloc show`` draws again with its ``--sample`` and ``--failures``."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.artifacts import read_strings
from placeloc.evaluation.pose_estimates import RIGHT_M, right_answers
from placeloc.evaluation.report import MethodPictures
from placeloc.umap.artifacts import answer_model, query_seen_rows, rooms_of_points
from placeloc.umap.bits import unpack
from placeloc.umap.panorama import render_panoramas
from placeloc.umap.plots import plot_ceiling_scores, plot_panorama_overlay

log = logging.getLogger("placeloc")


def ceiling_picture(path: Path, loc: Any) -> Path | None:
    """ceiling_scores.png where umap.grid.ceilings searched several ceilings (each one's
    mean grid score, the one found marked), else nothing."""
    if "ceiling_grid_means" not in loc:
        return None
    return plot_ceiling_scores(path, loc["ceiling_grid_means"][()], float(loc["ceiling_m"][0]), len(loc["names"]))


# panoramas drawn one PNG each, at most this many (:func:`pictured_panoramas` chooses them)
PANORAMA_PICTURES = 12


# how every panorama picture's file name starts (report.html leaves out those not chosen)
PANORAMA_PNG = "panorama_"


def ranked_panoramas(n: int, *, wrong: np.ndarray | None = None, error_m: np.ndarray | None = None,
                     doubtful: np.ndarray | None = None, margin: np.ndarray | None = None, limit: int | None = None,
                     failures: int | None = None, sample: int | None = None) -> list[int]:
    """The frames of ``n`` panorama answers that get a picture, in the order they were chosen
    (the order report.html shows them in): first the ``wrong`` ones (the largest ``error_m``
    first), then the ``doubtful`` ones (the smallest ``margin`` first), then the others
    spread evenly over the run (the first and the last among them, in frame order). Any of
    the four may be None (none wrong, none doubtful, ties in frame order).

    How many: at most ``limit`` in all (None: :data:`PANORAMA_PICTURES`); or, where
    ``failures`` or ``sample`` is given (``placeloc show``'s options, which count other
    methods' strips so), at most ``failures`` wrong ones, then ``sample`` more (None: none),
    the doubtful first. A wrong answer past the first ``failures`` may be among those
    ``sample`` more, as a wrong match may be among the strips spread over a traverse.

    Why: the pictures are where a user sees why an answer is wrong or doubtful, which of the
    photo's lines the map explains there and which it does not. Drawing the first twelve
    left out every such answer past them (generated home 21 with 32 photos: its one wrong
    and doubtful answer, pano_019, had no picture)."""
    order = np.arange(n)
    picked: list[int] = []

    def take(mask: np.ndarray | None, key: np.ndarray | None, upto: int) -> None:
        if mask is None:
            return
        mask = np.asarray(mask, bool) & ~np.isin(order, picked)
        keys = np.zeros(n) if key is None else np.nan_to_num(np.asarray(key, float), nan=np.inf)
        picked.extend(int(k) for k in order[mask][np.argsort(keys[mask], kind="stable")][:max(0, upto - len(picked))])

    shared = failures is None and sample is None
    cap = (PANORAMA_PICTURES if limit is None else int(limit)) if shared else int(failures or 0)
    take(wrong, None if error_m is None else -np.asarray(error_m, float), cap)
    if not shared:
        cap = len(picked) + int(sample or 0)
    take(doubtful, margin, cap)
    rest = order[~np.isin(order, picked)]
    room = cap - len(picked)
    if room > 0 and len(rest):
        # evenly over the run's frames: photos taken room by room are not all of the first rooms
        picked.extend(int(k) for k in rest[np.unique(np.round(np.linspace(0, len(rest) - 1, min(room, len(rest)))).astype(int))])
    return picked


def pictured_panoramas(n: int, *, wrong: np.ndarray | None = None, error_m: np.ndarray | None = None,
                       doubtful: np.ndarray | None = None, margin: np.ndarray | None = None,
                       limit: int | None = None) -> list[int]:
    """The frames :func:`ranked_panoramas` chooses (at most ``limit``, None:
    :data:`PANORAMA_PICTURES`), in frame order."""
    return sorted(ranked_panoramas(n, wrong=wrong, error_m=error_m, doubtful=doubtful, margin=margin, limit=limit))


def panorama_caption(k: int, *, wrong: np.ndarray | None = None, error_m: np.ndarray | None = None,
                     yaw_error_deg: np.ndarray | None = None, doubtful: np.ndarray | None = None,
                     margin: np.ndarray | None = None) -> str:
    """Why answer ``k`` has a picture, in the words report.html puts beside it: "wrong: 7.31
    m off" (or "wrong: heading 95 deg off" where its place is right), "right: 0.02 m off"
    where the truth is known, and "doubtful: margin 0.0153" where it is doubtful; "" where
    nothing is known of it (a run not evaluated, an answer not doubtful)."""
    words = []
    if wrong is not None and error_m is not None and np.isfinite(error_m[k]):
        if not wrong[k]:
            words.append(f"right: {error_m[k]:.2f} m off" if error_m[k] >= 0.005 else "right: under 0.01 m off")
        elif error_m[k] > RIGHT_M or yaw_error_deg is None:
            words.append(f"wrong: {error_m[k]:.2f} m off")
        else:
            words.append(f"wrong: heading {yaw_error_deg[k]:.0f} deg off")
    if doubtful is not None and doubtful[k]:
        words.append(f"doubtful: margin {margin[k]:.3g}" if margin is not None and np.isfinite(margin[k]) else "doubtful")
    return "; ".join(words)


def _panorama_file(name: str) -> str:
    return f"{PANORAMA_PNG}{Path(name).stem}.png"


def _report_of(names: list[str], frames: list[int], note: str, **known: Any) -> MethodPictures:
    """report.html's view of the panorama pictures of ``frames`` (in their order), each with
    :func:`panorama_caption` from what is ``known`` of it."""
    return MethodPictures(PANORAMA_PNG, [(_panorama_file(names[k]), panorama_caption(k, **known)) for k in frames], note)


def _choice_note(n: int, judged: bool, failures: int | None, sample: int | None) -> str:
    """How the pictures were chosen, in a line above them in report.html."""
    rest = "the doubtful ones first (the smallest margin first), then others spread over the run"
    if failures is None and sample is None:
        first = "the wrong answers first (the largest error first), then " if judged else ""
        return f"One picture per photo for at most {PANORAMA_PICTURES} of the {n}: {first}{rest.replace(' first (', ' (', 1) if judged else rest}."
    if not judged:
        return f"As placeloc show --sample {sample} chose them: {rest}."
    parts = ([f"the wrong answers, at most {failures} (the largest error first)"] if failures else []) + (
        [f"{f'then {sample} more' if failures else sample}: {rest}"] if sample else [])
    return f"As placeloc show --failures {failures} --sample {sample} chose them: {', '.join(parts) or 'none'}."


def _show_counts(judged: bool, sample: int | None, failures: int | None) -> tuple[int | None, int | None]:
    """show's ``--failures`` and ``--sample`` as :func:`ranked_panoramas` reads them (None,
    None: evaluate's choice, neither given): the one not given counts as its default, as it
    does for the strips; without ground truth there are no failures to count."""
    from placeloc.evaluation.show import DEFAULT_COUNT

    if sample is None and failures is None:
        return None, None
    if not judged:
        return (None, None) if sample is None else (0, sample)
    return (DEFAULT_COUNT if failures is None else failures), (DEFAULT_COUNT if sample is None else sample)


def _known(loc: Any, err: np.ndarray | None = None, yaw_err: np.ndarray | None = None) -> dict[str, Any]:
    """What the choice of pictures and their captions read of each answer: from the localize
    artifact ``loc`` whether it is doubtful and its margin; with the position errors ``err``
    (None: not evaluated) and heading errors ``yaw_err`` evaluate measured, whether it is
    wrong and those errors."""
    known: dict[str, Any] = {"doubtful": loc["doubtful"][()] if "doubtful" in loc else None,
                             "margin": loc["margin"][()] if "margin" in loc else None}
    if err is not None:
        known.update(wrong=~right_answers(err, yaw_err) & np.isfinite(err), error_m=err, yaw_error_deg=yaw_err)
    return known


def _judged(judged: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The position and heading errors the evaluate artifact ``judged`` wrote (evaluate chose
    its pictures from the same numbers), or None for each it lacks."""
    err = judged["error_m"][()] if "error_m" in judged else None
    return err, judged["yaw_error_deg"][()] if err is not None and "yaw_error_deg" in judged else None


def panorama_pictures(ctx: Any, ex: Any, plan: Any, loc: Any, gt: Any, rows: np.ndarray, err: np.ndarray,
                       yaw_err: np.ndarray | None) -> MethodPictures:
    names = read_strings(loc["names"])
    # the numbers in memory that evaluate.h5 keeps (report_pictures reads them back: the same choice)
    known = _known(loc, err, yaw_err)
    frames = _ranked(len(names), known)
    _draw_judged(ctx.output, ex, plan, loc, gt, rows, err, frames)
    return _report_of(names, frames, _choice_note(len(names), True, None, None), **known)


def _draw_judged(output: Callable[[str], Path], ex: Any, plan: Any, loc: Any, gt: Any, rows: np.ndarray,
                 err: np.ndarray, frames: list[int]) -> list[Path]:
    """The pictures of the panoramas ``frames`` of an evaluated run, each answer's render
    against the truth's, at ``output(file name)``."""
    h, w = int(ex.attrs["height"]), int(ex.attrs["width"])
    segs, faces = answer_model(plan, loc)
    zs = _answer_heights(loc, plan)
    names = read_strings(loc["names"])
    est_h = loc["heading_deg"][()]
    out = []
    for k in frames:
        true_pose = None
        if gt.heading is not None:
            tz = float(gt.z[rows[k]]) if gt.z is not None else zs[k]
            true_pose = (*gt.xy[rows[k]], tz, np.degrees(gt.heading[rows[k]]))
        path = output(_panorama_file(names[k]))
        _overlay(path, ex["lines"][k], (h, w), segs, faces, (loc["x"][k], loc["y"][k], zs[k], est_h[k]), true_pose,
                 f"{names[k]}: error {err[k]:.2f} m, estimated heading {est_h[k]:.1f} deg{_height_note(loc, k)}"
                 f"{_tilt_note(loc, k)}{_doubt_note(loc, k)}", unseen=_unseen_rows(ex, k, h))
        out.append(path)
    return out


def report_pictures(run_dir: Path, *, evaluated: bool = False, sample: int | None = None,
                    failures: int | None = None) -> MethodPictures | None:
    """report.html's order and captions of a panorama run's pictures as ``placeloc show``
    chooses them (:func:`show_extra`; without ``sample`` and ``failures``, evaluate's choice
    where ``evaluated``), from the run's artifacts; None for a run of pinhole photos."""
    import h5py

    run_dir = Path(run_dir)
    try:
        with h5py.File(run_dir / "extract.h5", "r") as ex, h5py.File(run_dir / "localize.h5", "r") as loc:
            if str(ex.attrs.get("query_kind", "")) != "panorama":
                return None
            names, known, frames, (failures, sample) = _chosen(run_dir, loc, evaluated, sample, failures)
    except (OSError, KeyError):   # a folder without the artifacts (a report of a bare folder): name order
        return None
    return _report_of(names, frames, _choice_note(len(names), "wrong" in known, failures, sample), **known)


def _chosen(run_dir: Path, loc: Any, evaluated: bool, sample: int | None, failures: int | None
            ) -> tuple[list[str], dict[str, Any], list[int], tuple[int | None, int | None]]:
    """What show's pictures and the report's order are chosen from, and the choice: the
    localize artifact ``loc``'s names, what is known of each answer (:func:`_known`; with
    evaluate.h5 where ``evaluated``), the frames :func:`ranked_panoramas` picks and the counts
    it took (:func:`_show_counts`)."""
    import h5py

    names = read_strings(loc["names"])
    if evaluated:
        with h5py.File(Path(run_dir) / "evaluate.h5", "r") as judged:
            known = _known(loc, *_judged(judged))
    else:
        known = _known(loc)
    counts = _show_counts("wrong" in known, sample, failures)
    return names, known, _ranked(len(names), known, *counts), counts


def _ranked(n: int, known: dict[str, Any], failures: int | None = None, sample: int | None = None) -> list[int]:
    """:func:`ranked_panoramas` of ``n`` answers from what is ``known`` of them
    (:func:`_known`): the one call behind evaluate's pictures and show's, so both choose
    alike."""
    return ranked_panoramas(n, wrong=known.get("wrong"), error_m=known.get("error_m"), doubtful=known["doubtful"],
                            margin=known["margin"], failures=failures, sample=sample)


def show_extra(run_dir: Path, res: Any, out_dir: Path, *, evaluated: bool = False, sample: int | None = None,
               failures: int | None = None, config: dict[str, Any] | None = None) -> list[Path]:
    """``placeloc show``'s pictures of a panorama run, one per photo, as
    :func:`ranked_panoramas` chooses them with show's ``failures`` and ``sample`` (None: not
    given). Not evaluated (a photo located without ground truth): the doubtful ones first,
    each photo's detected lines against the map rendered at its answer and, where the answer
    is doubtful, at its rival too, so that whoever took the photo sees which lines the answer
    explains. Evaluated: against the truth, as evaluate draws them, and only where
    ``failures`` or ``sample`` is given (otherwise evaluate's pictures stand). Pinhole runs:
    none, and a warning where either is given (they choose nothing there)."""
    import h5py

    run_dir = Path(run_dir)
    out: list[Path] = []
    with h5py.File(run_dir / "extract.h5", "r") as ex, h5py.File(run_dir / "build-dictionary.h5", "r") as plan, \
            h5py.File(run_dir / "localize.h5", "r") as loc:
        if str(ex.attrs.get("query_kind", "")) != "panorama":
            if sample is not None or failures is not None:
                log.warning("%s: UMap located pinhole photos here, and draws a picture per photo only for panoramas: "
                            "--sample and --failures choose no picture of it", run_dir)
            return []
        if evaluated and sample is None and failures is None:
            return []   # evaluate drew its choice already: show leaves the run's pictures as they are
        if not evaluated and failures is not None:
            log.warning("--failures %d: %s is not evaluated (no ground truth judged its answers), so no answer is known "
                        "wrong and none is drawn as a failure; --sample's pictures show the doubtful answers first",
                        failures, run_dir)
        names, known, frames, _ = _chosen(run_dir, loc, evaluated, sample, failures)
        if evaluated:
            from placeloc.evaluation.pose_estimates import true_poses
            from placeloc.evaluation.report import run_config

            cfg = config if config is not None else run_config(run_dir)
            gt, rows = true_poses(cfg["ground_truth"], names)
            return _draw_judged(lambda name: out_dir / name, ex, plan, loc, gt, rows, known["error_m"], frames)
        ceiling = ceiling_picture(out_dir / "ceiling_scores.png", loc)
        if ceiling is not None:
            out.append(ceiling)
        size = (int(ex.attrs["height"]), int(ex.attrs["width"]))
        segs, faces = answer_model(plan, loc)
        zs = _answer_heights(loc, plan)
        x, y, heading = loc["x"][()], loc["y"][()], loc["heading_deg"][()]
        (rooms,) = rooms_of_points(plan, np.column_stack([x, y]))
        for k in frames:
            doubt = _doubt_note(loc, k)
            rival = (loc["rival_x"][k], loc["rival_y"][k], zs[k], loc["rival_heading_deg"][k]) if doubt else None
            where = f" in the {rooms[k]}" if rooms[k] else ""
            path = out_dir / _panorama_file(names[k])
            _overlay(path, ex["lines"][k], size, segs, faces, (x[k], y[k], zs[k], heading[k]),
                     rival if rival is not None and np.isfinite(rival).all() else None,
                     f"{names[k]}: answer ({x[k]:.2f}, {y[k]:.2f}) m{where}, heading {heading[k]:.1f} deg"
                     f"{_height_note(loc, k)}{_tilt_note(loc, k)}{doubt}",
                     second="the rival", unseen=_unseen_rows(ex, k, size[0]))
            out.append(path)
    return out


def _height_note(loc: Any, k: int) -> str:
    """", camera 1.10 m up" where the height was searched (umap.grid.heights), ", ceiling
    2.40 m" where the ceiling's was (umap.grid.ceilings), else ""."""
    return (f", camera {float(loc['height_m'][k]):.2f} m up" if "height_m" in loc else "") + (
        f", ceiling {float(loc['ceiling_m'][k]):.2f} m" if "ceiling_m" in loc else "")


def _tilt_note(loc: Any, k: int) -> str:
    """", levelled by 4.2 deg" where the panorama was turned upright by more than 0.5 deg
    (umap.panorama.level_max_deg; its lines are drawn levelled), else ""."""
    return f", levelled by {float(loc['tilt_deg'][k]):.1f} deg" if "tilt_deg" in loc and loc["tilt_deg"][k] > 0.5 else ""


def _answer_heights(loc: Any, plan: Any) -> np.ndarray:
    """Each answer's camera height: the one found (``height_m``, where umap.grid.heights
    searched several), else the grid's, from the build-dictionary artifact ``plan`` (its
    poses, which the index copies: the index's 0.7 GB file need not be opened for it)."""
    return loc["height_m"][()] if "height_m" in loc else np.full(len(loc["x"]), float(plan["poses"][0, 2]))


def _unseen_rows(ex: Any, k: int, height: int) -> np.ndarray | None:
    """The line-image rows panorama ``k`` of the extract artifact ``ex`` did not cover (those
    its score leaves out), or None where it covered them all."""
    seen = query_seen_rows(ex, height, slice(k, k + 1))
    return None if seen is None or bool(np.all(seen == 1.0)) else seen[0] == 0.0


def _overlay(path: Path, words: np.ndarray, size: tuple[int, int], segs: np.ndarray, faces: np.ndarray, pose: tuple,
             second_pose: tuple | None, title: str, second: str = "the truth", unseen: np.ndarray | None = None) -> None:
    """One panorama's picture (:func:`plot_panorama_overlay`): its packed oriented line
    channels ``words`` of ``size`` (H, W) (their union drawn) against the map rendered at
    ``pose`` and at ``second_pose`` (x, y, z, heading in degrees; None: none), each render in
    the frame of a camera at its own heading, as the query is in its own."""
    h, w = size

    def at(q: tuple) -> np.ndarray:
        return unpack(render_panoramas(segs, faces, np.array([q], float), width=w, height=h, hidden=True), h, w)[0]

    plot_panorama_overlay(path, unpack(words, h, w).max(axis=0), at(pose), None if second_pose is None else at(second_pose),
                          title, second=second, unseen=unseen)


def _doubt_note(loc: Any, k: int) -> str:
    """The pictures' words for answer ``k`` of a localize artifact where it is doubtful: its
    margin and its rival's pose ("" where it is not)."""
    if "doubtful" not in loc or not loc["doubtful"][k]:
        return ""
    return (f"; doubtful (margin {loc['margin'][k]:.3f}), its rival at ({loc['rival_x'][k]:.2f}, "
            f"{loc['rival_y'][k]:.2f}) m, {loc['rival_heading_deg'][k]:.1f} deg")
