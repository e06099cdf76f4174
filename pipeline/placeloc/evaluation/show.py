"""Pictures of the matches: strips of query | best match | a true positive.

Reads a run directory: ``per_query.csv`` (written by evaluate, with ground truth) or,
without ground truth, the ``ranked`` or ``loops`` result in ``localize.h5`` (query image,
best reference image, confidence), and the config stamped in the artifacts for the image
folders. :func:`show_run` is ``placeloc show`` for every result contract. Writes
``strips_sample.png`` (queries spread evenly over the traverse) and, with ground truth,
``strips_failures.png`` (the wrong matches made with the highest confidence, i.e. the
ones a threshold would let through first).
"""

from __future__ import annotations

import csv
import logging
import math
import os
import shlex
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.core.safe_io import read_run_table

log = logging.getLogger("placeloc")
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


def read_rows(run_dir: Path, only_matched: bool = False) -> list[Row]:
    """Per-query rows from per_query.csv (evaluate), else from the ``ranked`` or ``loops``
    result in localize.h5 (no ground truth: matches not judged). ``only_matched``: the
    rows with a match (loop closures: the frames that closed one)."""
    per_query = run_dir / "per_query.csv"
    rows: list[Row] = []
    if per_query.is_file():
        # five columns of a hundred: read by position (a dict per row cost more than the strips)
        reader = csv.reader(read_run_table(run_dir, "per_query.csv"))
        head = next(reader, [])
        wanted = ("query_image", "best_image", "confidence", "correct", "positive_image")
        if not set(wanted) <= set(head):
            raise ShowError(f"{per_query}: lacks the columns {', '.join(sorted(set(wanted) - set(head)))}; "
                            "re-run evaluate (placeloc evaluate --force)")
        qi, bi, ci, oi, pi = (head.index(c) for c in wanted)
        for r in reader:
            r += [""] * (len(head) - len(r))  # a short row: its missing cells empty
            if only_matched and not r[bi]:
                continue
            rows.append(Row(r[qi], r[bi], _num(r[ci]), r[oi] == "1", r[pi]))
        return rows
    from placeloc.evaluation.contracts import localize_result

    res = localize_result(run_dir)
    if res is None or res.kind not in ("ranked", "loops"):
        raise ShowError(f"{run_dir}: holds no localize result with matches (per_query.csv or localize.h5); "
                        "run `placeloc localize CONFIG -o RUN_DIR` first")
    if res.kind == "ranked":
        name_of = dict(zip(res["reference_index"].tolist(), res["reference_names"]))
        pairs = zip(res["query_names"], res["candidates"][:, 0], res["confidence"])
    else:
        name_of = dict(zip(res["frame_index"].tolist(), res["frame_names"]))
        pairs = zip(res["frame_names"], res["match"], res["confidence"])
    for qn, j, c in pairs:
        if only_matched and j < 0:
            continue
        rows.append(Row(qn, name_of.get(int(j), "") if j >= 0 else "", float(c), None, ""))
    return rows


def _num(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return float("nan")


class ImagesByName(Mapping[str, Path]):
    """A traverse's images by file name (``reference.images``: a folder or a glob). In a
    folder a name is looked up directly (one stat), not by listing the folder: the strips
    need 8 to 16 images of what may be tens of thousands. A glob is listed once."""

    def __init__(self, spec: str | Path) -> None:
        self.spec = str(spec)
        self._listed: dict[str, Path] | None = None

    def _listing(self) -> dict[str, Path]:
        from placeloc.core.images import ImageError, list_images

        if self._listed is None:
            try:
                self._listed = {p.name: p for p in list_images(self.spec).paths}
            except ImageError:
                self._listed = {}
        return self._listed

    def __getitem__(self, name: str) -> Path:
        from placeloc.core.images import IMAGE_EXTENSIONS

        folder = Path(self.spec)
        if not folder.is_dir():
            return self._listing()[name]
        # only a plain file name of an image the listing would hold (never a path out of the folder)
        if name and Path(name).name == name and name not in (".", "..") and Path(name).suffix.lower() in IMAGE_EXTENSIONS:
            path = folder / name
            if path.is_file():
                return path
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._listing())

    def __len__(self) -> int:
        return len(self._listing())


