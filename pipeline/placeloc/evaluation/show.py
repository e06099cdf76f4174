"""Pictures of the matches: strips of query | best match | a true positive.

Reads a run directory: ``per_query.csv`` (written by evaluate, with ground truth) or,
without ground truth, ``matches.csv`` (written by localize: query image, best reference
image, confidence), and ``config.yaml`` for the image folders. Writes
``strips_sample.png`` (queries spread evenly over the traverse) and, with ground truth,
``strips_failures.png`` (the wrong matches made with the highest confidence, i.e. the
ones a threshold would let through first).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SAMPLE_PNG = "strips_sample.png"
FAILURES_PNG = "strips_failures.png"


class ShowError(ValueError):
    """The run directory lacks what the pictures need."""


@dataclass
class Row:
    query_image: str
    best_image: str
    confidence: float
    correct: bool | None  # None: no ground truth
    positive_image: str


def read_rows(run_dir: Path) -> list[Row]:
    """Per-query rows from per_query.csv, else matches.csv (no ground truth)."""
    per_query, matches = run_dir / "per_query.csv", run_dir / "matches.csv"
    rows: list[Row] = []
    if per_query.is_file():
        with per_query.open(newline="") as fh:
            for r in csv.DictReader(fh):
                rows.append(Row(r["query_image"], r["best_image"], _num(r["confidence"]),
                                r["correct"] == "1",
                                r["positive_image"]))
        return rows
    if matches.is_file():
        with matches.open(newline="") as fh:
            for r in csv.DictReader(fh):
                rows.append(Row(r.get("query_image", ""), r.get("reference_image", ""), _num(r.get("confidence", "")),
                                None, ""))
        return rows
    raise ShowError(f"{run_dir}: neither per_query.csv (evaluate) nor matches.csv (localize) is there; "
                    "run `placeloc localize CONFIG -o RUN_DIR` first")


def _num(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return float("nan")


def _folders(run_dir: Path) -> tuple[dict[str, Path], dict[str, Path]]:
    from placeloc.evaluation.report import run_config
    from placeloc.images import ImageError, list_images

    cfg = run_config(run_dir)
    if not cfg:
        raise ShowError(f"{run_dir}: holds no placeloc artifact; run `placeloc localize CONFIG -o {run_dir}` first")

    def names(role: str) -> dict[str, Path]:
        section = cfg.get(role) or {}
        if not section.get("images"):
            return {}
        try:
            return {p.name: p for p in list_images(section["images"]).paths}
        except ImageError:
            return {}

    ref = names("reference")
    query = names("query") or ref
    return ref, query


def _read(path: Path | None, shape: tuple[int, int]) -> np.ndarray:
    from placeloc.images import ImageError, read_rgb

    if path is None:
        return np.full((*shape, 3), 235, np.uint8)

    try:
        return read_rgb(path)  # upright (EXIF orientation), as the stages saw it
    except ImageError:
        return np.full((*shape, 3), 200, np.uint8)


def pick_sample(n: int, count: int) -> list[int]:
    """``count`` queries spread evenly over ``n`` (first and last included)."""
    if n == 0:
        return []
    return sorted(set(np.linspace(0, n - 1, min(count, n)).round().astype(int).tolist()))


def pick_failures(rows: list[Row], count: int) -> list[int]:
    """Wrong matches, most confident first."""
    wrong = [i for i, r in enumerate(rows) if r.correct is False and r.best_image]
    wrong.sort(key=lambda i: -(rows[i].confidence if np.isfinite(rows[i].confidence) else -1))
    return wrong[:count]


def draw_strip_figure(rows: list[Row], picks: list[int], ref: dict[str, Path], query: dict[str, Path], path: Path,
                      title: str) -> Path | None:
    """One row per picked query: query | best match | a true positive, the match framed
    green (right), red (wrong) or grey (no ground truth)."""
    if not picks:
        return None
    from placeloc.evaluation.plots import _save, plt

    with_gt = any(rows[i].correct is not None for i in picks)
    cols = 3 if with_gt else 2
    fig, axes = plt.subplots(len(picks), cols, figsize=(3.2 * cols, 1.9 * len(picks) + 0.5), squeeze=False)
    for row_axes, i in zip(axes, picks):
        r = rows[i]
        q_img = _read(query.get(r.query_image), (48, 96))
        shape = q_img.shape[:2]
        panels = [(q_img, f"query {r.query_image}", "black"),
                  (_read(ref.get(r.best_image) if r.best_image else None, shape),
                   f"best {r.best_image}  conf {r.confidence:.2f}" if r.best_image else "best: none (no full sequence)",
                   "grey" if r.correct is None else ("limegreen" if r.correct else "red"))]
        if with_gt:
            panels.append((_read(ref.get(r.positive_image) if r.positive_image else None, shape),
                           f"true {r.positive_image or '(no positive)'}", "royalblue"))
        for ax, (img, label, colour) in zip(row_axes, panels):
            ax.imshow(img, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_edgecolor(colour)
                spine.set_linewidth(4 if colour in ("limegreen", "red") else 1.5)
            ax.set_title(label, fontsize=7.5, color="black" if colour in ("black", "royalblue", "grey") else colour)
        if not r.best_image:
            row_axes[1].text(0.5, 0.5, "no match", transform=row_axes[1].transAxes, ha="center", va="center", fontsize=10)
        if r.correct is not None:
            verdict = "RIGHT" if r.correct else ("WRONG" if r.best_image else "MISSED")
            row_axes[1].text(0.02, 0.95, verdict, transform=row_axes[1].transAxes, fontsize=9,
                             fontweight="bold", va="top", color="white",
                             bbox={"facecolor": "green" if r.correct else "red", "alpha": 0.85, "pad": 1.5})
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def draw_strips(run_dir: str | Path, *, sample: int = 8, failures: int = 8, out_dir: str | Path | None = None) -> list[Path]:
    """Write the sample strips (and, with ground truth, the worst failures); return paths.

    ``out_dir`` (a stage's ``ctx.output_dir``): where the figures go, and where this stage's
    own per_query.csv / matches.csv are looked for first (they are staged there until the
    stage commits); default ``run_dir``."""
    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    has_rows = (out_dir / "per_query.csv").is_file() or (out_dir / "matches.csv").is_file()
    rows = read_rows(out_dir if has_rows else run_dir)
    ref, query = _folders(run_dir)
    out: list[Path] = []
    with_gt = any(r.correct is not None for r in rows)
    picks = pick_sample(len(rows), sample)
    n_right = sum(1 for r in rows if r.correct)
    what = f"{n_right} of {len(rows)} best matches right" if with_gt else "no ground truth: matches not judged"
    p = draw_strip_figure(rows, picks, ref, query, out_dir / SAMPLE_PNG,
                          f"{len(picks)} queries spread over the traverse ({what})")
    if p:
        out.append(p)
    fail = pick_failures(rows, failures)
    stale = out_dir / FAILURES_PNG
    if fail:
        p = draw_strip_figure(rows, fail, ref, query, stale, f"worst failures: the {len(fail)} most confident wrong matches")
        if p:
            out.append(p)
    elif stale.exists():
        stale.unlink()
    return out


def recall_from_per_query(run_dir: str | Path, ns: list[int]) -> dict[int, tuple[float | None, float | None]]:
    """Standard Recall@N for any N from ``per_query.csv`` (its ``first_correct_rank``):
    (over all queries, over queries with a positive); None beyond the K candidates the
    file lists."""
    path = Path(run_dir) / "per_query.csv"
    if not path.is_file():
        raise ShowError(f"{path} is missing: Recall@N needs ground truth; run `placeloc evaluate` first")
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        k = sum(1 for c in reader.fieldnames or [] if c.startswith("correct_"))
        rows = list(reader)
    first = np.array([int(r["first_correct_rank"]) for r in rows])
    has = np.array([r["has_positive"] == "1" for r in rows])
    out: dict[int, tuple[float | None, float | None]] = {}
    for n in ns:
        if n > k or not len(rows):
            out[n] = (None, None)
            continue
        hit = (first >= 1) & (first <= n)
        out[n] = (float(hit.mean()), float(hit[has].mean()) if has.any() else None)
    return out


def show_run(run_dir: str | Path, *, sample: int = 8, failures: int = 8) -> tuple[list[Path], Path]:
    """Strips and report.html for a run directory, as ``placeloc show`` does. A file that
    comes out byte-identical keeps its old modification time, so that re-showing a run
    does not make the evaluate stage that wrote the same file look out of date."""
    import os

    from placeloc.evaluation.report import REPORT, write_report

    run_dir = Path(run_dir)
    names = [SAMPLE_PNG, FAILURES_PNG, REPORT]
    before = {n: ((run_dir / n).read_bytes(), (run_dir / n).stat()) for n in names if (run_dir / n).is_file()}
    strips = draw_strips(run_dir, sample=sample, failures=failures)
    report = write_report(run_dir)
    for name, (data, st) in before.items():
        p = run_dir / name
        if p.is_file() and p.read_bytes() == data:
            os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    return strips, report
