"""One self-contained ``report.html`` per run directory: config summary, metrics table and
every PNG of the run (match strips included) embedded as base64, so a person opens one
file in a browser instead of a folder of pictures."""

from __future__ import annotations

import base64
import copy
import functools
import html
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from placeloc.core.artifacts import atomic_open, stamp_token
from placeloc.core.safe_io import MAX_RUN_TABLE_BYTES, load_json, open_run_file, read_run_file

log = logging.getLogger("placeloc")

REPORT = "report.html"
# placeloc's own pictures are a few MB; a larger PNG in the run folder is not embedded.
MAX_PICTURE_BYTES = 32 << 20
MAX_METRICS_BYTES = 16 << 20
# Pictures first that say most; any other PNG follows in name order.
ORDER = ("strips_sample.png", "strips_failures.png", "estimates_on_plan.png", "map.png", "recall_at_n.png", "pr_curve.png",
         "error_cdf.png", "confidence.png", "time_per_frame.png", "difference_matrix.png")
# the answers a localize stage writes beside its result (UMap's poses; the ranked contract's matches): a run not
# evaluated (no ground truth: a photo located in one's own home) shows the first of them under its headline
ANSWERS = {"estimates.csv": "docs/umap.md", "matches.csv": "docs/evaluation.md"}   # and where their columns are told
ANSWER_ROWS = 20
# what the terminal shows of each answer (the first column names it)
ANSWER_COLUMNS = {"estimates.csv": ("frame", "x", "y", "heading_deg", "height_m", "ceiling_m", "tilt_deg", "room", "doubtful",
                                    "rival_room"),
                  "matches.csv": ("query_image", "reference_image", "confidence")}
CSS = """body{font-family:system-ui,sans-serif;margin:24px;max-width:1300px;color:#222}
table{border-collapse:collapse;margin:8px 0 20px}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px;text-align:left}
th{background:#f0f0f0}td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:min(100%,1100px);border:1px solid #ddd;margin:6px 0 18px}h2{margin-top:28px;border-bottom:1px solid #ddd}
.cfg{display:flex;gap:32px;flex-wrap:wrap;align-items:flex-start}.muted{color:#777;font-size:12px}
details{margin:8px 0 20px}summary{cursor:pointer;color:#336;font-size:13px}
.why{font-size:14px;font-weight:normal;color:#555;margin-left:10px}
.headline{display:flex;gap:14px;flex-wrap:wrap;margin:10px 0 6px}.fig{border:1px solid #ccd;border-radius:6px;padding:8px 14px;
background:#f6f8fc}.fig .v{font-size:24px;font-weight:600}.fig .k{font-size:12px;color:#555}"""


@dataclass(frozen=True)
class MethodPictures:
    """A method's own pictures as report.html shows them (UMap's ``panorama_<photo>.png``):
    ``chosen``, (file name, caption) in the order the method chose them, the one to look at
    first first (file-name order put the one wrong answer of 32 photos eighth of twelve);
    ``family``, the prefix their names share: a PNG of the family not chosen is left out (one
    left from an earlier run, or from ``placeloc show`` with other options); ``note``, a line
    above them that says how they were chosen."""

    family: str
    chosen: list[tuple[str, str]] = field(default_factory=list)
    note: str = ""


def format_value(v: Any) -> str:
    """A figure or setting as the report and the command line show it: four decimals, or
    three significant digits for a number too small for them (an AKAZE threshold of 3e-05
    shown as 0.0000 read as zero); a list's numbers to six significant digits (a grid's
    computed bounds showed as 4.859999999999999)."""
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.3g}" if v != 0.0 and abs(v) < 5e-4 else f"{v:.4f}"
    if isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return "[" + ", ".join(f"{x:.6g}" if isinstance(x, float) else str(x) for x in v) + "]"
    return str(v)


def _flatten(d: dict, prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for k, v in d.items():
        if isinstance(v, dict):
            out += _flatten(v, f"{prefix}{k}.")
        else:
            out.append((f"{prefix}{k}", v))
    return out


def _table(rows: list[tuple[str, Any]], head: tuple[str, str]) -> str:
    body = "".join(f"<tr><td>{html.escape(k)}</td><td class='{'num' if isinstance(v, (int, float)) else ''}'>"
                   f"{html.escape(format_value(v))}</td></tr>" for k, v in rows)
    return f"<table><tr><th>{head[0]}</th><th>{head[1]}</th></tr>{body}</table>"


def stamped_configs(run_dir: Path) -> list[tuple[str, str, dict[str, Any]]]:
    """(stage, its token, config) of the artifacts that form one chain of stamps: the first
    stage's artifact, then each next stage's as long as it records the tokens of its
    parents as they are in the chain (``parent``: the one before it; ``parents``: the stages
    it names, :attr:`placeloc.core.methods.Stage.parents`). An artifact left from an earlier
    run (a parent re-run since) ends the chain, however recent its modification time.
    Artifacts are read through the run-folder guard (no symbolic links, regular files
    only)."""
    from placeloc.core.stage_names import STAGES

    chain: list[tuple[str, str, dict[str, Any]]] = []
    tokens: dict[str, str] = {}   # each stage of the chain -> its token
    for stage in STAGES:
        attrs = _artifact_attrs(run_dir, f"{stage}.h5")
        if attrs is None:
            break
        stamp = str(attrs.get("stamp") or "")
        try:
            inputs = load_json(str(attrs.get("inputs") or "{}"), f"{stage}.h5 inputs")
            parents = inputs.get("parents") if "parents" in inputs else \
                ({chain[-1][0]: inputs.get("parent")} if chain else {})
            current = isinstance(parents, dict) and all(tokens.get(p) == t for p, t in parents.items())
        except (ValueError, AttributeError):  # not JSON, too deep, not a mapping
            break
        if not stamp or not current:
            break
        cfg = _parse_config(attrs.get("config_yaml"))
        if cfg is None:
            break
        # what a child records of its parent (as the runner records it)
        tokens[stage] = stamp_token(stamp, attrs.get("write_id"))
        chain.append((stage, tokens[stage], cfg))
    return chain


def _artifact_attrs(run_dir: Path, name: str) -> dict[str, Any] | None:
    return artifact_attrs(run_dir, name, ("stamp", "write_id", "inputs", "config_yaml"))


def artifact_attrs(run_dir: Path, name: str, keys: tuple[str, ...]) -> dict[str, Any] | None:
    """Root attributes ``keys`` of a run folder's artifact (None when absent, a link, not a
    regular file or not HDF5)."""
    import h5py

    from placeloc.core.safe_io import UnsafeInputError, open_run_file

    try:
        fd = open_run_file(run_dir, name, os.O_RDONLY)
    except (OSError, UnsafeInputError):
        return None
    try:
        with os.fdopen(fd, "rb") as fh, h5py.File(fh, "r") as f:
            return {k: f.attrs[k] for k in keys if k in f.attrs}
    except (OSError, ValueError):
        return None


def _parse_config(text: Any) -> dict[str, Any] | None:
    if not text:
        return None
    cfg = _parsed_config(str(text))
    return copy.deepcopy(cfg) if cfg is not None else None


@functools.lru_cache(maxsize=32)
def _parsed_config(text: str) -> dict[str, Any] | None:
    """The stamped config's YAML parsed once per process: a run's artifacts usually carry the
    same text, and the guarded parse (:func:`placeloc.core.safe_io.load_yaml`) took 13 ms each,
    a fifth of the demo's evaluate (its chain of four artifacts is read to find the images)."""
    from placeloc.core.safe_io import load_yaml

    try:
        cfg = load_yaml(text, "a stamped config")
    except yaml.YAMLError:
        return None
    return cfg if isinstance(cfg, dict) else None


def evaluate_is_current(run_dir: Path) -> bool:
    """True when evaluate.h5 belongs to the run folder's chain of stamps."""
    return any(stage == "evaluate" for stage, _, _ in stamped_configs(Path(run_dir)))


def run_config(run_dir: Path) -> dict[str, Any]:
    """The config of the last artifact of the run folder's chain of stamps
    (:func:`stamped_configs`); config.yaml is written only after a run succeeds, and a
    file's modification time says nothing about which run wrote it."""
    chain = stamped_configs(Path(run_dir))
    return chain[-1][2] if chain else {}


def _picture_bytes(png: Path) -> bytes | None:
    """A PNG of the run folder to embed: a regular file (a symbolic link, a FIFO or a device
    named *.png is skipped with a warning, never followed: the report must not carry bytes
    from outside the run), PNG-signed, at most MAX_PICTURE_BYTES."""
    from placeloc.core.safe_io import UnsafeInputError

    try:
        raw = read_run_file(png.parent, png.name, MAX_PICTURE_BYTES)
    except (OSError, UnsafeInputError) as exc:
        log.warning("report: %s not embedded (%s)", png, " ".join(str(exc).split()))
        return None
    if not raw.startswith(b"\x89PNG\r\n\x1a\n"):
        log.warning("report: %s not embedded (not a PNG file)", png)
        return None
    return raw


def _headline_html(kind: str | None, figures: list[tuple[str, Any]]) -> str:
    """The headline figures first, as large numbers, with the contract they belong to."""
    if not figures:
        what = f"result: {kind}; " if kind else ""
        return f"<h2>Headline</h2><p>{html.escape(what)}not evaluated (no ground truth, or evaluate has not run).</p>"
    cells = "".join(f"<div class='fig'><div class='v'>{html.escape(format_value(v))}</div><div class='k'>{html.escape(k)}</div>"
                    "</div>" for k, v in figures)
    return (f"<h2>Headline</h2><p class='muted'>result contract: <b>{html.escape(kind or '?')}</b> "
            f"(docs/evaluation.md explains every figure)</p><div class='headline'>{cells}</div>")


def answer_rows(run_dir: Path, most: int = ANSWER_ROWS) -> tuple[str, list[str], list[list[str]], bool] | None:
    """The head of the run's answers file (:data:`ANSWERS`, the first there): its name, its
    header, its first ``most`` rows and whether there are more; None where there is none.
    Only the file's first 256 kB are read: a file of 35,768 matches is a few MB."""
    import csv
    import io

    for name in ANSWERS:
        if not (run_dir / name).is_file():
            continue
        fd = open_run_file(run_dir, name, os.O_RDONLY, max_bytes=MAX_RUN_TABLE_BYTES)
        with os.fdopen(fd, "rb") as fh:
            head = fh.read(1 << 18)
        rows: list[list[str]] = []
        for row in csv.reader(io.StringIO(head.decode("utf-8", "replace"), newline="")):
            rows.append(row)
            if len(rows) > most + 1:   # one more than kept: whether there are more
                break
        if len(rows) >= 2:
            return name, rows[0], rows[1:most + 1], len(rows) > most + 1
    return None


def answer_lines(run_dir: Path, most: int = 5) -> list[str]:
    """The first ``most`` answers of a run, one line each, for the terminal: the columns of
    :data:`ANSWER_COLUMNS` that the row fills (a ``rival_*`` column only where the answer is
    doubtful). Rows without an answer (a query a sequence search leaves unmatched) are
    counted, not shown; only the file's first 200 rows are looked at."""
    found = answer_rows(run_dir, 200)
    if found is None:
        return []
    name, header, rows, more = found
    cols = [header.index(c) for c in ANSWER_COLUMNS.get(name, tuple(header)) if c in header]
    doubtful = header.index("doubtful") if "doubtful" in header else -1
    out, unanswered, shown = [], 0, 0
    for row in rows:
        cells = [(header[i], row[i]) for i in cols if i < len(row) and row[i] != ""
                 and not (header[i].startswith("rival_") and (doubtful < 0 or row[doubtful] != "true"))]
        if len(cells) < 2:
            unanswered += 1
            continue
        if shown == most:
            more = True
            break
        out.append(f"{cells[0][1]}: " + ", ".join(f"{k} {v}" for k, v in cells[1:]))
        shown += 1
    if unanswered:
        out.append(f"({unanswered} {'query' if unanswered == 1 else 'queries'} up to here without an answer)"
                   if out else f"(none of the first {unanswered} queries has an answer)")
    if more:
        out.append(f"... more in {run_dir / name}")
    return out


def _answers_html(run_dir: Path) -> str:
    """:func:`answer_rows` as a table, or "" where there is none."""
    found = answer_rows(run_dir)
    if found is None:
        return ""
    name, header, rows, more = found
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    what = f"the first {ANSWER_ROWS}" if more else "every answer"
    return (f"<h2>Answers</h2><p class='muted'>{what}, from <code>{html.escape(name)}</code> (its columns: "
            f"{ANSWERS[name]})</p><table><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in header)
            + f"</tr>{body}</table>")


def _metrics_doc(doc: dict[str, str] | None) -> str:
    items = "".join(f"<li><code>{html.escape(k)}</code>: {html.escape(v)}</li>" for k, v in (doc or {}).items())
    return f"<ul class='muted'>{items}</ul>" if items else ""


def write_report(run_dir: str | Path, title: str | None = None, config: dict[str, Any] | None = None,
                 out_dir: str | Path | None = None, result_kind: str | None = None,
                 headline: list[tuple[str, Any]] | None = None, metrics_doc: dict[str, str] | None = None,
                 method_pictures: MethodPictures | None = None) -> Path:
    """Write ``report.html`` from what the run directory holds now; ``config`` is the
    run's config (default: the one stamped in its newest artifact). ``out_dir`` (a stage's
    ``ctx.output_dir``, default ``run_dir``): where the report goes; the metrics.json and
    PNGs staged there by the same stage take the place of the run directory's.
    ``method_pictures``: the method's own pictures, in its order and with its captions, right
    after the :data:`ORDER` figures (None: every PNG past those in name order)."""
    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    cfg = config if config is not None else run_config(run_dir)
    metrics: dict[str, Any] = {}
    # the run folder's metrics.json counts only while evaluate is in the chain of stamps: left
    # from an earlier run (its parent re-run since), it describes other settings
    metrics_dir = out_dir if (out_dir / "metrics.json").is_file() else (
        run_dir if (run_dir / "metrics.json").is_file() and evaluate_is_current(run_dir) else None)
    if metrics_dir is not None:
        metrics = load_json(read_run_file(metrics_dir, "metrics.json", MAX_METRICS_BYTES).decode("utf-8", "replace"),
                            str(metrics_dir / "metrics.json"))
        if not isinstance(metrics, dict):
            raise ValueError(f"{metrics_dir / 'metrics.json'}: not a JSON object of metrics; re-run evaluate (--force)")
    method = cfg.get("method", "?")
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title or run_dir.name)}</title>"
             f"<style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title or f'placeloc run: {run_dir.name}')}</h1>",
             f"<p class='muted'>{html.escape(str(run_dir.resolve()))}</p>"]
    parts.append(_headline_html(result_kind, headline or []))
    if not metrics:   # not evaluated: what the method answered is the result
        parts.append(_answers_html(run_dir))
    summary = [("method", method)]
    for role in ("reference", "query"):
        if cfg.get(role):
            summary.append((f"{role} images", cfg[role].get("images")))
    gt = cfg.get("ground_truth") or {}
    # only the ground-truth settings its kind reads
    used = {"synchronous": ("tolerance",), "csv": ("path", "tolerance"), "hdf5": ("path",), "poses": ("path", "radius"),
            "matrix": ("path", "tolerance", "exclude_recent")}
    # a method that reads its truth from its own section (co-embedding's coembed.truth) says so in metrics.json
    own_truth = metrics.get("scored_against")
    if gt.get("kind", "none") == "none" and isinstance(own_truth, str) and own_truth:
        summary.append(("ground truth", own_truth))
    else:
        keys = used.get(gt.get("kind", "none"), ())
        if result_kind == "poses":   # pose estimates are scored within 1 m and 30 deg: the radius is not read
            keys = tuple(k for k in keys if k != "radius")
        elif result_kind == "loops" and "exclude_recent" not in keys:
            keys = (*keys, "exclude_recent")
        summary.append(("ground truth", ", ".join([f"kind={gt.get('kind', 'none')}"] + [
            f"{k}={gt[k]}" for k in keys if gt.get(k) is not None])))
    params = ""
    if isinstance(cfg.get(method), dict):
        # a value the method chose at run time (co-embedding's alpha by alpha_select) beside the config's,
        # in the short table too: it is a result as much as a setting
        section = cfg[method]
        chosen = {k for k in section if section.get(f"{k}_select") not in (None, "none", "fixed", False)}
        values = _flatten(section)
        picked = {k for k, v in values if k in chosen and k in metrics and not isinstance(metrics[k], (dict, list))
                  and metrics[k] != v}
        rows = [(k, f"{format_value(v)} in the config; {format_value(metrics[k])} chosen by {k}_select (metrics.json)"
                 if k in picked else v) for k, v in values]
        summary += [(f"{method}.{k}", v) for k, v in rows if k in picked]
        # every parameter, folded: a method has tens of them, and the pictures should not wait below them
        params = (f"<details><summary>all {len(rows)} {html.escape(method)} parameters</summary>"
                  + _table(rows, (f"{method} parameter", "value")) + "</details>")
    parts.append("<h2>Configuration</h2><div class='cfg'>" + _table(summary, ("setting", "value")) + params + "</div>")
    found = {p.name: p for d in (run_dir, out_dir) for p in d.glob("*.png") if not p.name.startswith(".")}
    chosen = dict(method_pictures.chosen) if method_pictures is not None else {}
    rank = {name: k for k, name in enumerate(chosen)}
    if method_pictures is not None:
        found = {n: p for n, p in found.items() if n in chosen or not n.startswith(method_pictures.family)}

    def place(p: Path) -> tuple[int, int, str]:
        if p.name in ORDER:
            return 0, ORDER.index(p.name), ""
        return (1, rank[p.name], "") if p.name in rank else (2, 0, p.name)

    pngs = sorted(found.values(), key=place)
    parts.append("<h2>Pictures</h2>")
    embedded, noted = 0, False
    for png in pngs:
        raw = _picture_bytes(png)
        if raw is None:
            continue
        if png.name in chosen and not noted and method_pictures is not None and method_pictures.note:
            parts.append(f"<p class='muted'>{html.escape(method_pictures.note)}</p>")
            noted = True
        embedded += 1
        data = base64.b64encode(raw).decode("ascii")
        why = f"<span class='why'>{html.escape(chosen[png.name])}</span>" if chosen.get(png.name) else ""
        parts.append(f"<h3>{html.escape(png.name)}{why}</h3><img alt='{html.escape(png.name)}' "
                     f"src='data:image/png;base64,{data}'>")
    if not embedded:
        parts.append("<p>No pictures in this run directory (plots: false?).</p>")
    # every figure of metrics.json after the pictures: the headline above holds the few to look at first
    if metrics:
        main = [(k, v) for k, v in metrics.items() if not isinstance(v, (dict, list))]
        parts.append("<h2>Metrics</h2>" + _metrics_doc(metrics_doc) + _table(main, ("metric", "value")))
    else:
        parts.append("<h2>Metrics</h2><p>No metrics.json (no ground truth, or evaluate has not run).</p>")
    parts.append("</body></html>")
    path = out_dir / REPORT
    with atomic_open(path) as fh:
        fh.write("\n".join(parts))
    return path