def _folders(run_dir: Path, within_reference: bool = False,
             config: Mapping[str, Any] | None = None) -> tuple[Mapping[str, Path], Mapping[str, Path]]:
    from placeloc.evaluation.report import run_config

    # the evaluate stage hands over its own config: reading the run's chain of artifacts
    # for it (four HDF5 files and their stamped YAML) took 40 ms of the demo's evaluate
    cfg = run_config(run_dir) if config is None else config
    if not cfg:
        raise ShowError(f"{run_dir}: holds no placeloc artifact; run `placeloc localize CONFIG -o {shlex.quote(str(run_dir))}` first")

    def images(role: str) -> Mapping[str, Path] | None:
        section = cfg.get(role) or {}
        return ImagesByName(section["images"]) if section.get("images") else None

    ref, query = images("reference"), images("query")  # never `or`: that would list a folder to count it
    if ref is None:
        ref = {}
    return ref, (ref if within_reference or query is None else query)


def _read(path: Path | None, shape: tuple[int, int]) -> np.ndarray:
    from placeloc.core.images import ImageError, read_rgb

    if path is None:
        return np.full((*shape, 3), 235, np.uint8)

    try:
        img = read_rgb(path)  # upright (EXIF orientation), as the stages saw it
    except ImageError:
        return np.full((*shape, 3), 200, np.uint8)
    return shrink(img)


# A strip's panel is drawn PANEL_HEIGHT_PX high: a frame is shrunk right after its decode,
# so that drawing holds about one decoded frame; more pixels than this add nothing but memory.
PANEL_PIXELS = 480


def shrink(img: np.ndarray, longest: int = PANEL_PIXELS) -> np.ndarray:
    """``img`` scaled down (area averaging) so its longer side is at most ``longest``."""
    import cv2

    h, w = img.shape[:2]
    scale = longest / max(h, w)
    if scale >= 1:
        return img
    return cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


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


# the strips' panels: this many pixels high (the width keeps the first query's aspect)
PANEL_HEIGHT_PX = 110


def zero_confidence_note(run_dir: Path, res: Any = None) -> str | None:
    """What a confidence of exactly 0 means for the run's method (the result's
    ``zero_confidence``; SeqSLAM: no rival outside the enhancement window), or None."""
    if res is None:
        from placeloc.evaluation.contracts import localize_result

        res = localize_result(Path(run_dir))
    note = res.attrs.get("zero_confidence") if res is not None else None
    return str(note) if note else None


