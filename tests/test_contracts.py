"""Every result contract end to end: a run of each of the five methods, then `placeloc show`
and report.html on it. Real assertions: the contract's files exist, the headline figures the
report and `placeloc run` print equal metrics.json, the strips draw the images the per-query
CSV names, and (where Chromium is installed) report.html renders in a headless browser."""

from __future__ import annotations

import csv
import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from placeloc.core.config import load_config
from placeloc.core.runner import run_all
from placeloc.evaluation import show as show_mod
from placeloc.evaluation.contracts import ContractError, contract, headline, read_result, validate
from placeloc.evaluation.report import format_value

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------ one run per method
def _seqslam(tmp: Path) -> Path:
    run_all(load_config(ROOT / "configs" / "demo.yaml"), tmp / "seqslam", quiet=True)
    return tmp / "seqslam"


def _retrieval(tmp: Path) -> Path:
    run_all(load_config(ROOT / "configs" / "retrieval.yaml"), tmp / "retrieval", quiet=True)
    return tmp / "retrieval"


def _pirf(tmp: Path) -> Path:
    from placeloc.synth.omni import generate

    data = tmp / "omni"
    generate(data, seed=0, frames=80, test_frames=40, width=240, layout="small", step=0.3)
    cfg = load_config(data={"method": "pirf", "reference": {"images": str(data / "mapping")},
                            "query": {"images": str(data / "test")},
                            "ground_truth": {"kind": "poses", "path": str(data / "mapping" / "poses.csv"), "radius": 1.0},
                            "pirf": {"eps": 10, "tau": 0.003, "n_pmin": 20, "query_poses": str(data / "test" / "poses.csv")}})
    run_all(cfg, tmp / "pirf", quiet=True)
    return tmp / "pirf"


def _umap(tmp: Path) -> Path:
    from test_umap_method import _config, _tiny_corridor

    (tmp / "corridor").mkdir()
    _tiny_corridor(tmp / "corridor")
    run_all(_config(tmp / "corridor"), tmp / "umap", quiet=True)
    return tmp / "umap"


def _coembed(tmp: Path) -> Path:
    from placeloc.synth import generate

    generate("coembed", tmp / "abcd", seed=0, steps=400)
    d = tmp / "abcd"
    cfg = load_config(data={"method": "coembed", "coembed": {
        "source": "csv", "observations": str(d / "obs_bearing.csv"), "landmarks": str(d / "landmarks.csv"),
        "truth": str(d / "features.csv"), "poses": str(d / "poses.csv"), "pose_label_every": 50, "dim": 2}})
    run_all(cfg, tmp / "coembed", quiet=True)
    return tmp / "coembed"


MAKERS = {"seqslam": _seqslam, "retrieval": _retrieval, "pirf": _pirf, "umap": _umap, "coembed": _coembed}
KIND = {"seqslam": "ranked", "retrieval": "ranked", "pirf": "loops", "umap": "poses", "coembed": "map"}
PICTURES = {"ranked": ("strips_sample.png", "pr_curve.png", "recall_at_n.png"),
            "loops": ("strips_sample.png", "pr_curve.png", "time_per_frame.png"),
            "poses": ("estimates_on_plan.png", "error_cdf.png"), "map": ("map.png",)}


@pytest.fixture(scope="module", params=list(MAKERS))
def run(request, tmp_path_factory) -> tuple[str, Path]:
    return request.param, MAKERS[request.param](tmp_path_factory.mktemp(request.param))


def _headline_cells(report: str) -> dict[str, str]:
    return {html.unescape(k): html.unescape(v) for v, k in
            re.findall(r"<div class='fig'><div class='v'>([^<]*)</div><div class='k'>([^<]*)</div>", report)}


def test_show_and_report_for_every_contract(run):
    from placeloc.cli import app

    name, run_dir = run
    res = read_result(run_dir / "localize.h5")
    assert res.kind == KIND[name]
    m = json.loads((run_dir / "metrics.json").read_text())
    figures = headline(run_dir)
    assert figures and [k for k, _ in figures] == [k for k in m["headline"] if k in m]
    # `placeloc show` redraws the contract's main picture and the report
    (run_dir / PICTURES[res.kind][0]).unlink()
    (run_dir / "report.html").unlink()
    out = CliRunner().invoke(app, ["show", str(run_dir), "--quiet"])
    assert out.exit_code == 0, out.output
    for p in PICTURES[res.kind]:
        assert (run_dir / p).stat().st_size > 5000, p
    report = (run_dir / "report.html").read_text()
    # the report opens with the headline figures (equal to metrics.json), then the short config, then the
    # pictures; the method's many parameters are folded, and the full metrics table comes last
    assert (report.index("<h2>Headline</h2>") < report.index("<h2>Configuration</h2>") < report.index("<h2>Pictures</h2>")
            < report.index("<h2>Metrics</h2>"))
    assert report.index("<details><summary>all ") < report.index(f"<th>{name} parameter</th>") < report.index("</details>")
    cells = _headline_cells(report)
    assert list(cells) == [k for k, _ in figures]
    for k, v in figures:
        assert cells[k] == format_value(v)   # tests/test_reports.py holds the formatter to hand-written strings
    assert f"method</td><td class=''>{name}" in report
    for p in PICTURES[res.kind]:
        assert f"alt='{p}'" in report


