"""The staged pipeline: artifacts, skip/re-run logic, atomic writes, bad input, CLI smoke."""

from __future__ import annotations

import csv
import json
import logging
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from placeloc.core.artifacts import atomic_h5, describe, read_stamp
from placeloc.core.config import load_config
from placeloc.core.images import ImageError, list_images, natural_key
from placeloc.core.methods import Stage
from placeloc.core.runner import run_all, run_stage
from placeloc.seqslam import stages as seqslam_stages

ROOT = Path(__file__).resolve().parent.parent


def _mtimes(run_dir: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in run_dir.glob("*.h5")}


def _settled_run(route: Path, tmp_path: Path) -> tuple[dict, Path, dict[str, int]]:
    """The route's config (no plots) run twice in ``tmp_path/run``: the second run re-runs
    nothing. Returns the config, the run folder and the artifacts' mtimes."""
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_all(cfg, run, quiet=True)
    first = _mtimes(run)
    run_all(cfg, run, quiet=True)
    assert _mtimes(run) == first
    return cfg, run, first


def test_natural_sort_and_empty_folder(tmp_path):
    assert sorted(["img10.png", "img2.png", "img1.png"], key=natural_key) == ["img1.png", "img2.png", "img10.png"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImageError, match="no images found"):
        list_images(tmp_path / "empty")


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "x.h5"
    with pytest.raises(RuntimeError):
        with atomic_h5(target, {"stamp": "s"}) as f:
            f["a"] = np.arange(3)
            raise RuntimeError("boom")
    assert not target.exists() and list(tmp_path.iterdir()) == []
    with atomic_h5(target, {"stamp": "s"}) as f:
        f["a"] = np.arange(3)
    assert read_stamp(target) == "s"


def test_run_skips_up_to_date_and_reruns_what_changed(route, tmp_path):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_all(cfg, run, quiet=True)
    first = _mtimes(run)
    assert set(first) == {"extract.h5", "build-dictionary.h5", "index.h5", "localize.h5", "evaluate.h5"}
    run_all(cfg, run, quiet=True)
    assert _mtimes(run) == first  # everything up to date

    # a search parameter: extract stays, localize and evaluate re-run
    cfg2 = load_config(route / "config.yaml", ["plots=false", "seqslam.ds=5"])
    run_all(cfg2, run, quiet=True)
    after = _mtimes(run)
    assert after["extract.h5"] == first["extract.h5"]
    assert after["localize.h5"] != first["localize.h5"] and after["evaluate.h5"] != first["evaluate.h5"]

    # an input image changed: everything from extract re-runs
    img = sorted((route / "query").iterdir())[3]
    img.write_bytes(img.read_bytes())
    run_all(cfg2, run, quiet=True)
    assert _mtimes(run)["extract.h5"] != after["extract.h5"]

    # --force on one stage re-runs only that stage
    before = _mtimes(run)
    run_stage(cfg2, run, "localize", force=True, quiet=True)
    now = _mtimes(run)
    assert now["localize.h5"] != before["localize.h5"] and now["extract.h5"] == before["extract.h5"]

    text = describe(run / "extract.h5")
    assert "stage: extract" in text and "images.query" in text and "comparison: sad" in text


def test_interrupted_stage_leaves_no_trusted_artifact(route, tmp_path, monkeypatch):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_stage(cfg, run, "extract", quiet=True)

    def interrupted(ctx):
        ctx.out.create_dataset("difference", data=np.zeros(3))
        raise KeyboardInterrupt

    declared = seqslam_stages.METHOD.stages["localize"]
    monkeypatch.setitem(seqslam_stages.METHOD.stages, "localize", Stage(interrupted, declared.keys))
    with pytest.raises(KeyboardInterrupt):
        run_stage(cfg, run, "localize", quiet=True)
    assert not (run / "localize.h5").exists()
    assert not [p for p in run.iterdir() if ".tmp-" in p.name]
    monkeypatch.undo()
    run_stage(cfg, run, "localize", quiet=True)
    with h5py.File(run / "localize.h5") as f:
        assert f["difference"].shape == (80, 81)