def draw_strip_figure(rows: list[Row], picks: list[int], ref: Mapping[str, Path], query: Mapping[str, Path], path: Path,
                      title: str, zero_note: str | None = None) -> Path | None:
    """One row per picked query: query | best match | a true positive, the match framed
    green (right), red (wrong) or grey (no ground truth).

    The panels are composed into one image (each scaled to the same size), the labels
    drawn on it by Pillow (:mod:`placeloc.evaluation.raster`): one
    picture's cost whatever the number of rows, and no matplotlib, whose import and text
    layout made the strips most of evaluate's time."""
    if not picks:
        path.unlink(missing_ok=True)
        return None
    import cv2

    from placeloc.evaluation import raster as R

    with_gt = any(rows[i].correct is not None for i in picks)
    cols = 3 if with_gt else 2
    strip: list[list[tuple[np.ndarray, str, str]]] = []  # per row: (image, label, frame colour) per panel
    for i in picks:
        r = rows[i]
        q_img = _read(query.get(r.query_image), (48, 96))
        shape = q_img.shape[:2]
        best = "best: none (no full sequence)"
        if r.best_image:
            best = f"best {r.best_image}  conf {r.confidence:.3g}"
            if zero_note and r.confidence == 0:
                best += f" ({zero_note})"
        panels = [(q_img, f"query {r.query_image}", "black"),
                  (_read(ref.get(r.best_image) if r.best_image else None, shape), best,
                   "grey" if r.correct is None else ("limegreen" if r.correct else "red"))]
        if with_gt:
            panels.append((_read(ref.get(r.positive_image) if r.positive_image else None, shape),
                           f"true {r.positive_image or '(no positive)'}", "royalblue"))
        strip.append(panels)
    first = strip[0][0][0]
    ph = PANEL_HEIGHT_PX
    pw = int(np.clip(round(ph * first.shape[1] / max(1, first.shape[0])), ph * 3 // 4, ph * 4))
    label_h, gap = 26, 10
    # a cell is as wide as its widest label: under a narrow (4:3, fish-eye) image the best
    # match's "best NAME  conf X" ran on under the next panel's label
    label_w = max(R.text_width(label, 12) for panels in strip for _, label, _ in panels)
    cell_w, cell_h = max(pw, math.ceil(label_w) + 4) + gap, ph + label_h + gap
    canvas = np.full((len(picks) * cell_h, cols * cell_w, 3), 255, np.uint8)
    colours = {"black": (0, 0, 0), "grey": (128, 128, 128), "limegreen": (50, 205, 50), "red": (220, 0, 0),
               "royalblue": (65, 105, 225)}
    texts: list[tuple[float, float, str, str]] = []  # x, y (canvas pixels), text, colour
    verdicts: list[tuple[float, float, str, str]] = []
    for k, (i, panels) in enumerate(zip(picks, strip)):
        r = rows[i]
        y0 = k * cell_h + label_h
        for c, (img, label, colour) in enumerate(panels):
            x0 = c * cell_w + gap // 2
            width = 4 if colour in ("limegreen", "red") else 1
            canvas[y0 - width:y0 + ph + width, x0 - min(width, x0):x0 + pw + width] = colours[colour]
            canvas[y0:y0 + ph, x0:x0 + pw] = cv2.resize(np.ascontiguousarray(img[..., :3]), (pw, ph),
                                                        interpolation=cv2.INTER_AREA)
            texts.append((x0, y0 - 6, label, "black" if colour in ("black", "royalblue", "grey") else colour))
        if not r.best_image:
            texts.append((cell_w + gap // 2 + pw / 2, y0 + ph / 2, "no match", "black"))
        if r.correct is not None:
            verdicts.append((cell_w + gap // 2 + 6, y0 + 6, "RIGHT" if r.correct else ("WRONG" if r.best_image else "MISSED"),
                             "green" if r.correct else "red"))
    h, w = canvas.shape[:2]
    title_h = 50
    page = R.Canvas(w, h + title_h, ss=1)  # images, axis-parallel frames and text: nothing to smooth
    page.paste(canvas, 0, title_h)
    rgb = {name: colours[name] for name in ("black", "grey", "royalblue")} | {"limegreen": (0, 160, 0), "red": (220, 0, 0),
                                                                             "green": (0, 128, 0)}
    for x, y, text, colour in texts:
        centred = text == "no match"
        page.text(x, title_h + y, text, 12, fill=rgb[colour], anchor="mm" if centred else "ld")
    for x, y, text, colour in verdicts:
        page.text(x + 2, title_h + y + 2, text, 13, fill=(255, 255, 255), anchor="la", box=rgb[colour], pad=2)
    page.text(w / 2, title_h / 2, title, 15, anchor="mm")
    return page.save(path, photo=True)


def draw_strips(run_dir: str | Path, *, sample: int = 8, failures: int = 8, rows: list[Row] | None = None,
                what: str = "best matches", out_dir: str | Path | None = None,
                config: Mapping[str, Any] | None = None, zero_note: str | None = None) -> list[Path]:
    """Write the sample strips (and, with ground truth, the worst failures); return paths.

    ``out_dir`` (a stage's ``ctx.output_dir``): where the figures go, and where this stage's
    own per_query.csv is looked for first (staged there until the stage commits); default
    ``run_dir``. ``config``: the run's config (its ``reference`` and ``query`` images), when
    the caller has it; else the config stamped in the run's artifacts."""
    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    if rows is None:
        rows = read_rows(out_dir if (out_dir / "per_query.csv").is_file() else run_dir)
    ref, query = _folders(run_dir, within_reference=what == "loop closures", config=config)
    out: list[Path] = []
    with_gt = any(r.correct is not None for r in rows)
    picks = pick_sample(len(rows), sample)
    n_right = sum(1 for r in rows if r.correct)
    verdict = f"{n_right} of {len(rows)} {what} right" if with_gt else f"no ground truth: {what} not judged"
    p = draw_strip_figure(rows, picks, ref, query, out_dir / SAMPLE_PNG,
                          f"{len(picks)} {what} spread over the traverse ({verdict})", zero_note)
    if p:
        out.append(p)
    fail = pick_failures(rows, failures)
    stale = out_dir / FAILURES_PNG
    if fail:
        p = draw_strip_figure(rows, fail, ref, query, stale, f"worst failures: the {len(fail)} most confident wrong {what}",
                              zero_note)
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
    reader = csv.DictReader(read_run_table(run_dir, "per_query.csv"))
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


SHOW_DIR = "show"
# --sample and --failures where not given: strips of this many queries each
DEFAULT_COUNT = 8


def show_run(run_dir: str | Path, *, sample: int | None = None, failures: int | None = None) -> tuple[list[Path], Path]:
    """The contract's pictures (strips, plan, map) and report.html for a run directory, as
    ``placeloc show`` does. ``sample``, ``failures``: how many strips (None:
    :data:`DEFAULT_COUNT`), and the method's own pictures (its ``show_extra``; None:
    not given, the method's own choice).

    ``show`` is read-only for the pipeline: it never changes a file a stage recorded as its
    side output (a stage whose recorded file changed re-runs). Everything is drawn into a
    temporary folder first; then each file goes to the run folder when no stage records
    that name (or the recorded file is already gone or changed), is dropped when it is
    byte-identical to the recorded one, and otherwise goes to ``RUN/show/``. Only the stages
    of the run's chain of stamps count (:func:`placeloc.evaluation.report.stamped_configs`)."""
    import shutil

    from placeloc.core.artifacts import TMP_MARK
    from placeloc.core.safe_io import load_json, read_run_file
    from placeloc.evaluation.contracts import contract, localize_result, report_parts
    from placeloc.evaluation.report import MAX_METRICS_BYTES, REPORT, evaluate_is_current, run_config, write_report

    run_dir = Path(run_dir)
    res = localize_result(run_dir)
    if res is None:
        runs = sorted(p.parent.name for p in run_dir.glob("*/localize.h5"))
        if runs:  # a sweep's or a comparison's folder: one run per subfolder
            table = next((n for n in ("sweep.md", "table.md") if (run_dir / n).is_file()), None)
            raise ShowError(f"{run_dir}: holds {len(runs)} runs, one per folder{f' (their table: {run_dir / table})' if table else ''}; "
                            f"show one of them, e.g. placeloc show {shlex.quote(str(run_dir / runs[0]))}")
        raise ShowError(f"{run_dir}: holds no localize result; run `placeloc localize CONFIG -o {shlex.quote(str(run_dir))}` first")
    mod = contract(res.kind)
    staging = run_dir / f".show{TMP_MARK}{os.getpid()}"
    if staging.is_symlink():  # a predictable name: whatever was planted there goes
        staging.unlink()
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(mode=0o700)
    try:
        # the run's config, read once (its chain of artifacts and their stamped YAML) for the
        # contract's pictures, the method's and the report
        cfg = run_config(run_dir)
        drawn = mod.show(run_dir, res, sample=DEFAULT_COUNT if sample is None else sample,
                         failures=DEFAULT_COUNT if failures is None else failures, out_dir=staging, config=cfg)
        metrics = None
        if (run_dir / "metrics.json").is_file() and not evaluate_is_current(run_dir):
            log.warning("%s: evaluate.h5 is from an earlier run (a stage before it re-ran since): its metrics are left "
                        "out of the report; run `placeloc evaluate` to judge the new result", run_dir)
        elif (run_dir / "metrics.json").is_file():
            metrics = load_json(read_run_file(run_dir, "metrics.json", MAX_METRICS_BYTES).decode("utf-8", "replace"),
                                str(run_dir / "metrics.json"))
            if not isinstance(metrics, dict):
                raise ShowError(f"{run_dir / 'metrics.json'}: not a JSON object of metrics; re-run evaluate (--force)")
        # the method's own pictures of its answers, where it has some: not evaluated, all it draws; evaluated,
        # those --sample and --failures ask for (evaluate drew its own choice)
        method = _method(cfg)
        options = {"evaluated": metrics is not None, "sample": sample, "failures": failures}
        if (sample is not None or failures is not None) and not mod.CHOOSES_QUERIES and not (method and method.show_extra):
            # said, not silently ignored: a user who asked for the worst 3 should know none were chosen
            log.warning("%s: a %s result is drawn whole (%s); --sample and --failures choose the queries other "
                        "results draw strips of, and choose nothing here", run_dir, res.kind,
                        ", ".join(p.name for p in drawn) or "no picture")
        if method is not None and method.show_extra:
            drawn += list(method.show_extra(run_dir, res, staging, config=cfg, **options))
        chosen = method.report_pictures(run_dir, **options) if method is not None and method.report_pictures else None
        write_report(run_dir, config=cfg, out_dir=staging, method_pictures=chosen, **report_parts(res.kind, metrics))
        placed = _place(run_dir, staging, recorded_side_outputs(run_dir))
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    pictures = [placed[p.name] for p in drawn if p.name in placed]
    return pictures, placed[REPORT]


def _method(config: Mapping[str, Any]) -> Any:
    """The method (:class:`placeloc.core.methods.Method`) the run's ``config`` names, for its
    ``show_extra`` and ``report_pictures`` hooks; None where it names none this placeloc knows
    (the contract's pictures only)."""
    from placeloc.core.methods import get_method

    name = config.get("method")
    try:
        return get_method(name) if isinstance(name, str) else None
    except KeyError:
        return None


def recorded_side_outputs(run_dir: Path) -> dict[str, str]:
    """name -> fingerprint of every side output recorded by the artifacts of the run's
    chain of stamps (an artifact left from an older run re-runs anyway: its files are not
    kept from show)."""
    from placeloc.core.safe_io import load_json
    from placeloc.evaluation.report import artifact_attrs, stamped_configs

    out: dict[str, str] = {}
    for stage, _, _ in stamped_configs(run_dir):
        attrs = artifact_attrs(run_dir, f"{stage}.h5", ("side_outputs",)) or {}
        try:
            out.update(load_json(str(attrs.get("side_outputs") or "{}"), f"{stage}.h5 side outputs"))
        except (ValueError, TypeError):
            continue
    return out


def _fingerprint(path: Path) -> str:
    """As the runner fingerprints a side output: size and modification time."""
    st = path.stat()
    return f"{st.st_size}:{st.st_mtime_ns}"


def _place(run_dir: Path, staging: Path, recorded: dict[str, str]) -> dict[str, Path]:
    """Move what show drew out of ``staging`` (see :func:`show_run`); name -> final path."""
    placed: dict[str, Path] = {}
    for new in sorted(staging.iterdir()):
        target = run_dir / new.name
        intact = (new.name in recorded and target.is_file() and not target.is_symlink()
                  and _fingerprint(target) == recorded[new.name])
        if intact and target.read_bytes() == new.read_bytes():
            placed[new.name] = target  # what the stage wrote already: leave it (and its time) alone
            continue
        if intact:
            from placeloc.core.safe_io import name_inside

            target = name_inside(run_dir, SHOW_DIR, "show's folder") / new.name  # a link out of the run is refused
            target.parent.mkdir(exist_ok=True)
        os.replace(new, target)  # a link at the target is replaced, never written through
        placed[new.name] = target
    return placed