def test_strips_draw_the_images_the_per_query_csv_names(run, monkeypatch):
    name, run_dir = run
    kind = KIND[name]
    if kind not in ("ranked", "loops"):
        pytest.skip("strips belong to the ranked and loops contracts")
    drawn: list[str] = []
    real = show_mod._read
    monkeypatch.setattr(show_mod, "_read", lambda path, shape: (drawn.append(Path(path).name if path else ""), real(path, shape))[1])
    contract(kind).show(run_dir, read_result(run_dir / "localize.h5"), sample=4, failures=0)
    # loops: only the loop closures the method accepted (what n_accepted counts), never those below its threshold
    rows = [r for r in csv.DictReader((run_dir / "per_query.csv").open()) if kind == "ranked" or r["accepted"] == "1"]
    picks = show_mod.pick_sample(len(rows), 4)
    want = [x for i in picks for x in (rows[i]["query_image"], rows[i]["best_image"], rows[i]["positive_image"])]
    assert drawn == want
    if kind == "loops":  # a loop closure is drawn from the one traverse: the frame is a reference image
        cfg = load_config_from_run(run_dir)
        assert all((Path(cfg["reference"]["images"]) / n).is_file() for n in drawn if n)


def load_config_from_run(run_dir: Path) -> dict:
    from placeloc.evaluation.report import run_config

    return run_config(run_dir)


def test_run_prints_the_headline_figures(tmp_path):
    import sys

    proc = subprocess.run([sys.executable, str(ROOT / "cli.py"), "run",
                           str(ROOT / "configs" / "retrieval.yaml"), "-o", str(tmp_path / "r"), "--quiet"],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    for k in m["headline"]:
        assert f"  {k}: {format_value(m[k])}" in proc.stdout
    assert f"report: {tmp_path / 'r' / 'report.html'}" in proc.stdout


def test_contract_validation_names_the_dataset():
    ok = {"names": ["a", "b"], "x": np.zeros(2), "y": np.zeros(2), "heading_deg": np.zeros(2), "score": np.zeros(2)}
    validate("poses", ok)
    with pytest.raises(ContractError, match="'y' has Q = 3, another dataset 2"):
        validate("poses", {**ok, "y": np.zeros(3)})
    with pytest.raises(ContractError, match="'score' is missing"):
        validate("poses", {k: v for k, v in ok.items() if k != "score"})
    with pytest.raises(ContractError, match="'x' holds int64"):
        validate("poses", {**ok, "x": np.zeros(2, np.int64)})


def test_report_renders_in_headless_chromium(run, tmp_path):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (apt-get install chromium)")
    name, run_dir = run
    shot = tmp_path / "shot.png"
    dom = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                          "--dump-dom", (run_dir / "report.html").as_uri()], capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0 and "<h2>Headline</h2>" in dom.stdout
    # every picture decoded: the browser keeps the data URIs in the DOM it built
    assert dom.stdout.count("data:image/png;base64,") == (run_dir / "report.html").read_text().count("data:image/png;base64,")
    subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                    "--hide-scrollbars", "--window-size=1300,1600", f"--screenshot={shot}", (run_dir / "report.html").as_uri()],
                   capture_output=True, text=True, timeout=120)
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[:2] == (1600, 1300)
    # rendered, not blank: text and pictures put dark pixels on the white page
    assert (img.min(axis=2) < 128).mean() > 0.005


def test_show_says_when_sample_and_failures_choose_nothing(run, caplog):
    # A result drawn whole (a map) has no queries for --sample/--failures to choose: show says so
    # rather than ignoring them; results drawn as strips of chosen queries do not get the line.
    name, run_dir = run
    res = read_result(run_dir / "localize.h5")
    caplog.clear()
    with caplog.at_level("WARNING", logger="placeloc"):
        show_mod.show_run(run_dir, sample=2, failures=1)
    said = [r.getMessage() for r in caplog.records if "choose nothing here" in r.getMessage()]
    assert contract(res.kind).CHOOSES_QUERIES == (res.kind in ("ranked", "loops"))
    if name == "coembed":
        assert len(said) == 1 and "a map result is drawn whole (map.png)" in said[0]
    else:   # strips chosen, or UMap's own pictures (its show_extra speaks for itself)
        assert said == []