def test_corrupt_image_stops_with_its_path_or_is_skipped(route, tmp_path):
    bad = route / "query" / "frame5.png"
    bad.write_bytes(b"not a png")
    cfg = load_config(route / "config.yaml", ["plots=false"])
    with pytest.raises(ImageError, match="frame5.png"):
        run_stage(cfg, tmp_path / "a", "extract", quiet=True)
    cfg = load_config(route / "config.yaml", ["plots=false", "query.on_error=skip"])
    run_all(cfg, tmp_path / "b", quiet=True)
    with h5py.File(tmp_path / "b" / "extract.h5") as f:
        assert len(f["query/features"]) == 80
        assert 5 not in f["query/index"][()]
        assert "frame5.png" in f["query/skipped"][0].decode()
    # ground truth still lines up by original index: the accuracy is that of the full run
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert m["n_queries"] == 80 and m["recall_at_1"] > 0.5


def test_loop_closure_on_a_route_driven_twice(route, tmp_path):
    """Reference = the route then the same route again: frame i + 80 must close on frame i."""
    both = tmp_path / "both"
    both.mkdir()
    frames = sorted((route / "reference").iterdir(), key=lambda p: natural_key(p.name))
    for i, p in enumerate(frames + frames):
        (both / f"f{i}.png").write_bytes(p.read_bytes())
    gt = tmp_path / "gt.csv"
    with gt.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["query", "ref_first", "ref_last"])
        for q in range(160):
            if q >= 80:
                w.writerow([q, max(0, q - 82), q - 78])
    cfg = load_config(data={"method": "seqslam", "reference": {"images": str(both)}, "plots": False,
                            "ground_truth": {"kind": "csv", "path": str(gt), "exclude_recent": 40}}, base_dir=tmp_path)
    run_all(cfg, tmp_path / "lc", quiet=True)
    with h5py.File(tmp_path / "lc" / "localize.h5") as f:
        best = f["candidates"][:, 0]
        assert bool(f.attrs["loop_closure"])
        assert f["result"].attrs["kind"] == "loops" and (f["result/match"][()] == best).all()
    q = np.arange(160)
    assert (best[q >= 95] == q[q >= 95] - 80).all()
    matched = best >= 0
    assert (best[matched] <= q[matched] - 40).all()
    # scored as loop closures with the same exclusion: 80 frames close a loop
    m = json.loads((tmp_path / "lc" / "metrics.json").read_text())
    assert m["frames_with_loop"] == 80 and m["n_frames"] == 160 and m["exclude_recent"] == 40
    assert m["recall_at_100_precision"] >= 65 / 80


