"""``placeloc experiment pirf-dictionary``: does the improved dictionary update's effect grow
with properties of real video that our generated video lacks?

H. Sasaki and T. Hamagami ("Construction of feature space for speeding up self-localization
using time series omnidirectional images") report that their improved update (sec. 4.1)
shrinks the PIRF dictionary by 34 %; on our generated omnidirectional video it removes 2-5 %.
The improved rule only rejects a new PIRF that ratio-test-matches another *new PIRF of the
same frame* (or Q_{t-1}, which the plain rule already checked), so its effect is bounded by
how many within-frame near-duplicates a video produces. This experiment renders the
``synth omni`` building video with two properties of hand-held real video turned up step by
step, over several seeds:

- ``slow``: slow motion (after every 50 frames of walking, 50 frames at ``slow`` times the
  walking speed), 600 mapping frames;
- ``revisit``: revisits at a slightly different place (every lap after the first walked
  ``revisit_offset`` m to the side), 1,300 mapping frames (one lap is about 1,080);
- ``seam``: the stitching seams of a two-lens camera (the paper's RICOH THETA), where the
  scene is imaged twice, ``seam_ghost`` pixels apart, in a 20 deg band around each seam
  (:func:`placeloc.synth.omni.ghost_seams`), 600 mapping frames. Here the property sits in
  part of each frame, not in some frames, so "marked" means the PIRFs whose feature in the
  newest frame lies in a seam band (found by detecting the features again, checked to give
  the very PIRFs the extract stage wrote), and the frames are also checked for what the
  ghosting does to features: how many in the bands, against outside, have a ratio-test
  twin in the same frame, and how many of those twins sit at the ghost's offset.

For each video it extracts the PIRFs with the pipeline (``placeloc.api.run(...,
stages="extract")``, table 1's parameters) and maps them with both updates, using
:class:`placeloc.pirf.mapping.PirfMapper` (what the build-dictionary stage runs through
``map_video``, exact search). It counts:

- the plain and the improved dictionary sizes and the reduction;
- within-frame duplicates: of the PIRFs the plain update inserts, how many the improved rule
  would reject in the same frame (a ratio-test match with another new PIRF of that frame);
- across-frame twins: dictionary words whose nearest *other* word passes the ratio test
  (leave-one-out, exact), and how many such twins were inserted within eps frames of each
  other (a tracked feature inserted again) rather than further apart (a revisit);
- the same sizes restricted to the frames that carry the property (the slow stretches; the
  laps after the first), where an effect would show first;
- on one seed per setting, with features detected again, where within-frame twins come
  from: how many PIRFs of a frame have a ratio-test twin in that frame, and how many of
  those are *merged chains* (two features of frame t ratio-matched one feature of t-1).

Only some properties: ``python -m placeloc.experiments.pirf_dictionary --only seam``
(rows of other properties already measured stay cached in ``rows.json``).

Outputs under ``out_dir``: ``runs.csv`` (one row per video), ``table.csv`` and ``tables.md``
(median and range over seeds per setting), ``reduction.png``, ``summary.json``, and the
rendered data and extract artifacts under ``data/`` and ``runs/`` (re-used on a re-run).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from placeloc.api import load_config, run
from placeloc.experiments import pyplot, say, write_summary
from placeloc.pirf.mapping import PirfMapper, improved_insert, ratio_ok
from placeloc.pirf.params import PirfParams
from placeloc.pirf.results import read_pirfs
from placeloc.synth.omni import SEAM_BAND_DEG, generate, loop_length, seam_weight, speed_profile

STEP = 0.2          # walking step of the generator (m per frame)
SLOW_FRAMES = 50    # frames of slow motion after every 50 walked


@dataclass(frozen=True)
class Property:
    """One property of real video, the generator parameter that sets it and its levels
    (the first level is the generator's default: the property absent)."""

    name: str
    param: str
    levels: tuple[float, ...]
    frames: int
    unit: str


PROPERTIES = (
    Property("slow", "slow", (1.0, 0.5, 0.25, 0.1), 600, "fraction of walking speed in the slow stretches"),
    Property("revisit", "revisit_offset", (0.0, 0.2, 0.5), 1300, "sideways offset of later laps (m)"),
    Property("seam", "seam_ghost", (0.0, 3.0, 6.0, 12.0), 600, "ghost offset at the stitching seams (px, 480 px = 360 deg)"),
)
SEEDS = (0, 1, 2)


def property_frames(prop: str, level: float, frames: int, layout: str = "building") -> np.ndarray:
    """Mask of the mapping frames that carry the property: inside a slow stretch, or on a lap
    after the first (as :func:`placeloc.synth.omni.loop_path` walks them, start 0)."""
    if prop == "slow":
        return speed_profile(frames, slow=level, slow_frames=SLOW_FRAMES) < 1
    if prop == "revisit":
        walked = STEP * np.concatenate([[0.0], np.cumsum(speed_profile(frames)[1:])])
        return walked >= loop_length(layout)
    if prop == "seam":  # a property of every frame (its PIRFs are marked by where they lie: see seam_marks)
        return np.ones(frames, bool)
    raise ValueError(f"unknown property {prop!r}; choose one of {', '.join(p.name for p in PROPERTIES)}")


def ratio_twins(words: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-out ratio test of a dictionary against itself (exact, faiss ``IndexFlatL2``).

    Returns (has_twin mask, twin id per word, -1 where none): word i has a twin j when j is
    its nearest other word and passes eq. (1) against i's second nearest other word.
    """
    import faiss

    n = len(words)
    twin = np.full(n, -1, np.int64)
    if n < 3:
        return twin >= 0, twin
    x = np.ascontiguousarray(words, np.float32)
    index = faiss.IndexFlatL2(x.shape[1])
    index.add(x)
    d, i = index.search(x, 3)
    own = i == np.arange(n)[:, None]
    # drop each word's own hit (normally the first; not always with exact duplicates)
    keep = ~own
    keep[own.sum(1) == 0, 2] = False
    d2 = d[keep].reshape(n, 2)
    i2 = i[keep].reshape(n, 2)
    ok = ratio_ok(d2, i2, ratio)
    twin[ok] = i2[ok, 0]
    return ok, twin


def merged_chains(frames: Iterable[tuple[np.ndarray, np.ndarray]], *, ratio: float, w_size_default: int, w_size_max: int,
                  n_pmin: int, n_pmax: int) -> dict[str, Any]:
    """Where within-frame near-duplicate PIRFs come from. Runs PIRF extraction (sec. 3.1,
    as the extract stage does) over the frames' (descriptors, detector responses) and, per
    frame, counts the PIRFs that have a ratio-test twin among the other PIRFs of the same
    frame, and the PIRFs whose chain is *merged*: another PIRF of the frame ratio-matched the
    same feature of frame t-1 (the ratio test is not one-to-one), so the two chains, and
    their mean descriptors, share all but one frame."""
    from placeloc.pirf.chain import PirfTracker

    tracker = PirfTracker(ratio=ratio, w_size_default=w_size_default, w_size_max=w_size_max, n_pmin=n_pmin, n_pmax=n_pmax)
    total = twins = merged = both = 0
    for desc, resp in frames:
        pirf, sel, _w = tracker.push_selected(desc, resp)
        if len(pirf) < 3:
            continue
        prev = tracker.matches[-1][sel]  # each PIRF's feature in frame t-1
        ids, counts = np.unique(prev, return_counts=True)
        shared = np.isin(prev, ids[counts > 1])
        has, _twin = ratio_twins(pirf, ratio)
        total += len(pirf)
        twins += int(has.sum())
        merged += int(shared.sum())
        both += int((has & shared).sum())
    return {"pirfs": total, "twins_in_frame": twins, "merged_chain": merged, "twins_in_merged_chain": both,
            "twins_in_frame_pct": 100.0 * twins / max(total, 1), "merged_chain_pct": 100.0 * merged / max(total, 1)}


def _row_ids(rows: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Index in ``frame`` of each of ``rows`` (rows copied from ``frame``), by exact value;
    equal rows of a frame are taken in order."""
    where: dict[bytes, list[int]] = {}
    for i, r in enumerate(np.ascontiguousarray(frame, np.float32)):
        where.setdefault(r.tobytes(), []).append(i)
    return np.array([where[r.tobytes()].pop(0) for r in np.ascontiguousarray(rows, np.float32)], np.int64)


def dictionary_counts(pirfs: np.ndarray, offsets: np.ndarray, *, ratio: float, n_pmax: int, eps: int, sigma: float,
                      marked: np.ndarray | None = None, marked_rows: np.ndarray | None = None) -> dict[str, Any]:
    """Map one video's PIRFs with the plain and the improved update (exact search) and count
    what explains the difference. ``marked``: optional mask of frames to count separately
    (``*_marked``); or ``marked_rows``, a mask over the PIRFs (rows of ``pirfs``) instead,
    for a property that sits in part of every frame. Frame t's PIRFs are
    ``pirfs[offsets[t]:offsets[t + 1]]``."""
    n_frames = len(offsets) - 1
    if marked is not None and marked_rows is not None:
        raise ValueError("give marked (frames) or marked_rows (PIRFs), not both")
    marked = np.zeros(n_frames, bool) if marked is None else np.asarray(marked, bool)
    if len(marked) != n_frames:
        raise ValueError(f"marked has {len(marked)} entries for {n_frames} frames")
    if marked_rows is not None and len(marked_rows) != len(pirfs):
        raise ValueError(f"marked_rows has {len(marked_rows)} entries for {len(pirfs)} PIRFs")
    rows = None if marked_rows is None else np.asarray(marked_rows, bool)
    out: dict[str, Any] = {"frames": n_frames, "marked_frames": int(marked.sum()),
                           "pirfs_per_frame": float(np.diff(offsets).mean()) if n_frames else 0.0}
    if rows is not None:
        out["marked_frames"] = n_frames
        out["marked_pirfs"] = int(rows.sum())
    growth = {}
    within = np.zeros(n_frames, np.int64)
    within_rows = 0  # of them, marked PIRFs (marked_rows only)
    dicts = {}
    for update in ("plain", "improved"):
        mapper = PirfMapper(pirfs.shape[1], ratio=ratio, n_pmax=n_pmax, eps=eps, sigma=sigma, update=update,
                            search="bruteforce", hnsw_m=32, hnsw_ef_construction=40, ef_search=64)
        inserted_marked = 0
        for t in range(n_frames):
            frame = pirfs[offsets[t]:offsets[t + 1]]
            before = mapper.n
            mapper.step(frame)
            if rows is not None and mapper.n > before:
                inserted_marked += int(rows[offsets[t] + _row_ids(mapper.words[before:mapper.n], frame)].sum())
            if update == "plain" and mapper.last_new is not None and len(mapper.last_new[0]):
                # what the improved rule would reject from the new PIRFs the plain rule inserts here
                _order, added, _word = improved_insert(*mapper.last_new, ratio)
                within[t] = int((~added).sum())
                if rows is not None and (~added).any():
                    within_rows += int(rows[offsets[t] + _row_ids(mapper.last_new[0][~added], frame)].sum())
        sizes = np.asarray(mapper.dict_size_after, np.int64)
        growth[update] = np.diff(np.concatenate([[0], sizes]))
        dicts[update] = mapper.dictionary.copy()
        out[update] = int(sizes[-1]) if n_frames else 0
        out[f"{update}_marked"] = int(growth[update][marked].sum()) if rows is None else inserted_marked
    out["reduction_pct"] = 100.0 * (1 - out["improved"] / out["plain"]) if out["plain"] else 0.0
    out["reduction_marked_pct"] = (100.0 * (1 - out["improved_marked"] / out["plain_marked"]) if out["plain_marked"]
                                   else float("nan"))
    out["within_frame"] = int(within.sum())
    out["within_frame_pct"] = 100.0 * within.sum() / max(out["plain"], 1)
    within_marked = within[marked].sum() if rows is None else within_rows
    out["within_frame_marked_pct"] = (100.0 * within_marked / out["plain_marked"] if out["plain_marked"]
                                      else float("nan"))
    for update in ("plain", "improved"):
        has, twin = ratio_twins(dicts[update], ratio)
        frame_of = np.searchsorted(np.cumsum(growth[update]), np.arange(len(twin)), side="right")
        gap = np.abs(frame_of[has] - frame_of[twin[has]])
        out[f"twins_{update}_pct"] = 100.0 * has.mean() if len(has) else 0.0
        out[f"twins_{update}_near_pct"] = 100.0 * float((gap <= eps).mean()) if len(gap) else float("nan")
    return out


def in_seam_bands(x: np.ndarray, width: int, band_deg: float) -> np.ndarray:
    """Whether each keypoint x (OpenCV's: pixel centres at integers) lies in a column that
    the seam ghosting blends (:func:`placeloc.synth.omni.seam_weight` > 0)."""
    col = np.clip(np.floor(np.asarray(x, np.float64) + 0.5).astype(np.int64), 0, width - 1)
    return seam_weight(width, band_deg)[col] > 0


def seam_marks(paths: list[Path], *, features: str, n_features: int, ratio: float, w_size_default: int, w_size_max: int,
               n_pmin: int, n_pmax: int, band_deg: float, shift_px: float, tol_px: float = 1.5,
               workers: int = 1) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Detect the features of a video's frames again and run PIRF extraction (sec. 3.1, as
    the extract stage does) keeping where each PIRF's feature lies in the newest frame.

    Returns (PIRFs (n, d) in the extract stage's order, in-seam-band mask over them,
    counts). The counts ask what the seam ghosting does within a frame: features (and
    PIRFs) in the bands and outside, how many have a ratio-test twin among the other
    features (PIRFs) of the same frame (eq. 1, leave-one-out), and how many in-band feature
    twins are *ghost pairs*: the twin lies ``shift_px`` (within ``tol_px``) to the side at the
    same height, the doubled image of one structure."""
    from placeloc.pirf.chain import PirfTracker
    from placeloc.pirf.features import extract_frame

    items = [(str(q), features, n_features) for q in paths]
    if workers > 1:
        import multiprocessing as mp

        with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
            detected = list(pool.map(extract_frame, items, chunksize=16))
    else:
        detected = [extract_frame(it) for it in items]
    c = dict.fromkeys(("features_band", "features_out", "twins_band", "twins_out", "ghost_pairs", "pirfs_band", "pirfs_out",
                       "pirf_twins_band", "pirf_twins_out"), 0)
    tracker = PirfTracker(ratio=ratio, w_size_default=w_size_default, w_size_max=w_size_max, n_pmin=n_pmin, n_pmax=n_pmax)
    all_pirfs, all_band = [], []
    for xy, resp, desc, shape in detected:
        width = shape[1]
        band = in_seam_bands(xy[:, 0], width, band_deg)
        has, twin = ratio_twins(desc, ratio)
        c["features_band"] += int(band.sum())
        c["features_out"] += int((~band).sum())
        c["twins_band"] += int((has & band).sum())
        c["twins_out"] += int((has & ~band).sum())
        if shift_px:
            j = np.where(has, twin, 0)
            d = np.abs(xy[j] - xy)
            dx = np.minimum(d[:, 0], width - d[:, 0])  # the frame wraps around in azimuth
            c["ghost_pairs"] += int((has & band & (np.abs(dx - shift_px) <= tol_px) & (d[:, 1] <= tol_px)).sum())
        pirf, sel, _w = tracker.push_selected(desc, resp)
        pband = band[sel]
        phas, _ = ratio_twins(pirf, ratio)
        c["pirfs_band"] += int(pband.sum())
        c["pirfs_out"] += int((~pband).sum())
        c["pirf_twins_band"] += int((phas & pband).sum())
        c["pirf_twins_out"] += int((phas & ~pband).sum())
        all_pirfs.append(pirf)
        all_band.append(pband)
    pct = {"feature_twins_band_pct": 100.0 * c["twins_band"] / max(c["features_band"], 1),
           "feature_twins_out_pct": 100.0 * c["twins_out"] / max(c["features_out"], 1),
           "ghost_pairs_pct": 100.0 * c["ghost_pairs"] / c["twins_band"] if shift_px and c["twins_band"] else float("nan"),
           "pirf_twins_band_pct": 100.0 * c["pirf_twins_band"] / max(c["pirfs_band"], 1),
           "pirf_twins_out_pct": 100.0 * c["pirf_twins_out"] / max(c["pirfs_out"], 1),
           "band_pirfs_pct": 100.0 * c["pirfs_band"] / max(c["pirfs_band"] + c["pirfs_out"], 1)}
    dim = tracker.descs[-1].shape[1] if tracker.descs else 128
    pirfs = np.concatenate(all_pirfs) if all_pirfs else np.zeros((0, dim), np.float32)
    return pirfs, np.concatenate(all_band) if all_band else np.zeros(0, bool), {**c, **pct}


def seam_frame_check(out_dir: Path, settings: list[tuple[float, float]], frames: int = 150, seed: int = 0,
                     quiet: bool = False) -> list[dict[str, Any]]:
    """In-frame counts of :func:`seam_marks` alone (no mapping) for (ghost px, band deg)
    settings beyond the experiment's levels, each on ``frames`` frames of the seed's
    building video; writes ``seam_frames.csv`` and ``seam_frames.md`` under ``out_dir``."""
    out = Path(out_dir)
    p = PirfParams()
    rows = []
    for ghost, band_deg in settings:
        data = out / "data" / f"seamcheck-{ghost:g}px-{band_deg:g}deg-seed{seed}"
        want = {"seed": seed, "frames": frames, "test_frames": 2, "width": 480, "layout": "building", "seam_ghost": ghost,
                "seam_band": band_deg}
        meta = data / "params.json"
        if not (meta.is_file() and json.loads(meta.read_text()) == want):
            say("pirf-dictionary", quiet, f"rendering {data.name}: {frames} frames")
            generate(data, **want, workers=min(2, os.cpu_count() or 1))
            meta.write_text(json.dumps(want))
        _pirfs, _band, c = seam_marks(sorted((data / "mapping").glob("frame_*.png")), features=p.features,
                                      n_features=p.n_features, ratio=p.ratio, w_size_default=p.w_size_default,
                                      w_size_max=p.w_size_max, n_pmin=p.n_pmin, n_pmax=p.n_pmax, band_deg=band_deg,
                                      shift_px=ghost, workers=min(2, os.cpu_count() or 1))
        rows.append({"ghost_px": ghost, "band_deg": band_deg, "frames": frames, "seed": seed, **c})
        say("pirf-dictionary", quiet, f"{data.name}: in-band features with a twin {c['feature_twins_band_pct']:.1f} % "
                                      f"(outside {c['feature_twins_out_pct']:.1f} %), ghost pairs {c['ghost_pairs']}")
    with open(out / "seam_frames.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rows for k in r)), restval="")
        w.writeheader()
        w.writerows(rows)
    lines = [f"# Seam ghosting within frames (seed {seed}, {frames} frames each, no mapping)", "",
             "| ghost px | band deg | seam-band PIRFs % | features with an in-frame twin: bands / outside % "
             "| in-band twins that are ghost pairs | PIRFs with an in-frame twin: bands / outside % |", "|" + "---|" * 6]
    for r in rows:
        lines.append(f"| {r['ghost_px']:g} | {r['band_deg']:g} | {r['band_pirfs_pct']:.1f} | {r['feature_twins_band_pct']:.1f} / "
                     f"{r['feature_twins_out_pct']:.1f} | {r['ghost_pairs']} of {r['twins_band']} "
                     f"| {r['pirf_twins_band_pct']:.1f} / {r['pirf_twins_out_pct']:.1f} |")
    (out / "seam_frames.md").write_text("\n".join(lines) + "\n")
    return rows


def _data(out: Path, prop: Property, level: float, seed: int, quiet: bool) -> Path:
    data = out / "data" / f"{prop.name}-{level:g}-seed{seed}"
    meta = data / "params.json"
    want = {"seed": seed, "frames": prop.frames, "test_frames": 2, "width": 480, "layout": "building", prop.param: level}
    if meta.is_file() and json.loads(meta.read_text()) == want:
        return data
    say("pirf-dictionary", quiet, f"rendering {data.name}: {prop.frames} frames")
    generate(data, **want, workers=min(2, os.cpu_count() or 1))
    meta.write_text(json.dumps(want))
    return data


def measure_video(out: Path, prop: Property, level: float, seed: int, quiet: bool = True) -> dict[str, Any]:
    """Render one video (or re-use it), extract its PIRFs with the pipeline and count."""
    data = _data(out, prop, level, seed, quiet)
    rd = out / "runs" / data.name
    cfg = load_config(data={"method": "pirf", "seed": seed, "reference": {"images": str(data / "mapping")},
                            "executor": {"workers": min(2, os.cpu_count() or 1)}})
    t0 = time.perf_counter()
    run(cfg, rd, stages="extract", quiet=True)
    pirfs, off = read_pirfs(rd, "reference")
    p = PirfParams()
    row: dict[str, Any] = {"property": prop.name, "level": level, "seed": seed}
    if prop.name == "seam":
        paths = sorted((data / "mapping").glob("frame_*.png"))
        again, band, counts = seam_marks(paths, features=p.features, n_features=p.n_features, ratio=p.ratio,
                                         w_size_default=p.w_size_default, w_size_max=p.w_size_max, n_pmin=p.n_pmin,
                                         n_pmax=p.n_pmax, band_deg=SEAM_BAND_DEG, shift_px=level,
                                         workers=min(2, os.cpu_count() or 1))
        if not np.array_equal(again, pirfs):
            raise RuntimeError(f"{data}: detecting the features again gave other PIRFs than {rd / 'extract.h5'}; "
                               "the seam-band marks would not fit (delete that run folder and re-run)")
        row.update(counts)
        row.update(dictionary_counts(pirfs, off, ratio=p.ratio, n_pmax=p.n_pmax, eps=int(p.eps), sigma=p.sigma,
                                     marked_rows=band))
    else:
        row.update(dictionary_counts(pirfs, off, ratio=p.ratio, n_pmax=p.n_pmax, eps=int(p.eps), sigma=p.sigma,
                                     marked=property_frames(prop.name, level, len(off) - 1)))
    row["seconds"] = time.perf_counter() - t0
    return row


CHAIN_FRAMES = 300  # frames re-detected per setting to find where within-frame twins come from


def chain_sources(out: Path, prop: Property, level: float, seed: int) -> dict[str, Any]:
    """:func:`merged_chains` on ``CHAIN_FRAMES`` frames of a rendered video that carry the
    property: the first ones for slow motion (three slow stretches), the last ones for
    revisits (the second lap), with table 1's parameters and the default features."""
    from placeloc.pirf.features import extract_frame

    p = PirfParams()
    data = _data(out, prop, level, seed, quiet=True)
    paths = sorted((data / "mapping").glob("frame_*.png"))
    paths = paths[:CHAIN_FRAMES] if prop.name == "slow" else paths[-CHAIN_FRAMES:]
    frames = ((d, r) for _xy, r, d, _shape in (extract_frame((str(q), p.features, p.n_features)) for q in paths))
    return merged_chains(frames, ratio=p.ratio, w_size_default=p.w_size_default, w_size_max=p.w_size_max, n_pmin=p.n_pmin,
                         n_pmax=p.n_pmax)


COLUMNS = ("plain", "improved", "reduction_pct", "within_frame_pct", "twins_plain_pct", "twins_improved_pct",
           "twins_plain_near_pct", "marked_frames", "plain_marked", "improved_marked", "reduction_marked_pct",
           "within_frame_marked_pct", "pirfs_per_frame")
# the seam rows' own counts (seam_marks), summarised where every row of a setting has them
SEAM_COLUMNS = ("marked_pirfs", "feature_twins_band_pct", "feature_twins_out_pct", "ghost_pairs_pct", "pirf_twins_band_pct",
                "pirf_twins_out_pct", "band_pirfs_pct")


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Median, min and max over seeds of every counted column, per (property, level)."""
    table = []
    for key in dict.fromkeys((r["property"], r["level"]) for r in rows):
        rr = [r for r in rows if (r["property"], r["level"]) == key]
        entry: dict[str, Any] = {"property": key[0], "level": key[1], "seeds": len(rr)}
        for c in COLUMNS + tuple(c for c in SEAM_COLUMNS if all(c in r for r in rr)):
            v = np.array([r[c] for r in rr], float)
            v = v[np.isfinite(v)]
            entry[c] = float(np.median(v)) if len(v) else float("nan")
            entry[f"{c}_min"] = float(v.min()) if len(v) else float("nan")
            entry[f"{c}_max"] = float(v.max()) if len(v) else float("nan")
        table.append(entry)
    return table


def _fmt(e: dict[str, Any], c: str, nd: int = 1) -> str:
    if not np.isfinite(e[c]):
        return "-"
    if e["seeds"] == 1 or e[f"{c}_min"] == e[f"{c}_max"]:
        return f"{e[c]:.{nd}f}"
    return f"{e[c]:.{nd}f} [{e[f'{c}_min']:.{nd}f}, {e[f'{c}_max']:.{nd}f}]"


def _write(out: Path, rows: list[dict[str, Any]], table: list[dict[str, Any]], props: tuple[Property, ...]) -> None:
    for path, rr in ((out / "runs.csv", rows), (out / "table.csv", table)):
        with open(path, "w", newline="") as fh:
            # the seam setting's rows carry its seam counts, the others' leave them empty
            w = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(k for r in rr for k in r)), restval="")
            w.writeheader()
            w.writerows(rr)
    units = {p.name: p for p in props}
    lines = ["# PIRF dictionary: plain vs improved update as properties of real video grow", "",
             "Median [min, max] over seeds. Percentages: reduction = 1 - improved/plain; within-frame = PIRFs the plain "
             "update inserts that the improved rule would reject in the same frame (share of the plain dictionary); twins = "
             "words whose nearest other word passes the ratio test (share of that dictionary), near = twin inserted within "
             "eps frames. 'marked' = the frames carrying the property (slow stretches; laps after the first). The last two "
             f"columns: seed {rows[0]['seed']} only, {CHAIN_FRAMES} frames carrying the property, features re-detected: PIRFs with a "
             "ratio-test twin among the other PIRFs of their frame, and the share of those whose chain merged with another "
             "(two features of frame t matched the same feature of t-1).", ""]
    for name in dict.fromkeys(e["property"] for e in table):
        pr = units[name]
        if name == "seam":
            lines += _seam_table(pr, [e for e in table if e["property"] == name])
            continue
        lines += [f"## {name}: {pr.unit}, {pr.frames} mapping frames", "",
                  "| level | plain | improved | reduction % | within-frame % | twins plain % | twins improved % | twins near % "
                  "| marked frames | reduction in marked % | within-frame in marked % | PIRFs with an in-frame twin % "
                  "| of those, merged chains % |", "|" + "---|" * 13]
        for e in (e for e in table if e["property"] == name):
            lines.append(f"| {e['level']:g} | {_fmt(e, 'plain', 0)} | {_fmt(e, 'improved', 0)} | {_fmt(e, 'reduction_pct')} "
                         f"| {_fmt(e, 'within_frame_pct')} | {_fmt(e, 'twins_plain_pct')} | {_fmt(e, 'twins_improved_pct')} "
                         f"| {_fmt(e, 'twins_plain_near_pct')} | {_fmt(e, 'marked_frames', 0)} | {_fmt(e, 'reduction_marked_pct')} "
                         f"| {_fmt(e, 'within_frame_marked_pct')} | {e['chains_twins_in_frame_pct']:.1f} "
                         f"| {100 * e['chains_twins_in_merged_chain'] / max(e['chains_twins_in_frame'], 1):.0f} |")
        lines.append("")
    (out / "tables.md").write_text("\n".join(lines))
    _plot(out / "reduction.png", table, units)


def _seam_table(pr: Property, entries: list[dict[str, Any]]) -> list[str]:
    """The seam setting's table: 'marked' = PIRFs whose feature lies in a seam band, plus
    what the ghosting does to the features of a frame (all frames of every seed)."""
    lines = [f"## {pr.name}: {pr.unit}, {pr.frames} mapping frames, {SEAM_BAND_DEG:g} deg bands", "",
             "Marked = PIRFs whose feature in the newest frame lies in a seam band. In-frame twins: features (PIRFs) "
             "whose nearest other feature (PIRF) of the same frame passes the ratio test; ghost pairs: in-band feature "
             "twins lying the ghost offset (+-1.5 px) to the side at the same height.", "",
             "| level | plain | improved | reduction % | reduction of seam-band words % | within-frame % "
             "| within-frame among seam-band words % | seam-band PIRFs % | features with an in-frame twin: bands / outside % "
             "| of in-band twins, ghost pairs % | PIRFs with an in-frame twin: bands / outside % | twins plain / improved % |",
             "|" + "---|" * 12]
    for e in entries:
        lines.append(f"| {e['level']:g} | {_fmt(e, 'plain', 0)} | {_fmt(e, 'improved', 0)} | {_fmt(e, 'reduction_pct')} "
                     f"| {_fmt(e, 'reduction_marked_pct')} | {_fmt(e, 'within_frame_pct')} | {_fmt(e, 'within_frame_marked_pct')} "
                     f"| {_fmt(e, 'band_pirfs_pct')} | {_fmt(e, 'feature_twins_band_pct')} / {_fmt(e, 'feature_twins_out_pct')} "
                     f"| {_fmt(e, 'ghost_pairs_pct', 0)} | {_fmt(e, 'pirf_twins_band_pct')} / {_fmt(e, 'pirf_twins_out_pct')} "
                     f"| {e['twins_plain_pct']:.1f} / {e['twins_improved_pct']:.1f} |")
    return lines + [""]


def _plot(path: Path, table: list[dict[str, Any]], units: dict[str, Property]) -> None:
    plt = pyplot()
    names = list(dict.fromkeys(e["property"] for e in table))
    # one panel alone (one property run) still needs room for the title and the legend
    fig, axes = plt.subplots(1, len(names), figsize=(max(5.5 * len(names), 8.0), 4.4 if len(names) > 1 else 5.0), squeeze=False, sharey=True)
    for ax, name in zip(axes[0], names):
        ee = [e for e in table if e["property"] == name]
        x = np.arange(len(ee))
        for c, label, mk in (("reduction_pct", "dictionary reduction by the improved update, all frames", "o-"),
                             ("reduction_marked_pct", "the same, words from the frames (seam: the bands) with the property", "s--"),
                             ("within_frame_pct", "within-frame duplicates the plain update inserts", "^:")):
            y = np.array([e[c] for e in ee])
            lo = y - np.array([e[f"{c}_min"] for e in ee])
            hi = np.array([e[f"{c}_max"] for e in ee]) - y
            ax.errorbar(x, y, yerr=[np.nan_to_num(lo), np.nan_to_num(hi)], fmt=mk, capsize=3, label=label)
        ax.set_xticks(x)
        ax.set_xticklabels([f"{e['level']:g}" for e in ee])
        ax.set_xlabel(units[name].unit)
        ax.set_title(f"{name} ({units[name].frames} mapping frames, {ee[0]['seeds']} seeds)", fontsize=10)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("% of the plain dictionary\n(median, bars: min-max over seeds)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    rows = 1 if len(names) > 1 else len(labels)  # one panel is too narrow for the legend in one row
    fig.legend(handles, labels, loc="lower center", ncol=len(labels) if rows == 1 else 1, fontsize=8, frameon=False)
    fig.suptitle("Improved PIRF dictionary update (Sasaki and Hamagami; the paper: -34 %) on generated video", fontsize=10)
    fig.tight_layout(rect=(0, 0.07 if rows == 1 else 0.16, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(out_dir: Path, quick: bool = False, quiet: bool = False, seeds: tuple[int, ...] | None = None,
         properties: tuple[Property, ...] | None = None) -> Path:
    """Every (property, level, seed) video; rows are cached in ``rows.json`` so a re-run only
    measures what is missing. ``quick``: seed 0 only, each property's absent and largest level."""
    pyplot()  # its figures need matplotlib: stop now, not after the runs, where it is missing
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    seeds = seeds or ((0,) if quick else SEEDS)
    props = properties or PROPERTIES
    if quick:
        props = tuple(Property(p.name, p.param, (p.levels[0], p.levels[-1]), p.frames, p.unit) for p in props)
    cache_path = out / "rows.json"
    cache = json.loads(cache_path.read_text()) if cache_path.is_file() else {}
    rows = []
    # seed by seed, so that an interrupted run leaves whole seeds (re-running resumes)
    for prop in props:
        for seed in seeds:
            for level in prop.levels:
                key = json.dumps({**asdict(prop), "levels": None, "level": level, "seed": seed}, sort_keys=True)
                if key not in cache:
                    cache[key] = measure_video(out, prop, level, seed, quiet=quiet)
                    cache_path.write_text(json.dumps(cache, indent=1))
                    r = cache[key]
                    say("pirf-dictionary", quiet, f"{prop.name} {level:g} seed {seed}: plain {r['plain']}, improved {r['improved']} "
                                f"({r['reduction_pct']:.1f} %), within-frame {r['within_frame_pct']:.1f} %, {r['seconds']:.0f} s")
                rows.append(cache[key])
    rows.sort(key=lambda r: ([p.name for p in props].index(r["property"]), r["level"] if r["property"] != "slow" else -r["level"],
                             r["seed"]))
    table = summarise(rows)
    for e in table:  # one seed: re-detecting features is as slow as extraction
        if e["property"] == "seam":  # its rows carry their own in-frame counts (seam_marks)
            continue
        key = json.dumps({"chains": e["property"], "level": e["level"], "seed": seeds[0], "frames": CHAIN_FRAMES})
        if key not in cache:
            prop = next(p for p in props if p.name == e["property"])
            cache[key] = chain_sources(out, prop, e["level"], seeds[0])
            cache_path.write_text(json.dumps(cache, indent=1))
        e.update({f"chains_{k}": v for k, v in cache[key].items()})
    _write(out, rows, table, props)
    return write_summary(out, {f"{e['property']}-{e['level']:g}": e for e in table})


if __name__ == "__main__":
    cli = argparse.ArgumentParser(description="PIRF plain vs improved dictionary as properties of real video grow.")
    cli.add_argument("--out", type=Path, default=Path("runs/experiment-pirf-dictionary"), help="output folder")
    cli.add_argument("--only", default="", help=f"comma-separated properties ({', '.join(p.name for p in PROPERTIES)}); "
                                                 "default all")
    cli.add_argument("--quick", action="store_true", help="seed 0, each property's absent and largest level")
    cli.add_argument("--seeds", default="", help="comma-separated seeds (default 0,1,2)")
    cli.add_argument("--seam-frames", default="", help="instead: in-frame seam counts only, for GHOST:BAND settings "
                                                       "(px:deg, comma-separated), e.g. 24:20,24:40,48:40")
    args = cli.parse_args()
    if args.seam_frames:
        pairs = [tuple(float(v) for v in item.split(":")) for item in args.seam_frames.split(",") if item.strip()]
        if any(len(x) != 2 for x in pairs):
            cli.error(f"--seam-frames {args.seam_frames!r}: expected GHOST:BAND pairs such as 24:40")
        args.out.mkdir(parents=True, exist_ok=True)
        seam_frame_check(args.out, [(g, b) for g, b in pairs])
        print(f"results: {args.out / 'seam_frames.md'}")
        raise SystemExit(0)
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = sorted(set(names) - {p.name for p in PROPERTIES})
    if unknown:
        cli.error(f"--only: unknown propert{'ies' if len(unknown) > 1 else 'y'} {', '.join(unknown)}; "
                  f"choose from {', '.join(p.name for p in PROPERTIES)}")
    chosen = tuple(p for p in PROPERTIES if p.name in names) or None
    seeds = tuple(int(x) for x in args.seeds.split(",") if x.strip()) or None
    print(f"results: {main(args.out, quick=args.quick, seeds=seeds, properties=chosen)}")
