"""``placeloc experiment coembed``: the paper's simulation (fig. 4) over many seeds, and tears-of-steel.

Runs, for each seed, the ABCD world with both sensors (bearing only, range only) and the
three methods (co-embedding, Isomap, PCAMD); then camera tracks, 2-D image points of 3-D
points: six synthetic ones with lens distortion (``synth coembed world=camera``, the fixed
landmark rule and 5 random sets each) and the real tracks of tears-of-steel when the shared
data folder has them (the fixed rule and 20 random landmark sets of 10, seeds 0-19, listed
in the table). Five methods on each (co-embedding pinhole / perspective / paper's form,
Isomap, PCAMD), each with its settings chosen by leave-one-landmark-out cross-validation,
against two blind references. Landmark warnings are logged once per cause and counted. Leaves ``summary.json`` (run name -> metrics),
``aggregate.json`` and ``table.md``.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.config import load_config
from placeloc.core.runner import run_all
from placeloc.experiments import shared_data_dir, write_summary
from placeloc.synth import generate

log = logging.getLogger("placeloc")

SOLVERS = ("coembed", "isomap", "pcamd")
SENSORS = ("bearing", "range")
# Real tracks: every method with its free settings chosen by leave-one-landmark-out cross-validation.
TEARS_METHODS = {
    "coembed-pinhole": {"solver": "coembed", "camera_model": "pinhole", "alpha_select": "loo"},
    "coembed-perspective": {"solver": "coembed", "camera_model": "perspective", "alpha_select": "loo"},
    "coembed-paper": {"solver": "coembed", "camera_model": "linear", "alpha_select": "loo", "intrinsics": None},
    "isomap": {"solver": "isomap", "isomap_neighbors_select": "loo"},
    "pcamd": {"solver": "pcamd", "pcamd_rank": 4},
}
TEARS_LANDMARK_COUNT = 10
CAMERA_SEEDS = (0, 1, 2, 3, 4, 5)   # synthetic perspective camera tracks (synth coembed world=camera), a known answer


class _OncePerCause(logging.Filter):
    """Lets through the first landmark warning of each cause and counts the rest (one experiment runs many landmark sets)."""

    def __init__(self) -> None:
        super().__init__()
        self.counts: dict[str, int] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        cause = getattr(record, "coembed_warning_cause", None)
        if cause is None:
            return True
        self.counts[cause] = self.counts.get(cause, 0) + 1
        if self.counts[cause] == 1:
            record.msg = f"{record.msg} (shown once; the experiment counts the runs it applies to)"
            return True
        return False
PAPER = "co-embedding has the smallest map error for both sensors (fig. 4; no numbers given)"


def _run(config: dict, run_dir: Path, quiet: bool) -> dict[str, Any]:
    t0 = time.perf_counter()
    try:
        run_all(config, run_dir, force=True, quiet=quiet)
        m = json.loads((run_dir / "metrics.json").read_text())
    except Exception as exc:  # noqa: BLE001 - a failed run is a result of the experiment, recorded with its reason
        log.warning("%s failed: %s", run_dir.name, exc)
        m = {"error": f"{type(exc).__name__}: {exc}", "map_rmse": None, "map_max_error": None, "path_rmse": None}
    m["wall_seconds"] = time.perf_counter() - t0
    return m


def _stats(values: list[float | None]) -> dict[str, Any]:
    v = np.array([x for x in values if x is not None], dtype=float)
    if not len(v):
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0, "min": float(v.min()),
            "max": float(v.max()), "n": int(len(v))}


def _fmt(s: dict) -> str:
    return "failed" if s["mean"] is None else f"{s['mean']:.2f} ± {s['std']:.2f}"


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    once = _OncePerCause()
    log.addFilter(once)
    try:
        return _main(Path(out_dir), quick, quiet, once)
    finally:
        log.removeFilter(once)


def _main(out_dir: Path, quick: bool, quiet: bool, once: _OncePerCause) -> Path:
    seeds = range(2) if quick else range(10)
    steps = 800 if quick else 2000
    runs: dict[str, dict[str, Any]] = {}
    for seed in seeds:
        world = out_dir / "data" / f"abcd-seed{seed}"
        generate("coembed", world, seed=seed, steps=steps)
        for sensor in SENSORS:
            for solver in SOLVERS:
                name = f"abcd-{sensor}-{solver}-seed{seed}"
                config = load_config(world / f"{sensor}.yaml", [f"coembed.solver={solver}", "plots=true" if seed == 0 else "plots=false"])
                runs[name] = _run(config, out_dir / name, quiet)
                log.info("%s: map RMSE %s", name, runs[name].get("map_rmse"))
                write_summary(out_dir, runs)   # after every run: a stopped experiment still leaves its results
    agg: dict[str, Any] = {}
    lines = [f"# Co-embedding experiment ({len(seeds)} seeds, {steps}+ steps, 200 features, 11 landmarks)", "",
             f"Paper's finding: {PAPER}.", "",
             "Map error in metres over the 189 non-landmark features, mean ± sample std over seeds.", "",
             "| sensor | method | map RMSE | map max error | path RMSE | best on seeds | failed runs |", "|---|---|---|---|---|---|---|"]
    for sensor in SENSORS:
        best = {s: 0 for s in SOLVERS}
        for seed in seeds:
            vals = {s: runs[f"abcd-{sensor}-{s}-seed{seed}"]["map_rmse"] for s in SOLVERS}
            ok = {s: v for s, v in vals.items() if v is not None}
            if ok:
                best[min(ok, key=ok.get)] += 1
        for solver in SOLVERS:
            ms = [runs[f"abcd-{sensor}-{solver}-seed{s}"] for s in seeds]
            st = {k: _stats([m.get(k) for m in ms]) for k in ("map_rmse", "map_max_error", "path_rmse")}
            failed = sum("error" in m for m in ms)
            agg[f"abcd-{sensor}-{solver}"] = {**st, "best_on_seeds": best[solver], "failed": failed}
            path = _fmt(st["path_rmse"]) if st["path_rmse"]["n"] else "-"
            lines.append(f"| {sensor} | {solver} | {_fmt(st['map_rmse'])} | {_fmt(st['map_max_error'])} | {path} | "
                         f"{best[solver]}/{len(seeds)} | {failed} |")
    for seed in CAMERA_SEEDS[:1] if quick else CAMERA_SEEDS:
        world = out_dir / "data" / f"camera-seed{seed}"
        generate("coembed", world, seed=seed, world="camera")
        lines += tears_table(world, out_dir, runs, agg, n_random=3 if quick else 5, quiet=quiet, name=f"camera{seed}",
                             title=f"synthetic camera track, seed {seed}, synth coembed world=camera: radial distortion, 0.7 px noise")
    root = shared_data_dir()
    tears = root / "tears-of-steel" if root is not None else None
    if tears is not None and (tears / "markers.csv").is_file():
        lines += tears_table(tears, out_dir, runs, agg, n_random=5 if quick else 20, quiet=quiet)
    else:
        lines += ["", "tears-of-steel: ../shared/data/tears-of-steel absent, skipped."]
    if once.counts:
        lines += ["", "Landmark warnings (each logged once): " + "; ".join(f"{c}: {k} runs" for c, k in sorted(once.counts.items()))]
    write_summary(out_dir, runs)
    (out_dir / "aggregate.json").write_text(json.dumps(agg, indent=2, sort_keys=True))
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir


def random_landmark_sets(track_ids: np.ndarray, n_sets: int, size: int) -> list[list[int]]:
    """Landmark set i is ``size`` tracks drawn without replacement by ``numpy.random.default_rng(i)``."""
    return [sorted(int(t) for t in np.random.default_rng(i).choice(track_ids, size, replace=False)) for i in range(n_sets)]


def _blind(points: np.ndarray, lm: list[int]) -> tuple[float, float]:
    """RMSE of the two references that use no observations: every unknown point at the landmarks'
    centroid, and at the evaluated points' own centroid (an oracle: it needs their truth)."""
    is_lm = np.isin(points[:, 0], lm)
    rest, known = points[~is_lm, 1:], points[is_lm, 1:]

    def rmse(c: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum((rest - c) ** 2, axis=1))))

    return rmse(known.mean(axis=0)), rmse(rest.mean(axis=0))