def test_cli_run_end_to_end_on_data_samples(tmp_path):
    run = tmp_path / "demo"
    proc = subprocess.run([sys.executable, str(ROOT / "cli.py"), "run", str(ROOT / "configs" / "demo.yaml"),
                           "--run-dir", str(run), "--quiet"], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    m = json.loads((run / "metrics.json").read_text())
    for key in ("recall_at_1", "recall_at_5", "recall_at_10", "auc_pr", "recall_at_100_precision", "max_f1",
                "n_queries", "dissimilarity_mean", "dissimilarity_count_ge1"):
        assert key in m
    assert m["n_queries"] == 81
    # abs_zncc survives the night segment of the sample route (known-answer ground truth)
    assert m["recall_at_1"] >= 0.8
    rows = list(csv.DictReader((run / "matches.csv").open()))
    assert len(rows) == 81 and rows[0].keys() >= {"query", "reference", "confidence"}
    assert (run / "pr_curve.png").stat().st_size > 1000 and (run / "difference_matrix.png").stat().st_size > 1000
    assert (run / "config.yaml").is_file()
    again = subprocess.run([sys.executable, str(ROOT / "cli.py"), "run", str(ROOT / "configs" / "demo.yaml"),
                            "--run-dir", str(run)], capture_output=True, text=True, cwd=ROOT)
    assert "up to date" in again.stderr
    bad = subprocess.run([sys.executable, str(ROOT / "cli.py"), "run", str(ROOT / "configs" / "demo.yaml"),
                          "--run-dir", str(run), "--set", "seqslam.comparison=nope"], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "seqslam.comparison" in bad.stderr
    ins = subprocess.run([sys.executable, str(ROOT / "cli.py"), "inspect", str(run / "localize.h5")],
                         capture_output=True, text=True, cwd=ROOT)
    assert ins.returncode == 0 and "difference" in ins.stdout and "rows = reference" in ins.stdout


def test_a_changed_method_input_file_reruns_from_the_first_stage(tmp_path):
    """Files named by a method's path keys are fingerprinted like images."""
    from dataclasses import dataclass

    from placeloc.core.methods import Method
    from placeloc.core.params import Params, param
    from placeloc.core.runner import stage_inputs

    @dataclass(frozen=True)
    class ToyParams(Params):
        observations: str | None = param(None, path=True)

    obs = tmp_path / "obs.csv"
    obs.write_text("t,feature,value\n0,1,0.5\n")
    method = Method(name="toy", params=ToyParams, stages={}, required_images=())
    cfg = {"method": "toy", "seed": 0, "reference": None, "query": None, "toy": {"observations": str(obs)}}
    before = stage_inputs(cfg, method, "extract", {}, {})
    assert stage_inputs(cfg, method, "extract", {}, {}) == before
    obs.write_text("t,feature,value\n0,1,0.75\n")
    assert stage_inputs(cfg, method, "extract", {}, {})["file.observations"] != before["file.observations"]
    assert "file.observations" not in stage_inputs(cfg, method, "localize", {}, {"index": "parent"})


def test_atomic_open_leaves_the_old_file_on_failure(tmp_path):
    from placeloc.core.artifacts import atomic_open

    target = tmp_path / "matches.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError):
        with atomic_open(target) as fh:
            fh.write("half")
            raise RuntimeError("boom")
    assert target.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["matches.csv"]
    with atomic_open(target) as fh:
        fh.write("new\n")
    assert target.read_text() == "new\n"


def test_a_missing_or_edited_side_output_reruns_its_stage(route, tmp_path):
    """metrics.json and the plots belong to evaluate: delete or edit one and evaluate is no
    longer up to date, while the stages before it stay skipped."""
    cfg, run, before = _settled_run(route, tmp_path)
    (run / "metrics.json").unlink()
    run_all(cfg, run, quiet=True)
    now = _mtimes(run)
    assert (run / "metrics.json").is_file()
    assert now["evaluate.h5"] != before["evaluate.h5"] and now["localize.h5"] == before["localize.h5"]
    (run / "matches.csv").write_text("edited by hand\n")
    run_all(cfg, run, quiet=True)
    assert (run / "matches.csv").read_text().startswith("query,reference")
    assert _mtimes(run)["extract.h5"] == before["extract.h5"]


def test_a_change_of_placeloc_s_own_code_reruns_every_stage(route, tmp_path, monkeypatch, caplog):
    # the version number stays between commits; the stamp holds the source's fingerprint, so
    # an artifact written by other code is not taken as up to date
    from placeloc.core import runner

    fingerprint = runner.code_fingerprint()
    assert len(fingerprint) == 64 and runner.code_fingerprint() == fingerprint      # once a process
    cfg, run, first = _settled_run(route, tmp_path)
    assert f"placeloc_code: {fingerprint}" in describe(run / "extract.h5")      # placeloc inspect says which code
    monkeypatch.setattr(runner, "code_fingerprint", lambda: "0" * 64)
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_all(cfg, run, quiet=True)
    assert f"extract: {run / 'extract.h5'} was written by other placeloc code (source fingerprint {fingerprint[:12]}, " \
           f"now {'0' * 12}); the stage runs again" in caplog.text
    again = _mtimes(run)
    assert all(again[k] != first[k] for k in first)


def test_the_code_fingerprint_follows_the_source(tmp_path, monkeypatch):
    # by path and content: a copy of the package fingerprints alike, an edited file does not
    import shutil

    from placeloc.core import runner, source

    assert runner.code_fingerprint is source.code_fingerprint   # the runner's is the leaf module's
    src = Path(source.__file__).resolve().parent.parent
    copy = tmp_path / "placeloc"
    shutil.copytree(src, copy, ignore=shutil.ignore_patterns("__pycache__"))

    def fingerprint_of(root: Path) -> str:
        source.code_fingerprint.cache_clear()
        monkeypatch.setattr(source, "__file__", str(root / "core" / "source.py"))
        try:
            return source.code_fingerprint()
        finally:
            source.code_fingerprint.cache_clear()

    original = fingerprint_of(src)
    assert fingerprint_of(copy) == original
    (copy / "core" / "runner.py").write_text((copy / "core" / "runner.py").read_text() + "\n# edited\n")
    assert fingerprint_of(copy) != original
