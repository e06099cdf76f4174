"""Hostile inputs, second round: each case sets up one fault on tiny data and asserts the
clean outcome (what docs/reliability.md promises). ``make faults`` runs these with
tests/test_faults.py and prints one table row per case."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from faults_table import HANG_S, record
from faults_table import child_pids as _children
from faults_table import ignores_sigint as _ignores_sigint
from faults_table import run_cli as _cli
from faults_table import start_pooled_run as _start_pooled_run
from faults_table import stderr_of as _err
from faults_table import wait_for as _wait_for
from faults_table import wait_gone as _wait_gone
from faults_table import workers_of as _workers_of

from placeloc.core.config import load_config
from placeloc.core.images import ImageError, list_images, read_gray, read_rgb

ROOT = Path(__file__).resolve().parent.parent
PLACELOC = [sys.executable, "-m", "placeloc.cli"]


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


# ----------------------------------------------------------------- 1. EXIF orientation

def _upright() -> np.ndarray:
    """A 60 x 90 RGB picture with no symmetry: a turned or mirrored copy differs a lot."""
    y, x = np.mgrid[0:60, 0:90]
    img = np.stack([(x * 255 // 89), (y * 255 // 59), ((x + 2 * y) % 64) * 4], axis=-1).astype(np.uint8)
    img[5:20, 5:30] = (255, 255, 255)
    return img


def _jpeg_with_orientation(path: Path, stored_rgb: np.ndarray, orientation: int) -> None:
    from PIL import Image

    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(stored_rgb).save(path, quality=98, exif=exif.tobytes())


@pytest.mark.parametrize("orientation,stored", [(3, lambda u: np.rot90(u, 2)), (6, lambda u: np.rot90(u, 1))])
def test_exif_rotated_jpeg_reads_as_the_upright_image(tmp_path, orientation, stored):
    """A camera that stores the sensor's pixels and sets Orientation=3 (turned 180 deg) or 6
    (turn 90 deg clockwise to view) must read like the upright picture."""
    import cv2

    up = _upright()
    path = tmp_path / f"o{orientation}.jpg"
    _jpeg_with_orientation(path, np.ascontiguousarray(stored(up)), orientation)
    gray = read_gray(path)
    want = cv2.cvtColor(up, cv2.COLOR_RGB2GRAY)
    assert gray.shape == want.shape
    assert np.abs(gray.astype(int) - want).mean() < 3  # JPEG loss only; a turned copy differs by ~60
    assert np.abs(read_rgb(path).astype(int) - up).mean() < 4


def test_all_eight_exif_orientations_match_pillows_transpose(tmp_path):
    from PIL import Image, ImageOps

    stored = _upright()
    for o in range(1, 9):
        path = tmp_path / f"o{o}.jpg"
        _jpeg_with_orientation(path, stored, o)
        with Image.open(path) as im:
            want = np.asarray(ImageOps.exif_transpose(im).convert("RGB"))
        got = read_rgb(path)
        assert got.shape == want.shape, o
        assert np.abs(got.astype(int) - want).mean() < 2, o


def test_every_image_read_in_the_package_goes_through_the_one_reader():
    """No module but images.py calls cv2.imread (which ignores EXIF with IMREAD_UNCHANGED)."""
    offenders = []
    for path in (ROOT / "pipeline" / "placeloc").rglob("*.py"):
        if path.name == "images.py" or "experiments" in path.parts:
            continue
        text = path.read_text()
        if "cv2.imread(" in text or "IMREAD_" in text:
            offenders.append(str(path.relative_to(ROOT)))
    assert offenders == []


def test_seqslam_on_exif_rotated_queries_matches_the_plain_run(route, tmp_path):
    """End to end: the query frames stored turned 180 deg with Orientation=3 give the same
    Recall@1 as the same frames stored upright."""
    import cv2

    from placeloc.core.runner import read_metrics, run_all

    results = {}
    for kind in ("plain", "rotated"):
        folder = tmp_path / kind
        folder.mkdir()
        for png in sorted((route / "query").glob("*.png")):
            up = cv2.cvtColor(cv2.imread(str(png)), cv2.COLOR_BGR2RGB)
            if kind == "plain":
                _jpeg_with_orientation(folder / (png.stem + ".jpg"), up, 1)
            else:
                _jpeg_with_orientation(folder / (png.stem + ".jpg"), np.ascontiguousarray(np.rot90(up, 2)), 3)
        cfg = load_config(route / "config.yaml", ["plots=false", f"query.images={folder}"])
        run_all(cfg, tmp_path / f"run-{kind}", quiet=True)
        results[kind] = read_metrics(tmp_path / f"run-{kind}")["recall_at_1"]
    assert results["plain"] > 0.5 and results["rotated"] == pytest.approx(results["plain"], abs=0.02), results


# ----------------------------------------------------------------- 6/7. bad image files

def _truncated_jpeg(path: Path) -> None:
    import cv2

    ok, data = cv2.imencode(".jpg", (np.random.default_rng(0).random((64, 96)) * 255).astype(np.uint8))
    path.write_bytes(data.tobytes()[: len(data) // 2])


def test_truncated_jpeg_is_an_error_and_skipped_with_on_error_skip(route, tmp_path):
    from placeloc.core.runner import run_stage

    bad = route / "query" / "zz_truncated.jpg"
    _truncated_jpeg(bad)
    with pytest.raises(ImageError, match="truncated JPEG"):
        read_gray(bad)
    res = _cli(["extract", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"])
    assert res.exit_code == 2 and "zz_truncated.jpg: truncated JPEG" in _err(res) and "on_error: skip" in _err(res)
    cfg = load_config(route / "config.yaml", ["plots=false", "query.on_error=skip"])
    import h5py

    run_stage(cfg, tmp_path / "s", "extract", quiet=True)
    with h5py.File(tmp_path / "s" / "extract.h5") as f:
        skipped = [s.decode() for s in f["query/skipped"][()]]
    assert len(skipped) == 1 and "zz_truncated.jpg" in skipped[0]


def test_symlink_loop_names_the_link_and_on_error_skip_skips_it(route, tmp_path):
    loop = route / "query" / "loop.png"
    os.symlink(loop.name, loop)
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert "loop.png: is a symbolic link that points to itself" in lines[0] and "Errno" not in lines[0]
    images = list_images(route / "query", on_error="skip")
    assert loop not in images.paths and len(images.skipped) == 1
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "s"), "-q", "--set", "query.on_error=skip"])
    assert res.exit_code == 0, _err(res)


# ----------------------------------------------------------------- 2. side outputs commit with the artifact

EVALUATE_OUTPUTS = ("metrics.json", "per_query.csv", "pr_curve.png", "recall_at_n.png", "difference_matrix.png",
                    "strips_sample.png", "report.html")


def _leftovers(run: Path) -> list[str]:
    """Temporary files or staging folders anywhere in the run directory."""
    return [str(p.relative_to(run)) for p in run.rglob("*") if ".tmp" in p.name]


def test_a_folder_where_report_html_goes_fails_cleanly_and_mixes_nothing(route, tmp_path):
    """mkdir RUN/report.html, then a run whose evaluate re-runs: it stops with one line
    naming the folder, and no side output of the failed evaluate appears beside the
    artifacts and config.yaml of the earlier run."""
    run = tmp_path / "R"
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q"])
    assert res.exit_code == 0, _err(res)
    assert all((run / n).is_file() for n in EVALUATE_OUTPUTS)
    config_before = (run / "config.yaml").read_text()
    (run / "report.html").unlink()
    (run / "report.html").mkdir()
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q", "--set", "ground_truth.recall_at=[1, 2]"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert f"{run / 'report.html'} is a folder" in lines[0] and "rmdir" in lines[0]
    # all of evaluate's outputs went together with its artifact: none from the failed run
    assert [n for n in EVALUATE_OUTPUTS[:-1] if (run / n).exists()] == [] and not (run / "evaluate.h5").exists()
    assert (run / "config.yaml").read_text() == config_before and _leftovers(run) == []
    (run / "report.html").rmdir()
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q", "--set", "ground_truth.recall_at=[1, 2]"])
    assert res.exit_code == 0 and all((run / n).is_file() for n in EVALUATE_OUTPUTS)
    assert '"recall_at_2"' in (run / "metrics.json").read_text()


def test_disk_full_while_evaluate_draws_leaves_no_metrics_and_no_tmp_png(route, tmp_path, monkeypatch):
    """The disk fills while evaluate saves its difference-matrix picture (after metrics.json
    and per_query.csv were written): one line, and nothing of that evaluate in the run dir."""
    import builtins
    import errno

    import placeloc.evaluation.raster as raster

    run = tmp_path / "R"

    def full(fname, mode="r", *a, **k):  # the PNG's file fills the disk half-way through its bytes
        if "difference_matrix" in str(fname) and "w" in mode:
            Path(fname).write_bytes(b"\x89PNG half")
            raise OSError(errno.ENOSPC, "No space left on device", str(fname))
        return builtins.open(fname, mode, *a, **k)

    monkeypatch.setattr(raster, "open", full, raising=False)  # the module's own name shadows the builtin
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: no space left on "), lines
    assert f"while writing {run}/difference_matrix.png" in lines[0], lines
    assert (run / "localize.h5").is_file() and (run / "matches.csv").is_file()  # localize finished and committed
    assert [n for n in EVALUATE_OUTPUTS if (run / n).exists()] == [] and not (run / "evaluate.h5").exists()
    assert _leftovers(run) == []


def test_a_localize_that_fails_leaves_no_matches_csv(route, tmp_path, monkeypatch):
    """Ctrl-C right after localize wrote matches.csv (before its artifact was complete):
    no matches.csv appears, and the next run resumes from extract."""
    import placeloc.evaluation.ranked as ranked

    real = ranked.write_matches_csv

    def then_interrupt(path, *a, **k):
        real(path, *a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(ranked, "write_matches_csv", then_interrupt)
    run = tmp_path / "R"
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q"])
    assert res.exit_code == 130 and _err(res).strip() == "interrupted; rerun to resume"
    assert (run / "extract.h5").is_file() and not (run / "localize.h5").exists()
    assert not (run / "matches.csv").exists() and _leftovers(run) == []
    monkeypatch.undo()
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q"])
    assert res.exit_code == 0 and (run / "matches.csv").is_file()


def test_forced_rerun_that_fails_keeps_the_previous_complete_set(route, tmp_path, monkeypatch):
    """--force on the same inputs: until the new results are complete, the old artifact and
    all its side outputs stay exactly as they were."""
    import placeloc.seqslam.stages as stages

    run = tmp_path / "R"
    cfg = load_config(route / "config.yaml")
    from placeloc.core.runner import run_all, run_stage

    run_all(cfg, run, quiet=True)
    before = {n: (run / n).read_bytes() for n in EVALUATE_OUTPUTS + ("evaluate.h5",)}

    def broken(ctx):
        (ctx.output("metrics.json")).write_text("{}")
        raise RuntimeError("fails halfway")

    import dataclasses

    monkeypatch.setitem(stages.METHOD.stages, "evaluate", dataclasses.replace(stages.METHOD.stages["evaluate"], run=broken))
    with pytest.raises(RuntimeError):
        run_stage(cfg, run, "evaluate", force=True, quiet=True)
    assert {n: (run / n).read_bytes() for n in before} == before and _leftovers(run) == []


def test_stale_staging_folder_of_a_killed_run_is_removed(route, tmp_path):
    from placeloc.core.runner import run_all

    run = tmp_path / "R"
    stale = run / ".evaluate.outputs.tmp-999999999"
    stale.mkdir(parents=True)
    (stale / "metrics.json").write_text("{}")
    run_all(load_config(route / "config.yaml", ["plots=false"]), run, quiet=True)
    assert not stale.exists() and _leftovers(run) == []


# ----------------------------------------------------------------- 3. nothing hangs

@pytest.mark.parametrize("gap", [0.15, 0.02])
def test_double_ctrl_c_during_a_pooled_stage_exits_at_once(tmp_path, gap):
    """Two Ctrl-C in quick succession (a terminal sends them to the whole group): one line,
    rc 130, the process and its workers gone within a few seconds."""
    import signal
    import subprocess
    import time


    proc, tmpdir = _start_pooled_run(tmp_path)
    family = _children(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(gap)  # the gap between the two key presses: the case's input, not a wait for an event
    with __import__("contextlib").suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=HANG_S)  # only a hang fails; a loaded machine may take its time
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail(f"placeloc did not exit within {HANG_S} s of a double Ctrl-C (a hang)")
    record(proc.returncode, err)
    assert proc.returncode == 130 and err.strip() == "interrupted; rerun to resume", err
    assert _wait_gone(family) == [] and list(tmpdir.glob("placeloc-shared-*")) == []


@pytest.fixture
def http_server():
    """python -m http.server on a free loopback port."""
    import socket
    import subprocess

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    def accepts() -> bool:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return True
        except OSError:
            return False

    try:
        _wait_for(accepts, "python -m http.server listening")  # however long a loaded machine takes to start it
        yield f"tcp://127.0.0.1:{port}"
    finally:
        proc.kill()
        proc.wait()


@pytest.fixture
def silent_peer():
    """A socket that accepts connections and never says anything."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    held: list = []
    stop = threading.Event()

    def accept() -> None:
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(srv.accept()[0])
            except OSError:
                continue

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        stop.set()
        t.join()
        for c in held:
            c.close()
        srv.close()


