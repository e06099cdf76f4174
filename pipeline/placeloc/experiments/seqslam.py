"""``make experiment-seqslam``: the eight image comparisons for SeqSLAM on real and synthetic data.

Data sets: a generated route pair with strong illumination change (always), and
``../shared/data/corridor`` and ``../shared/data/nordland-dev`` when present. Every
comparison runs at ds = 10 and ds = 30, plus the best configuration we found for
nordland-dev. Writes per data set and ds a ``table.md``/``table.csv``/``pr_curves.png``,
one ``report.md`` with all tables, and ``summary.json`` (run name -> metrics).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from placeloc.core.config import load_config
from placeloc.core.runner import read_metrics, run_all
from placeloc.experiments import shared_data_dir, write_summary
from placeloc.experiments.compare import compare_methods, markdown_table
from placeloc.seqslam.comparisons import COMPARISONS
from placeloc.synth.route import generate

# The configuration that reaches the accuracy target on nordland-dev (R@1 and AUC >= 0.92): z-score
# patch normalisation (OpenSeqSLAM), 31-frame centred sequences.
NORDLAND_BEST = {"comparison": "sad", "normalisation": "zscore", "ds": 30, "search": "centred"}


def datasets(out: Path, quick: bool) -> dict[str, dict]:
    sets: dict[str, dict] = {}
    route = out / "data" / "route"
    if not (route / "ground_truth.csv").is_file():
        generate(route, seed=0, frames=150 if quick else 600, width=128, height=64)
    sets["synthetic-route"] = {"reference": {"images": str(route / "reference")}, "query": {"images": str(route / "query")},
                               "ground_truth": {"kind": "csv", "path": str(route / "ground_truth.csv")}}
    data = shared_data_dir()
    if data is not None and (data / "corridor").is_dir():
        c = data / "corridor"
        sets["corridor"] = {"reference": {"images": str(c / "ref")}, "query": {"images": str(c / "query")},
                            "ground_truth": {"kind": "csv", "path": str(c / "ground_truth.csv")}}
    if data is not None and (data / "nordland-dev").is_dir() and not quick:
        n = data / "nordland-dev"
        sets["nordland-dev"] = {"reference": {"images": str(n / "summer")}, "query": {"images": str(n / "winter")},
                                "ground_truth": {"kind": "synchronous", "tolerance": 2}}
    return sets


def main(out: Path, quick: bool = False, quiet: bool = False) -> Path:
    summary: dict[str, dict] = {}
    report = ["# SeqSLAM: the eight image comparisons (SeqSLAM, Milford and Wyeth, ICRA 2012, with illumination-robust comparisons)\n"]
    for name, base in datasets(out, quick).items():
        for ds in ((10,) if quick else (10, 30)):
            cfg = load_config(data={"method": "seqslam", **base, "seqslam": {"ds": ds}})
            title = f"{name}, ds = {ds}"
            table = compare_methods(cfg, out / name / f"ds{ds}", list(COMPARISONS), quiet=quiet, title=title)
            report.append(table.read_text())
            for comp in COMPARISONS:
                summary[f"{name}/ds{ds}/{comp}"] = read_metrics(out / name / f"ds{ds}" / comp)
        if name == "nordland-dev":
            cfg = load_config(data={"method": "seqslam", **base, "seqslam": NORDLAND_BEST})
            run_all(cfg, out / name / "best", quiet=quiet)
            m = read_metrics(out / name / "best")
            summary[f"{name}/best"] = m
            report.append(f"### {name}, best configuration {json.dumps(NORDLAND_BEST)}\n\n" + markdown_table([m]))
    write_summary(out, summary)
    (out / "report.md").write_text("\n".join(report))
    return out / "report.md"


# ---------------------------------------------------------------------------------------
# Presets on real data: chosen on one part, reported on the other
# ---------------------------------------------------------------------------------------
CONFIGS = Path(__file__).resolve().parents[3] / "configs"


def _subset(src: Path, dst: Path, lo: int, hi: int) -> Path:
    """Links to images lo..hi-1 (natural order) of ``src`` in ``dst``."""
    from placeloc.core.images import list_images

    dst.mkdir(parents=True, exist_ok=True)
    for p in list_images(src).paths[lo:hi]:
        link = dst / p.name
        if not link.exists():
            link.symlink_to(p.resolve())
    return dst


def _correct_per_query(run_dir: Path, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """From matches.csv: is query i's best reference inside [lo[i], hi[i]]?"""
    with open(run_dir / "matches.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    best = np.array([int(r["reference"]) if r["reference"] else -1 for r in rows])
    q = np.array([int(r["query"]) for r in rows])
    return (best >= lo[q]) & (best <= hi[q])


def _blocks(correct: np.ndarray, size: int) -> list[float]:
    return [float(correct[i:i + size].mean()) for i in range(0, len(correct) - size + 1, size)]


def presets(out: Path, quiet: bool = True) -> Path:
    """``configs/nordland.yaml`` on nordland-dev frames 1-600 (where it was chosen) and
    601-1200 (held out), each run on its own; ``configs/corridor.yaml`` with queries 0-54
    (chosen) and 55-110 (held out) scored from one run. R@1 per block of 100 (nordland)
    gives the spread. Writes ``presets.md`` and ``summary.json``."""
    data = shared_data_dir()
    # absolute: the subsets are handed to the presets as overrides, and a relative path in a
    # config resolves against the config's own folder (configs/), not the working folder
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    summary: dict[str, dict] = {}
    lines = ["# SeqSLAM presets: chosen on one part, reported on the other\n",
             "| preset | part | queries | R@1 | AUC | R@100P | R@1 single image | R@1 per 100 queries (min / median / max) |",
             "|---|---|---|---|---|---|---|---|"]
    if data is not None and (data / "nordland-dev").is_dir():
        nd = data / "nordland-dev"
        for part, (lo, hi) in (("1-600 (chosen on)", (0, 600)), ("601-1200 (held out)", (600, 1200))):
            tag = f"nordland-{lo + 1}-{hi}"
            ref = _subset(nd / "summer", out / "data" / tag / "summer", lo, hi)
            qry = _subset(nd / "winter", out / "data" / tag / "winter", lo, hi)
            cfg = load_config(CONFIGS / "nordland.yaml", [f"reference.images={ref}", f"query.images={qry}", "plots=false"])
            run_all(cfg, out / tag, quiet=quiet)
            m = read_metrics(out / tag)
            n = np.arange(hi - lo)
            blocks = _blocks(_correct_per_query(out / tag, n - 2, n + 2), 100)
            m["recall_at_1_per_100"] = blocks
            summary[tag] = m
            lines.append(f"| nordland | {part} | {m['n_queries']} | {m['recall_at_1']:.3f} | {m['auc_pr']:.3f} | "
                         f"{m['recall_at_100_precision']:.3f} | {m['single_image_recall_at_1']:.3f} | "
                         f"{min(blocks):.2f} / {float(np.median(blocks)):.2f} / {max(blocks):.2f} |")
    if data is not None and (data / "corridor").is_dir():
        cfg = load_config(CONFIGS / "corridor.yaml", ["plots=false"])
        run_all(cfg, out / "corridor", quiet=quiet)
        with open(data / "corridor" / "ground_truth.csv", newline="") as fh:
            gt = list(csv.DictReader(fh))
        lo = np.array([int(r["ref_first"]) for r in gt])
        hi = np.array([int(r["ref_last"]) for r in gt])
        ok = _correct_per_query(out / "corridor", lo, hi)
        m = read_metrics(out / "corridor")
        summary["corridor"] = m
        for part, sl in (("queries 0-54 (chosen on)", slice(0, 55)), ("queries 55-110 (held out)", slice(55, None))):
            summary[f"corridor/{part.split(' (')[0]}"] = {"recall_at_1": float(ok[sl].mean())}
            lines.append(f"| corridor | {part} | {len(ok[sl])} | {ok[sl].mean():.3f} | - | - | - | - |")
        lines.append(f"| corridor | all (one run) | {m['n_queries']} | {m['recall_at_1']:.3f} | {m['auc_pr']:.3f} | "
                     f"{m['recall_at_100_precision']:.3f} | {m['single_image_recall_at_1']:.3f} | - |")
    if not summary:
        lines.append("\nshared data (nordland-dev, corridor) not found: nothing to run")
    write_summary(out, summary)
    (out / "presets.md").write_text("\n".join(lines) + "\n")
    return out / "presets.md"


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="SeqSLAM presets on real data (chosen on one part, reported on the other)")
    ap.add_argument("--out", type=Path, default=Path("runs/seqslam-presets"))
    args = ap.parse_args()
    print((presets(args.out, quiet=False)).read_text())
