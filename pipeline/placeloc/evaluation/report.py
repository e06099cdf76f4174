"""One self-contained ``report.html`` per run directory: config summary, metrics table and
every PNG of the run (match strips included) embedded as base64, so a person opens one
file in a browser instead of a folder of pictures."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any

import yaml

from placeloc.core.artifacts import atomic_open

REPORT = "report.html"
# Pictures first that say most; any other PNG follows in name order.
ORDER = ("strips_sample.png", "strips_failures.png", "estimates_on_plan.png", "map.png", "recall_at_n.png", "pr_curve.png",
         "error_cdf.png", "time_per_frame.png", "difference_matrix.png")
CSS = """body{font-family:system-ui,sans-serif;margin:24px;max-width:1300px;color:#222}
table{border-collapse:collapse;margin:8px 0 20px}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px;text-align:left}
th{background:#f0f0f0}td.num{text-align:right;font-variant-numeric:tabular-nums}
img{max-width:min(100%,1100px);border:1px solid #ddd;margin:6px 0 18px}h2{margin-top:28px;border-bottom:1px solid #ddd}
.cfg{display:flex;gap:32px;flex-wrap:wrap;align-items:flex-start}.muted{color:#777;font-size:12px}
.headline{display:flex;gap:14px;flex-wrap:wrap;margin:10px 0 6px}.fig{border:1px solid #ccd;border-radius:6px;padding:8px 14px;
background:#f6f8fc}.fig .v{font-size:24px;font-weight:600}.fig .k{font-size:12px;color:#555}"""


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4f}"
    if v is None:
        return "n/a"
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
                   f"{html.escape(_fmt(v))}</td></tr>" for k, v in rows)
    return f"<table><tr><th>{head[0]}</th><th>{head[1]}</th></tr>{body}</table>"


def run_config(run_dir: Path) -> dict[str, Any]:
    """The config of the newest stage artifact in ``run_dir`` (config.yaml is written only
    after a run succeeds, so during a stage it may still describe the previous run)."""
    import h5py

    def newest_first(p: Path) -> float:
        try:
            return -p.stat().st_mtime
        except OSError:
            return 0.0

    for path in sorted(Path(run_dir).glob("*.h5"), key=newest_first):
        if path.is_file():
            try:
                with h5py.File(path, "r") as f:
                    text = f.attrs.get("config_yaml")
            except OSError:
                continue
            if text:
                return yaml.safe_load(str(text)) or {}
    return {}


def _headline_html(kind: str | None, figures: list[tuple[str, Any]]) -> str:
    """The headline figures first, as large numbers, with the contract they belong to."""
    if not figures:
        what = f"result: {kind}; " if kind else ""
        return f"<h2>Headline</h2><p>{html.escape(what)}not evaluated (no ground truth, or evaluate has not run).</p>"
    cells = "".join(f"<div class='fig'><div class='v'>{html.escape(_fmt(v))}</div><div class='k'>{html.escape(k)}</div>"
                    "</div>" for k, v in figures)
    return (f"<h2>Headline</h2><p class='muted'>result contract: <b>{html.escape(kind or '?')}</b> "
            f"(docs/evaluation.md explains every figure)</p><div class='headline'>{cells}</div>")


def _metrics_doc(doc: dict[str, str] | None) -> str:
    items = "".join(f"<li><code>{html.escape(k)}</code>: {html.escape(v)}</li>" for k, v in (doc or {}).items())
    return f"<ul class='muted'>{items}</ul>" if items else ""


def write_report(run_dir: str | Path, title: str | None = None, config: dict[str, Any] | None = None,
                 out_dir: str | Path | None = None, result_kind: str | None = None,
                 headline: list[tuple[str, Any]] | None = None, metrics_doc: dict[str, str] | None = None) -> Path:
    """Write ``report.html`` from what the run directory holds now; ``config`` is the
    run's config (default: the one stamped in its newest artifact). ``out_dir`` (a stage's
    ``ctx.output_dir``, default ``run_dir``): where the report goes; the metrics.json and
    PNGs staged there by the same stage take the place of the run directory's."""
    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    cfg = config if config is not None else run_config(run_dir)
    metrics: dict[str, Any] = {}
    metrics_path = next((d / "metrics.json" for d in (out_dir, run_dir) if (d / "metrics.json").is_file()), None)
    if metrics_path is not None:
        metrics = json.loads(metrics_path.read_text())
    method = cfg.get("method", "?")
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title or run_dir.name)}</title>"
             f"<style>{CSS}</style></head><body>",
             f"<h1>{html.escape(title or f'placeloc run: {run_dir.name}')}</h1>",
             f"<p class='muted'>{html.escape(str(run_dir.resolve()))}</p>"]
    parts.append(_headline_html(result_kind, headline or []))
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
        summary.append(("ground truth", ", ".join([f"kind={gt.get('kind', 'none')}"] + [
            f"{k}={gt[k]}" for k in used.get(gt.get("kind", "none"), ()) if gt.get(k) is not None])))
    parts.append("<h2>Configuration</h2><div class='cfg'>" + _table(summary, ("setting", "value")))
    if isinstance(cfg.get(method), dict):
        # a value the method chose at run time (e.g. co-embedding's alpha from alpha_select) beside the config's
        rows = [(k, f"{_fmt(v)} in the config; {_fmt(metrics[k])} used (metrics.json)"
                 if k in metrics and not isinstance(metrics[k], (dict, list)) and metrics[k] != v else v)
                for k, v in _flatten(cfg[method])]
        parts.append(_table(rows, (f"{method} parameter", "value")))
    parts.append("</div>")
    if metrics:
        main = [(k, v) for k, v in metrics.items() if not isinstance(v, (dict, list))]
        parts.append("<h2>Metrics</h2>" + _metrics_doc(metrics_doc) + _table(main, ("metric", "value")))
    else:
        parts.append("<h2>Metrics</h2><p>No metrics.json (no ground truth, or evaluate has not run).</p>")
    found = {p.name: p for d in (run_dir, out_dir) for p in d.glob("*.png") if not p.name.startswith(".")}
    pngs = sorted(found.values(), key=lambda p: (ORDER.index(p.name) if p.name in ORDER else len(ORDER), p.name))
    parts.append("<h2>Pictures</h2>")
    for png in pngs:
        data = base64.b64encode(png.read_bytes()).decode("ascii")
        parts.append(f"<h3>{html.escape(png.name)}</h3><img alt='{html.escape(png.name)}' src='data:image/png;base64,{data}'>")
    if not pngs:
        parts.append("<p>No pictures in this run directory (plots: false?).</p>")
    parts.append("</body></html>")
    path = out_dir / REPORT
    with atomic_open(path) as fh:
        fh.write("\n".join(parts))
    return path