@pytest.mark.parametrize("peer", ["http_server", "silent_peer"])
def test_a_scheduler_address_that_is_not_dask_fails_within_5s(route, tmp_path, request, peer):
    """A web server (which waits for a request) and a peer that never speaks: one line
    within the documented 3-5 s, not Dask's 300 s wait or its "(MemoryError)"."""

    pytest.importorskip("distributed")
    address = request.getfixturevalue(peer)
    # The message says placeloc's own 3 s greeting check answered, not Dask's 300 s wait: that
    # is what the case proves; the wall time would depend on the machine's load.
    res = _cli(["extract", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q",
                "--set", "executor.kind=dask", "--set", f"executor.scheduler={address}"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert f"no Dask scheduler answers at {address} (something accepts connections there but says nothing within 3 s)" \
        in lines[0] and "local-cluster" in lines[0], lines
    assert "MemoryError" not in lines[0]


def _dask_run(tmp_path: Path, frames: int):
    import subprocess

    from placeloc.synth.route import generate

    generate(tmp_path / "data", seed=3, frames=frames)
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    cmd = PLACELOC + ["run", str(tmp_path / "data" / "config.yaml"), "--run-dir", str(tmp_path / "run"), "-q",
                      "--set", "executor.kind=dask", "--set", "executor.workers=2", "--set", "executor.scheduler=local-cluster",
                      "--set", "seqslam.images_per_task=4", "--set", "plots=false"]
    proc = subprocess.Popen(cmd, env={**os.environ, "TMPDIR": str(tmpdir)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    return proc, tmpdir


def test_local_dask_cluster_leaves_no_scratch_space_in_tmpdir(tmp_path):
    pytest.importorskip("distributed")
    proc, tmpdir = _dask_run(tmp_path, 60)
    out, err = proc.communicate(timeout=HANG_S)
    record(proc.returncode, err)
    assert proc.returncode == 0, err
    assert list(tmpdir.iterdir()) == [], list(tmpdir.iterdir())


def test_ctrl_c_under_a_local_dask_cluster_is_one_line(tmp_path):
    import signal
    import subprocess


    pytest.importorskip("distributed")
    proc, tmpdir = _dask_run(tmp_path, 3000)

    # Events, not times: extract's staging folder exists (the cluster is up and the stage has
    # begun) and both Dask workers ignore Ctrl-C (their preload ran; before it, a Ctrl-C may
    # show Dask's own messages: documented). On a loaded machine this only takes longer.
    def ready() -> bool:
        if proc.poll() is not None:
            return True
        workers = _workers_of(proc.pid)
        return (bool(list((tmp_path / "run").glob(".extract.outputs.tmp-*"))) and len(workers) >= 2
                and all(_ignores_sigint(w) for w in workers))

    _wait_for(ready, "the local Dask cluster's two workers starting on extract")
    assert proc.poll() is None, "the run finished before it could be interrupted"
    family = _children(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=HANG_S)  # only a hang fails
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail(f"placeloc did not exit within {HANG_S} s of Ctrl-C under a local Dask cluster (a hang)")
    record(proc.returncode, err)
    assert proc.returncode == 130 and err.strip() == "interrupted; rerun to resume", err
    assert _wait_gone(family) == [] and list(tmpdir.iterdir()) == []


# ----------------------------------------------------------------- 5. one classification of failures

def test_a_pool_worker_killed_with_sigkill_is_an_environment_failure(tmp_path):
    """What the out-of-memory killer does to a worker: one line that says so and what to
    change, rc 3, no traceback, no "bug"."""
    import signal

    import psutil

    proc, _ = _start_pooled_run(tmp_path)
    workers = []
    for p in _children(proc.pid):
        with __import__("contextlib").suppress(psutil.Error):
            cmd = " ".join(psutil.Process(p).cmdline())
            if "spawn_main" in cmd and "resource_tracker" not in cmd:
                workers.append(p)
    assert workers
    os.kill(workers[0], signal.SIGKILL)
    out, err = proc.communicate(timeout=HANG_S)
    record(proc.returncode, err)
    lines = _lines(err)
    assert proc.returncode == 3 and len(lines) == 1, err
    assert lines[0].startswith("error: a worker process was killed (out of memory?)") and "executor.workers (now 2)" in lines[0]
    assert "Traceback" not in err and "bug" not in err and "array(" not in err


def test_killed_dask_worker_is_an_environment_failure():
    """Dask gives up on a task after its workers died repeatedly (KilledWorker): the same
    environment failure as a killed pool worker."""
    pytest.importorskip("distributed")
    from distributed.scheduler import KilledWorker

    from placeloc.core.dask_executor import DaskExecutor
    from placeloc.core.errors import WorkerLostError

    class Dead:
        def result(self):
            raise KilledWorker("extract_chunk-1", "tcp://127.0.0.1:1", [])

        def done(self):
            return True

        def release(self):
            pass

    ex = DaskExecutor.__new__(DaskExecutor)
    ex.workers, ex.retries = 2, 2
    with pytest.raises(WorkerLostError, match=r"a worker process was killed \(out of memory\?\) .*executor.workers \(now 2\)"):
        ex._result(len, (np.zeros((500, 500)), "x"), Dead(), lambda item: "chunk 3")


def test_describe_item_never_dumps_an_array():
    from placeloc.core.executor import describe_item

    text = describe_item((np.zeros((1000, 64)), {"a": np.ones(10)}, "settings"))
    assert "array(1000, 64) float64" in text and "0." not in text and len(text) <= 160


@pytest.mark.parametrize("where", ["file", "set"])
def test_100000_nested_brackets_are_a_one_line_config_error(route, tmp_path, where):
    deep = "[" * 100_000
    if where == "file":
        cfg = tmp_path / "deep.yaml"
        cfg.write_text(f"method: seqslam\nseqslam: {{ds: {deep}}}\n")
        args = ["run", str(cfg)]
    else:
        args = ["run", str(route / "config.yaml"), "--set", f"seqslam.ds={deep}"]
    res = _cli(args + ["--run-dir", str(tmp_path / "r")])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1 and "nested too deeply" in lines[0], lines[:3]
    assert len(lines[0]) < 1000  # the value is not echoed whole
    assert "RecursionError" not in _err(res)


def test_raw_os_errors_are_worded_with_the_file_and_the_fix():
    from placeloc.cli import _one_line, classify

    exc = OSError(30, "Read-only file system", "/mnt/ro/run/.lock")
    assert classify(exc) == "user"
    assert _one_line(exc) == "/mnt/ro/run/.lock: is on a read-only file system; choose a writable place, e.g. another --run-dir"
    assert "Errno" not in _one_line(FileExistsError(17, "File exists", "R"))


# ----------------------------------------------------------------- 6. bad input refused up front

def test_a_sequence_longer_than_the_traverse_is_refused_up_front(route, tmp_path):
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q", "--set", "seqslam.ds=100000"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert "seqslam.ds=100000 needs sequences of ds + 1 = 100001 frames" in lines[0] and "set seqslam.ds to at most" in lines[0]
    assert not (tmp_path / "r" / "extract.h5").exists()


def test_a_negative_ground_truth_range_end_is_refused_like_a_negative_index(route, tmp_path):
    from placeloc.evaluation.ground_truth import GroundTruthError

    (route / "ground_truth.csv").write_text("query,ref_first,ref_last\n40,-3,2\n")
    with pytest.raises(GroundTruthError, match=r"ground_truth.csv:2: reference index -3 is negative"):
        load_config(route / "config.yaml", ["plots=false"])  # the config check reads the ground truth


def test_an_empty_list_parameter_is_refused_at_config_check(route):
    from placeloc.core.config import ConfigError

    data = {"method": "coembed", "coembed": {"observations": str(route / "x.csv")}}
    with pytest.raises(ConfigError, match=r"coembed.alpha_grid: \[\] has 0 item\(s\); it needs at least 1"):
        load_config(data=data, overrides=["coembed.alpha_grid=[]"])


# ----------------------------------------------------------------- 7. messages with a fix

def test_run_dir_that_is_a_file_or_read_only(route, tmp_path, monkeypatch):
    afile = tmp_path / "R"
    afile.write_text("x")
    res = _cli(["run", str(route / "config.yaml"), "-o", str(afile), "-q"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1 and "is a file, not a folder" in lines[0] and "Errno" not in lines[0]
    # an up-to-date run in a run directory that became read-only (EROFS on the lock file)
    run = tmp_path / "run"
    assert _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q", "--set", "plots=false"]).exit_code == 0
    real_open = os.open

    def read_only(path, flags, *a):
        if str(path).endswith(".lock"):
            raise OSError(30, "Read-only file system", str(path))
        return real_open(path, flags, *a)

    monkeypatch.setattr(os, "open", read_only)
    res = _cli(["run", str(route / "config.yaml"), "-o", str(run), "-q", "--set", "plots=false"])
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert f"--run-dir {run} is on a read-only file system" in lines[0] and "even when every stage is up to date" in lines[0]


@pytest.mark.parametrize("var", ["PLACELOC_MEMORY_LIMIT_MB", "PLACELOC_DISK_LIMIT_MB"])
def test_limit_variables_that_are_not_numbers(route, tmp_path, var):
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"], **{var: "abc"})
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert f"{var}='abc' is not a number of megabytes" in lines[0] and "could not convert" not in lines[0]


def test_disk_limit_variable_is_named_not_the_file_system(route, tmp_path):
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"], PLACELOC_DISK_LIMIT_MB="1")
    lines = _lines(_err(res))
    assert res.exit_code == 2 and len(lines) == 1, lines
    assert "more than PLACELOC_DISK_LIMIT_MB=1 allows" in lines[0] and "no space left" not in lines[0]


def test_poses_csv_with_a_utf8_bom_is_read(tmp_path):
    from placeloc.evaluation.poses import read_poses

    path = tmp_path / "poses.csv"
    path.write_bytes("\ufeffname,x,y\na.png,1.5,2\nb.png,3,4\n".encode())
    poses = read_poses(path)
    assert poses.keys == ("a.png", "b.png") and np.allclose(poses.xy, [[1.5, 2], [3, 4]])
