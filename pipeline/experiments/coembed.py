"""``placeloc experiment coembed``: the paper's simulation (fig. 4) over many seeds, and tears-of-steel.

Runs, for each seed, the ABCD world with both sensors (bearing only, range only) and the
three methods (co-embedding, Isomap, PCAMD); then the real 2-D tracks of tears-of-steel
(3-D points, checked against the solved points) when ../shared/data is present. Leaves
``summary.json`` (run name -> metrics), ``aggregate.json`` and ``table.md``.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
from placeloc.config import load_config
from placeloc.experiments import shared_data_dir, write_summary
from placeloc.runner import run_all
from placeloc.synth import generate

log = logging.getLogger("placeloc")

SOLVERS = ("coembed", "isomap", "pcamd")
SENSORS = ("bearing", "range")
# Tears-of-steel landmark sets: "spread" spans the depth range (5 m to 50 m), "near" only the near points (5-8 m).
TEARS_LANDMARKS = {"spread": [1, 5, 7, 10, 14, 17, 21, 22, 23, 25], "near": [0, 4, 8, 12, 16, 20, 24, 7]}
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
    out_dir = Path(out_dir)
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
    root = shared_data_dir()
    tears = root / "tears-of-steel" if root is not None else None
    if tears is not None and (tears / "markers.csv").is_file():
        lines += ["", "## tears-of-steel (333 frames x 26 tracks, 2-D sightings -> 3-D points)", "",
                  "| landmarks | method | map RMSE (m) | median error (m) | max error (m) | blind RMSE (m) |", "|---|---|---|---|---|---|"]
        pts = np.loadtxt(tears / "points.csv", delimiter=",", skiprows=1)
        for variant, lm in TEARS_LANDMARKS.items():
            rest = pts[~np.isin(pts[:, 0], lm), 1:]
            blind = float(np.sqrt(np.mean(np.sum((rest - pts[np.isin(pts[:, 0], lm), 1:].mean(axis=0)) ** 2, axis=1))))
            for solver in SOLVERS:
                name = f"tears-of-steel-{variant}-{solver}"
                config = load_config(data={"method": "coembed", "coembed": {
                    "observations": str(tears / "markers.csv"), "landmarks": str(tears / "points.csv"), "landmark_ids": lm,
                    "truth": str(tears / "points.csv"), "dim": 3, "solver": solver, "pcamd_rank": 4, "isomap_neighbors": 6}})
                m = _run(config, out_dir / name, quiet)
                m["blind_rmse"] = blind
                runs[name] = m
                write_summary(out_dir, runs)
                cells = ["failed" if m.get(k) is None else f"{m[k]:.2f}" for k in ("map_rmse", "map_median_error", "map_max_error")]
                lines.append(f"| {variant} ({len(lm)}) | {solver} | {' | '.join(cells)} | {blind:.2f} |")
        lines += ["", "Blind RMSE: every unknown point placed at the landmarks' centroid (the no-information answer)."]
    else:
        lines += ["", "tears-of-steel: ../shared/data/tears-of-steel absent, skipped."]
    write_summary(out_dir, runs)
    (out_dir / "aggregate.json").write_text(json.dumps(agg, indent=2, sort_keys=True))
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir
