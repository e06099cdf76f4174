"""Parameter sweeps (OpenSeqSLAM2's batch mode for any config key): every combination of
the ``--grid key=v1,v2,...`` values runs as its own run directory under the sweep folder
(so an interrupted sweep resumes: finished combinations are up to date and skipped),
then one table (``sweep.md``, ``sweep.csv``) and one figure (``sweep.png``: PR curves and
Recall@N of every combination) sum it up."""

from __future__ import annotations

import copy
import csv
import itertools
import json
import logging
from pathlib import Path
from typing import Any, Sequence

import h5py
import numpy as np
import yaml

from placeloc.core.artifacts import atomic_open
from placeloc.core.config import ConfigError, apply_override, validate
from placeloc.core.safe_io import load_yaml

log = logging.getLogger("placeloc")
TABLE_KEYS = ("recall_at_1", "recall_at_5", "recall_at_10", "recall_at_20",
              "separated_recall_at_5", "auc_pr", "recall_at_100_precision", "max_f1", "n_queries")


def split_values(raw: str) -> list[str]:
    """``"10,[64, 32],'a,b'"`` -> ``["10", "[64, 32]", "'a,b'"]``: the commas between values,
    not those inside brackets, braces or quotes (a list such as a thumbnail size is one
    value)."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(raw):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth = max(0, depth - 1)
        elif ch == "," and depth == 0:
            parts.append(raw[start:i])
            start = i + 1
    parts.append(raw[start:])
    return parts


def parse_grid(items: Sequence[str]) -> list[tuple[str, list[Any]]]:
    """``["seqslam.ds=10,20", "seqslam.comparison=sad,zncc"]`` -> [(key, [values])]; values
    are parsed as YAML (``10`` is an integer) and split at the commas between them
    (:func:`split_values`: ``seqslam.thumbnail=[64,32],[32,16]`` is two values)."""
    grid = []
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--grid {item!r}: expected key.path=v1,v2,..., e.g. --grid seqslam.ds=10,20,30")
        key, raw = item.split("=", 1)
        try:
            values = [load_yaml(v, f"--grid {key.strip()} value") for v in split_values(raw) if v.strip()]
        except yaml.YAMLError as exc:
            shown = item if len(item) <= 80 else f"{item[:60]}... ({len(item):,} characters)"
            problem = getattr(exc, "problem", None) or " ".join(str(exc).split())
            raise ConfigError(f"--grid {shown!r}: a value is not valid YAML ({problem}); e.g. --grid "
                              f"{key.strip()}=10,20") from None
        if not values:
            raise ConfigError(f"--grid {item!r}: no values after '='")
        grid.append((key.strip(), values))
    keys = [k for k, _ in grid]
    if len(set(keys)) != len(keys):
        raise ConfigError(f"--grid names a key twice ({keys}); give all its values in one --grid")
    return grid


def _label(combo: dict[str, Any]) -> str:
    return ",".join(f"{k.split('.')[-1]}={v}" for k, v in combo.items())


def _dir_name(combo: dict[str, Any]) -> str:
    text = "__".join(f"{k}={v}" for k, v in combo.items())
    return "".join(c if c.isalnum() or c in "=._-" else "_" for c in text)


def run_sweep(raw_config: dict[str, Any], base_dir: Path, grid: list[tuple[str, list[Any]]], out_dir: str | Path,
              *, quiet: bool = True, force: bool = False) -> Path:
    """Run every combination (each validated first, so a bad value fails before any
    work) and write the table and figure; returns the path of ``sweep.md``."""
    from placeloc.api import run
    from placeloc.evaluation.plots import plot_sweep

    out_dir = Path(out_dir)
    combos = [dict(zip([k for k, _ in grid], values)) for values in itertools.product(*[v for _, v in grid])]
    configs = []
    for combo in combos:
        data = copy.deepcopy(raw_config)
        for key, value in combo.items():
            apply_override(data, f"{key}={json.dumps(value)}")
        configs.append(validate(data, base_dir))
    rows: list[dict[str, Any]] = []
    all_metrics: list[dict[str, Any]] = []
    curves: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    recalls: dict[str, tuple[list[int], list[float | None]]] = {}
    errors: dict[str, np.ndarray] = {}  # pose results: each run's position errors
    run_dirs = [out_dir / _dir_name(combo) for combo in combos]
    for i, (combo, cfg, run_dir) in enumerate(zip(combos, configs, run_dirs), start=1):
        log.info("sweep %d/%d: %s", i, len(combos), _label(combo))
        # the stages the points share (same stamp: e.g. extract when only localize keys vary)
        # are linked from another point's folder, not computed again
        run(cfg, run_dir, force=force, quiet=quiet, reuse=[d for d in run_dirs if d != run_dir])
        metrics = json.loads((run_dir / "metrics.json").read_text()) if (run_dir / "metrics.json").is_file() else {}
        rows.append({"run": run_dir.name, **combo})
        all_metrics.append(metrics)
        label = _label(combo)
        if (run_dir / "evaluate.h5").is_file():
            with h5py.File(run_dir / "evaluate.h5", "r") as f:
                if "pr" in f:
                    curves[label] = (f["pr/recall"][()], f["pr/precision"][()])
                if "error_m" in f:
                    errors[label] = f["error_m"][()]
        ns = sorted(int(k.split("_")[-1]) for k in metrics if k.startswith("recall_at_") and k[-1].isdigit()
                    and k[len("recall_at_"):].isdigit())
        if ns:
            recalls[label] = (ns, [metrics[f"recall_at_{n}"] for n in ns])
    figures = table_keys(all_metrics)
    for row, metrics in zip(rows, all_metrics):
        row.update({k: metrics.get(k) for k in figures})
    columns = ["run", *combos[0].keys(), *figures] if combos else ["run"]
    with atomic_open(out_dir / "sweep.csv", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        w.writeheader()
        w.writerows(rows)

    def cell(v: Any) -> str:
        return "n/a" if v is None else f"{v:.3f}" if isinstance(v, float) else str(v)

    lines = [f"# Sweep: {', '.join(k for k, _ in grid)} ({len(combos)} runs)", "",
             "| " + " | ".join(columns[1:]) + " |", "|" + "---|" * (len(columns) - 1)]
    lines += ["| " + " | ".join(cell(r.get(c)) for c in columns[1:]) + " |" for r in rows]
    if any(k.startswith("recall_at_") for k in figures):
        lines += ["", "recall_at_N (standard Recall@N) divides by all queries; see docs/evaluation.md."]
    lines += [""]
    with atomic_open(out_dir / "sweep.md") as fh:
        fh.write("\n".join(lines))
    title = f"Sweep over {', '.join(k for k, _ in grid)}"
    if curves or recalls:
        plot_sweep(curves, recalls, out_dir / "sweep.png", title=title)
    elif errors:
        from placeloc.evaluation.pose_estimates import plot_error_cdfs

        plot_error_cdfs(out_dir / "sweep.png", errors, title=title)
    return out_dir / "sweep.md"


def table_keys(runs: Sequence[dict[str, Any]]) -> list[str]:
    """The table's figures: those of :data:`TABLE_KEYS` that some run has (place
    recognition's), then each run's own headline figures (``metrics["headline"]``: a pose
    method's shares within 1 m and its errors, co-embedding's RMS) in their order; all of
    :data:`TABLE_KEYS` when no run has a figure (no ground truth: every cell n/a)."""
    keys = [k for k in TABLE_KEYS if any(k in m for m in runs)]
    for m in runs:
        keys += [k for k in m.get("headline", []) if k not in keys and k in m]
    return keys or list(TABLE_KEYS)