def tears_table(tears: Path, out_dir: Path, runs: dict, agg: dict, n_random: int, quiet: bool, name: str = "tears",
                title: str = "tears-of-steel problem 01") -> list[str]:
    """Map RMSE on a camera track (tears-of-steel problem 01, or a synthetic one in the same layout) over the fixed
    landmark rule and ``n_random`` random sets."""
    points = np.loadtxt(tears / "points.csv", delimiter=",", skiprows=1)
    sets: dict[str, dict] = {"fixed-rule": {"landmark_count": TEARS_LANDMARK_COUNT}}
    for i, lm in enumerate(random_landmark_sets(points[:, 0].astype(int), n_random, TEARS_LANDMARK_COUNT)):
        sets[f"random{i:02d}"] = {"landmark_ids": lm}
    cols = list(TEARS_METHODS) + ["blind-landmarks", "blind-evaluated"]
    per: dict[str, dict[str, float | None]] = {}
    for set_name, lm_cfg in sets.items():
        per[set_name] = {}
        for label, settings in TEARS_METHODS.items():
            section = {"observations": str(tears / "markers.csv"), "landmarks": str(tears / "points.csv"),
                       "truth": str(tears / "points.csv"), "intrinsics": str(tears / "intrinsics.csv"), "dim": 3,
                       **lm_cfg, **settings}
            run_name = f"{name}-{set_name}-{label}"
            plots = set_name == "fixed-rule"
            m = _run(load_config(data={"method": "coembed", "plots": plots, "coembed": section}), out_dir / run_name, quiet)
            runs[run_name] = m
            per[set_name][label] = m.get("map_rmse")
            if label == next(iter(TEARS_METHODS)):
                lm_used = _landmarks_of(out_dir / run_name, lm_cfg)
                per[set_name]["landmarks"] = lm_used  # type: ignore[assignment]
            write_summary(out_dir, runs)
        lm_used = per[set_name]["landmarks"] or []
        per[set_name]["blind-landmarks"], per[set_name]["blind-evaluated"] = _blind(points, lm_used) if lm_used else (None, None)
        log.info("%s %s: %s", name, set_name, {k: v for k, v in per[set_name].items() if k != "landmarks"})
    rand = [k for k in sets if k != "fixed-rule"]
    n_tracks = len(points)
    lines = ["", f"## {title} ({n_tracks} tracks, 2-D sightings -> 3-D points; {TEARS_LANDMARK_COUNT} landmarks)",
             "", f"Map RMSE (m) over the {n_tracks - TEARS_LANDMARK_COUNT} non-landmark points. "
             f"Random sets: median [min, max] over {len(rand)} sets; "
             f"'best' counts the sets on which that method had the lowest RMSE of the {len(TEARS_METHODS)} methods.", "",
             "| method | fixed rule | random sets: median [range] | best on |", "|---|---|---|---|"]
    wins = {c: 0 for c in TEARS_METHODS}
    for k in rand:
        vals = {c: per[k][c] for c in TEARS_METHODS if per[k][c] is not None}
        if vals:
            wins[min(vals, key=vals.get)] += 1
    for c in cols:
        v = np.array([per[k][c] for k in rand if per[k][c] is not None], dtype=float)
        fixed = per["fixed-rule"][c]
        cell = f"{np.median(v):.2f} [{v.min():.2f}, {v.max():.2f}]" if len(v) else "failed"
        best = f"{wins[c]}/{len(rand)}" if c in wins else "-"
        lines.append(f"| {c} | {'failed' if fixed is None else f'{fixed:.2f}'} | {cell} | {best} |")
        agg[f"{name}-{c}"] = {"fixed_rule": fixed, "median": float(np.median(v)) if len(v) else None,
                             "min": float(v.min()) if len(v) else None, "max": float(v.max()) if len(v) else None,
                             "n": int(len(v)), "best_on_sets": wins.get(c)}
    lines += ["", "Per landmark set (map RMSE, m):", "", "| set | landmarks | " + " | ".join(cols) + " |",
              "|---|---|" + "---|" * len(cols)]
    for k in sets:
        cells = " | ".join("-" if per[k][c] is None else f"{per[k][c]:.2f}" for c in cols)
        lines.append(f"| {k} | {' '.join(map(str, per[k]['landmarks'] or []))} | {cells} |")
    lines += ["", "Random set i: numpy.random.default_rng(i).choice(tracks, 10, replace=False). Fixed rule: farthest-point "
              "sampling on the known 3-D points from the most-seen track. blind-landmarks: every unknown point at the "
              "landmarks' centroid; blind-evaluated: at the unknown points' own centroid (an oracle that knows their truth)."]
    return lines


def _landmarks_of(run_dir: Path, lm_cfg: dict) -> list[int] | None:
    """The landmark ids a run used (the fixed rule picks them inside extract; read back from map.csv)."""
    if "landmark_ids" in lm_cfg:
        return list(lm_cfg["landmark_ids"])
    table = run_dir / "map.csv"
    if not table.is_file():
        return None
    data = np.loadtxt(table, delimiter=",", skiprows=1, ndmin=2)
    return sorted(int(f) for f in data[data[:, 1] == 1, 0])
