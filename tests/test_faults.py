"""Hostile inputs and faults: each case sets up the fault on tiny data and asserts the wanted behaviour.

Full disk, killed process pools, stale or mixed run directories, unbounded sizes, the one
CLI error boundary, parameters that cannot work and misleading messages.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import struct
import subprocess
import sys
import threading
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from faults_table import HANG_S, record, start_pooled_run, wait_for, wait_gone, workers_of
from faults_table import run_cli as _cli
from faults_table import stderr_of as _err

from placeloc.core.artifacts import DiskFullError, atomic_h5, atomic_open
from placeloc.core.config import ConfigError, load_config
from placeloc.core.images import ImageError, ImageSet, read_gray
from placeloc.core.limits import ResourceError, check_resources, image_size
from placeloc.core.methods import STAGES
from placeloc.core.runner import RunDirError, image_sets, lock_run_dir, run_all, run_stage

ROOT = Path(__file__).resolve().parent.parent
PLACELOC = [sys.executable, "-m", "placeloc.cli"]


def _mtimes(run_dir: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in run_dir.glob("*.h5")}


# ----------------------------------------------------------------- 1. full disk

@pytest.fixture
def tiny_fs(tmp_path):
    """A 1 MiB tmpfs (needs root and mount permission; skipped otherwise)."""
    mnt = tmp_path / "full"
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_full_disk_hdf5_write_is_one_clean_error_and_leaves_nothing(tiny_fs):
    target = tiny_fs / "extract.h5"
    with pytest.raises(DiskFullError) as info:
        with atomic_h5(target, {"stamp": "s"}) as f:
            f["a"] = np.random.default_rng(0).random(400_000)  # 3.2 MB into 1 MiB
    msg = str(info.value)
    assert msg.startswith(f"no space left on {tiny_fs} (tmpfs) while writing {target} (needs about ")
    assert "MB)" in msg and list(tiny_fs.iterdir()) == []


def test_full_disk_text_write_leaves_nothing(tiny_fs):
    with pytest.raises(DiskFullError, match="no space left on .* while writing .*metrics.json"):
        with atomic_open(tiny_fs / "metrics.json") as fh:
            for _ in range(200):
                fh.write("x" * 10_000)
                fh.flush()
    assert list(tiny_fs.iterdir()) == []


def test_full_disk_during_a_real_run_is_one_line_rc2(route, tiny_fs):
    """The size check is switched off here so the write itself meets the full disk
    (extract.h5 is about 0.5 MB; the tmpfs holds 1 MiB minus what the copy of the config
    takes): no segfault, no "Exception ignored" stream, one line, nothing left behind."""
    filler = tiny_fs / "filler"
    filler.write_bytes(b"\0" * 700_000)
    run = tiny_fs / "run"
    script = ("import sys, placeloc.core.runner as r; r.check_resources = lambda *a: []; from placeloc.cli import main; "
              f"sys.argv = ['placeloc', 'run', {str(route / 'config.yaml')!r}, '--run-dir', {str(run)!r}, '-q']; main()")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=HANG_S)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"error: no space left on {tiny_fs} (tmpfs) while writing {run}/") and "needs about" in lines[0]
    assert not list(run.glob("*.h5")) and not list(run.glob(".*tmp-*"))


def test_run_checks_free_space_up_front(route, tmp_path):
    """The artifact sizes are known before the work: a run that cannot fit stops at once,
    rc 2, one line with the figure, and writes no artifact."""
    run = tmp_path / "run"
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(run), "-q"], PLACELOC_DISK_LIMIT_MB="0.01")
    assert res.exit_code == 2, res.output
    lines = [ln for ln in _err(res).splitlines() if ln.strip()]
    assert len(lines) == 1 and "needs about" in lines[0] and "more than PLACELOC_DISK_LIMIT_MB=0.01 allows" in lines[0], lines
    assert "no space left" not in lines[0]  # the variable, not the disk, is short
    assert not list(run.glob("*.h5")) and not list(run.glob(".*tmp-*"))


# ----------------------------------------------------------------- 2. killed process pools

def _children(pid: int) -> list[int]:
    import psutil

    try:
        return [c.pid for c in psutil.Process(pid).children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def test_killed_run_takes_its_workers_along_and_next_run_cleans_shared_files(tmp_path):

    from placeloc.synth.route import generate

    generate(tmp_path / "data", seed=1, frames=240)
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    stale = tmpdir / "placeloc-shared-999999999-abc"  # left by a process that no longer exists
    stale.mkdir()
    (stale / "shared.npy").write_bytes(b"x")
    env = {**os.environ, "TMPDIR": str(tmpdir)}
    cmd = PLACELOC + ["localize", str(tmp_path / "data" / "config.yaml"), "--run-dir", str(tmp_path / "run"), "-q",
                      "--set", "executor.workers=2", "--set", "seqslam.images_per_task=2", "--set", "plots=false"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # Killed at any moment after both workers exist, they must die: before their initializer
    # they find the parent gone when they read their first task, after it the parent-death
    # signal and the watchdog take them. So the case waits for that event only.
    wait_for(lambda: proc.poll() is not None or len(workers_of(proc.pid)) >= 2, "the pool's two workers starting")
    assert proc.poll() is None, "the pool never started (the run finished too fast?)"
    everything = _children(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    alive = wait_gone(everything)
    assert alive == [], f"processes outlived their killed parent: {alive}"

    # the next run removes the shared folders of dead runs (ours and the stale one) and its own
    again = subprocess.run(cmd[:-6] + ["--set", "plots=false"], env=env, capture_output=True, text=True, timeout=HANG_S)
    assert again.returncode == 0, again.stderr
    assert list(tmpdir.glob("placeloc-shared-*")) == []


@pytest.mark.parametrize("sig,rc", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_and_sigterm_with_a_pool_is_one_line(tmp_path, sig, rc):
    # Long enough (600 frames) that the pool is still extracting when the signal comes (the
    # whole run takes several seconds; the signal follows the workers' start by 0.3 s).
    proc, tmpdir = start_pooled_run(tmp_path)
    os.killpg(proc.pid, sig) if sig == signal.SIGINT else proc.send_signal(sig)
    out, err = proc.communicate(timeout=HANG_S)
    record(proc.returncode, err)
    assert proc.returncode == rc, err
    assert err.strip() == "interrupted; rerun to resume", err
    assert list(tmpdir.glob("placeloc-shared-*")) == [] and not list((tmp_path / "run").glob(".*tmp-*"))


class _Stop(Exception):
    pass


def _raise_stop(signum, frame):
    raise _Stop()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_a_worker_is_spawned_waits_until_the_worker_has_its_instructions(monkeypatch, sig):
    """A spawned worker reads its instructions from a pipe the parent writes just after the
    exec. SIGTERM in between used to raise in the parent before the write, and the worker
    printed "EOFError: Ran out of input" under the run's one line (seen once in CI); Ctrl-C
    there was ignored by the parent, so the run went on. The signal here comes at exactly
    that moment: start() must finish, the worker must run its task, and the signal must
    then reach the parent's handler."""
    from multiprocessing import util

    from placeloc.core.executor import _QuietSpawnProcess

    real = util.spawnv_passfds

    def spawn_then_signal(*args, **kwargs):
        pid = real(*args, **kwargs)
        signal.raise_signal(sig)  # a handler would run here, before the write
        return pid

    monkeypatch.setattr(util, "spawnv_passfds", spawn_then_signal)
    old = signal.signal(sig, _raise_stop)
    try:
        proc = _QuietSpawnProcess(target=abs, args=(0,))
        with pytest.raises(_Stop):
            proc.start()
    finally:
        signal.signal(sig, old)
    assert proc._popen is not None, "start() was cut short: the worker never got its instructions"
    proc.join(HANG_S)
    assert proc.exitcode == 0
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set()), "Ctrl-C left blocked"


def test_a_worker_starts_with_ctrl_c_held_back_and_then_ignores_it(tmp_path):
    """The worker is born with SIGINT blocked (so a Ctrl-C during its imports does nothing)
    and, once its initializer ran, ignores it and no longer blocks it."""
    from placeloc.core.executor import _QuietSpawnProcess

    out = tmp_path / "masks.txt"
    proc = _QuietSpawnProcess(target=_masks_then_init, args=(str(out), os.getpid()))
    proc.start()
    proc.join(HANG_S)
    assert proc.exitcode == 0
    before, after = out.read_text().split()
    assert before == "blocked" and after == "ignored-unblocked"


def _masks_then_init(path: str, parent: int) -> None:
    """In the worker: whether Ctrl-C is blocked as it starts, then what the pool's
    initializer leaves."""
    from placeloc.core.executor import _worker_init

    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, set())
    _worker_init(parent)
    ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    unblocked = signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, set())
    Path(path).write_text(f"{'blocked' if blocked else 'open'} "
                          f"{'ignored' if ignored else 'handled'}-{'unblocked' if unblocked else 'blocked'}")


# ----------------------------------------------------------------- 3. stale or mixed results

def test_rewritten_parent_reruns_children_even_with_the_same_stamp(route, tmp_path):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_all(cfg, run, quiet=True)
    before = _mtimes(run)
    run_stage(cfg, run, "localize", force=True, quiet=True)
    run_all(cfg, run, quiet=True)
    after = _mtimes(run)
    assert after["evaluate.h5"] != before["evaluate.h5"]  # evaluate follows the rebuilt localize
    assert after["extract.h5"] == before["extract.h5"]


def test_files_beside_the_images_are_inputs_of_evaluate(route, tmp_path):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    (route / "query" / "poses.csv").write_text("frame,x,y\n0,0,0\n")
    run_all(cfg, run, quiet=True)
    before = _mtimes(run)
    (route / "query" / "poses.csv").write_text("frame,x,y\n0,5,5\n")
    run_all(cfg, run, quiet=True)
    after = _mtimes(run)
    assert after["evaluate.h5"] != before["evaluate.h5"] and after["extract.h5"] == before["extract.h5"]


def test_content_fingerprint_sees_an_edit_that_keeps_size_and_mtime(route, tmp_path):
    import cv2

    img = sorted((route / "query").glob("*.png"))[5]
    original = cv2.imread(str(img), cv2.IMREAD_UNCHANGED)
    edited = original.copy()
    edited[10:20, 10:20] = 255 - edited[10:20, 10:20]
    t = img.stat().st_mtime_ns

    def put(pixels: np.ndarray) -> None:
        # Uncompressed PNG: the file size depends only on the image size; then the old mtime.
        cv2.imwrite(str(img), pixels, [cv2.IMWRITE_PNG_COMPRESSION, 0])
        os.utime(img, ns=(t, t))

    for mode, expect_rerun in (("stat", False), ("content", True)):
        run = tmp_path / f"run-{mode}"
        cfg = load_config(route / "config.yaml", ["plots=false", f"query.fingerprint={mode}", f"reference.fingerprint={mode}"])
        put(original)
        run_stage(cfg, run, "extract", quiet=True)
        before, size = _mtimes(run)["extract.h5"], img.stat().st_size
        put(edited)
        assert img.stat().st_size == size and img.stat().st_mtime_ns == t
        run_stage(cfg, run, "extract", quiet=True)
        assert (_mtimes(run)["extract.h5"] != before) is expect_rerun, mode


def test_failed_stage_leaves_no_old_side_output_and_keeps_config(route, tmp_path):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_all(cfg, run, quiet=True)
    assert (run / "metrics.json").is_file()
    config_before = (run / "config.yaml").read_text()
    # the file breaks after the config was checked, so the failure comes at evaluate
    cfg_bad = load_config(route / "config.yaml", ["plots=false", "seqslam.ds=5"])
    (route / "ground_truth.csv").write_text("this is not,a ground truth\nfile,at all\n")
    with pytest.raises(ValueError, match="ground_truth.csv:1: header must be"):
        run_all(cfg_bad, run, quiet=True)
    assert not (run / "metrics.json").exists()  # the old figures would not match the new localize
    assert (run / "config.yaml").read_text() == config_before  # config.yaml names the last good run
    log = (run / "log.txt").read_text()
    assert "failed:" in log and "localize: running seqslam" in log


def test_second_run_on_a_locked_run_dir_stops_or_waits(route, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    cfg = load_config(route / "config.yaml", ["plots=false"])
    with lock_run_dir(run):
        with pytest.raises(RunDirError, match=rf"in use by another placeloc run \(pid {os.getpid()}\).*--wait"):
            run_stage(cfg, run, "extract", quiet=True)
    # --wait: the second run says it waits, and the holder lets go only after that line (an
    # event, so the case proves the wait however slow the machine is).
    held, waiting = threading.Event(), threading.Event()
    order: list[str] = []
    saw_waiting: list[bool] = []

    class _Waiting(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("waiting for placeloc pid"):
                saw_waiting.append(True)
                waiting.set()

    def hold() -> None:
        with lock_run_dir(run):
            held.set()
            waiting.wait(HANG_S)
            order.append("released")

    handler = _Waiting()
    placeloc_log = logging.getLogger("placeloc")
    level = placeloc_log.level
    placeloc_log.setLevel(logging.INFO)  # the line is INFO, logged before the run's log file raises the level
    placeloc_log.addHandler(handler)
    try:
        t = threading.Thread(target=hold)
        t.start()
        held.wait(HANG_S)
        run_stage(cfg, run, "extract", quiet=True, wait=True)
        order.append("ran")
    finally:
        waiting.set()
        placeloc_log.removeHandler(handler)
        placeloc_log.setLevel(level)
    t.join()
    assert order == ["released", "ran"] and (run / "extract.h5").is_file()
    assert saw_waiting, "the second run never said it waits"


def test_refuses_image_folder_and_foreign_config_yaml(route, tmp_path):
    cfg = load_config(route / "config.yaml", ["plots=false"])
    with pytest.raises(RunDirError, match="reference image folder"):
        run_stage(cfg, route / "reference", "extract", quiet=True)
    pics = tmp_path / "pics"
    pics.mkdir()
    shutil.copy(next((route / "query").glob("*.png")), pics / "a.png")
    with pytest.raises(RunDirError, match="looks like an image folder"):
        run_stage(cfg, pics, "extract", quiet=True)
    # a run directory from before config.yaml carried its header is still ours
    old = tmp_path / "old"
    run_stage(cfg, old, "extract", quiet=True)
    with h5py.File(old / "extract.h5", "r") as f:
        (old / "config.yaml").write_text(str(f.attrs["config_yaml"]))
    run_stage(cfg, old, "extract", quiet=True)
    assert (old / "config.yaml").read_text().startswith("# placeloc run config")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.yaml").write_text("my: own notes\n")
    with pytest.raises(RunDirError, match="not written by placeloc; refusing to overwrite"):
        run_stage(cfg, mine, "extract", quiet=True)
    assert (mine / "config.yaml").read_text() == "my: own notes\n"


def test_log_txt_and_stale_text_temp_files(route, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    stale = run / ".metrics.json.tmp-999999999"
    stale.write_text("{half")
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_all(cfg, run, quiet=True)
    run_all(cfg, run, quiet=True)
    assert not stale.exists()
    log = (run / "log.txt").read_text().splitlines()
    assert sum("run: seqslam up to evaluate" in ln for ln in log) == 2
    assert any("evaluate: up to date" in ln for ln in log)
    assert (run / "config.yaml").read_text().startswith("# placeloc run config")


# ----------------------------------------------------------------- 4. bounded memory and time

def test_yaml_alias_bomb_is_refused_fast(tmp_path):
    bomb = ["method: seqslam", "reference: {images: .}", 'a: &a ["x","x","x","x","x","x","x","x","x"]']
    for i in range(1, 9):
        bomb.append(f"{chr(97 + i)}: &{chr(97 + i)} [" + ",".join([f"*{chr(96 + i)}"] * 9) + "]")
    bomb.append("seqslam: {comparison: *i}")
    path = tmp_path / "bomb.yaml"
    path.write_text("\n".join(bomb) + "\n")
    # refused at the first alias, before anything expands (the message says so): no timing needed
    with pytest.raises(ConfigError, match="found alias \\*a: aliases are not allowed"):
        load_config(path)


def _png_header(path: Path, width: int, height: int) -> None:
    """A PNG whose header says width x height (the pixel data is not needed for the check)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk)))


def test_huge_frame_is_refused_from_its_header(tmp_path, monkeypatch):
    import placeloc.core.imagework as imagework

    monkeypatch.setenv("PLACELOC_MEMORY_LIMIT_MB", "4096")
    monkeypatch.setattr(imagework, "usable_cores", lambda: 1)  # one image described at a time
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(3):
        _png_header(frames / f"f{i}.png", 640, 480)
    _png_header(frames / "f3.png", 8000, 8000)
    assert image_size(frames / "f3.png") == (8000, 8000)
    images = {"reference": ImageSet(str(frames), sorted(frames.iterdir()))}
    # the files hold headers only: the size can only have come from the header, never a decode
    with pytest.raises(ResourceError, match=r"f3.png \(64.0 megapixels\).*needs about 14.3 GiB of memory, "
                       r"more than PLACELOC_MEMORY_LIMIT_MB=4096 allows \(4.0 GiB\)"):
        check_resources({"method": "pirf", "executor": {"workers": 1}}, images, tmp_path, STAGES)
    # on 4 cores the engine describes 4 images at once, and the estimate says so
    monkeypatch.setattr(imagework, "usable_cores", lambda: 4)
    with pytest.raises(ResourceError, match=r"x 4 at once \(1 worker\(s\) x 4 thread\(s\)\) needs about 57.2 GiB"):
        check_resources({"method": "pirf", "executor": {"workers": 1}}, images, tmp_path, STAGES)
    # stages after extract decode no image (PIRF's geometric check of loop closures aside,
    # which reads the frames again in build-dictionary): their estimate reads no image header
    later = check_resources({"method": "pirf", "executor": {"workers": 1}, "pirf": {"verify_frames": 0}}, images,
                            tmp_path, STAGES[1:])
    assert not any("megapixels" in n.what for n in later)
    with pytest.raises(ResourceError, match=r"geometric check .*f3.png \(64.0 megapixels\)"):
        check_resources({"method": "pirf", "executor": {"workers": 1}}, images, tmp_path, STAGES[1:])


def test_jpeg_header_size():
    import cv2

    path = Path(os.environ.get("TMPDIR", "/tmp")) / f"placeloc-test-{os.getpid()}.jpg"
    cv2.imwrite(str(path), np.zeros((37, 53, 3), np.uint8))
    try:
        assert image_size(path) == (53, 37)
    finally:
        path.unlink()


def test_umap_grid_step_and_seqslam_thumbnail_are_refused_before_work(route, tmp_path, monkeypatch):
    monkeypatch.setenv("PLACELOC_MEMORY_LIMIT_MB", "8192")
    cfg = load_config(route / "config.yaml", ["seqslam.thumbnail=[20000, 20000]"])
    with pytest.raises(ResourceError, match=r"SeqSLAM thumbnails 20000x20000 .* needs about \d+\.\d GiB .*seqslam.thumbnail"):
        check_resources(cfg, image_sets(cfg), tmp_path, STAGES)
    umap = {"method": "umap", "executor": {"workers": 1},
            "umap": {"camera": {"width": 160, "height": 120},
                     "grid": {"x": [0.0, 90.0, 1e-5], "y": [-1.5, 4.0, 0.2], "headings": [45, 135, 225, 315]}}}
    with pytest.raises(ResourceError, match=r"UMap database of 1,008,000,112 views of 160x120 .* needs about [0-9.]+ [GT]iB .*umap.grid"):
        check_resources(umap, {}, tmp_path, STAGES)
    # the run itself stops before extract, with rc 2 and one line
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "--set", "seqslam.thumbnail=[20000,20000]"],
               PLACELOC_MEMORY_LIMIT_MB="8192")
    assert res.exit_code == 2 and "seqslam.thumbnail" in _err(res) and not (tmp_path / "r" / "extract.h5").exists()


# ----------------------------------------------------------------- 5. one error boundary

@pytest.mark.parametrize("args,expect", [
    (["experiment", "foo"], "unknown experiment 'foo'; choose one of"),
    (["run", "configs/demo.yaml", "--set", "seqslam.ds=[1"], "--set 'seqslam.ds=[1': the value is not valid YAML"),
    (["run", "configs"], "config file configs is a folder"),
    (["inspect", "configs"], "configs is a folder, not an artifact"),
    (["inspect", "configs/demo.yaml"], "configs/demo.yaml is not an HDF5 file"),
])
def test_user_errors_are_one_line_rc2(args, expect, monkeypatch):
    monkeypatch.chdir(ROOT)
    res = _cli(args)
    assert res.exit_code == 2, res.output
    lines = [ln for ln in _err(res).splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and expect in lines[0], lines


def test_compare_on_another_method(route, tmp_path):
    cfg = tmp_path / "pirf.yaml"
    cfg.write_text(f"method: pirf\nreference: {{images: {route / 'reference'}}}\nquery: {{images: {route / 'query'}}}\n")
    res = _cli(["compare", str(cfg), "--run-dir", str(tmp_path / "c")])
    assert res.exit_code == 2 and "compare runs SeqSLAM image comparisons, but this config's method is 'pirf'" in _err(res)


def test_latin1_config_and_unreachable_scheduler(route, tmp_path):
    cfg = tmp_path / "latin1.yaml"
    cfg.write_bytes("method: seqslam\n# caf\xe9\n".encode("latin-1"))
    res = _cli(["run", str(cfg)])
    assert res.exit_code == 2 and "not UTF-8 text (byte 0xe9 at offset 21); save it as UTF-8" in _err(res)
    pytest.importorskip("distributed")
    # placeloc's own check answered (its message), not Dask's 300 s connect timeout
    res = _cli(["extract", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q",
                "--set", "executor.kind=dask", "--set", "executor.scheduler=tcp://127.0.0.1:9"])
    assert res.exit_code == 2 and "cannot reach a Dask scheduler at tcp://127.0.0.1:9" in _err(res)


def test_bug_shows_traceback_and_ctrl_c_is_one_line(route, tmp_path, monkeypatch):
    import placeloc.core.runner

    def boom(*a, **k):
        raise TypeError("an internal mistake")

    monkeypatch.setattr(placeloc.core.runner, "run_stage", boom)
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r")])
    out = _err(res)
    assert res.exit_code == 1 and "Traceback" in out and "TypeError: an internal mistake" in out
    assert "this is a bug in placeloc" in out.splitlines()[-1]

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(placeloc.core.runner, "run_stage", interrupted)
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r")])
    assert res.exit_code == 130 and _err(res).strip() == "interrupted; rerun to resume"


def test_error_classes_are_user_errors():
    import cv2

    from placeloc.cli import classify
    from placeloc.coembed.solver import CoembedError
    from placeloc.core.executor import WorkItemError
    from placeloc.evaluation.ground_truth import GroundTruthError
    from placeloc.evaluation.poses import PoseError

    for exc in (GroundTruthError("x"), PoseError("x"), CoembedError("x"), PermissionError(13, "denied", "f.png"),
                IsADirectoryError(21, "is a dir"), cv2.error("bad"), ResourceError("x"),
                UnicodeDecodeError("utf-8", b"\xe9", 0, 1, "bad"), ImageError("x"),
                WorkItemError("local", len, "item 3", ImageError("bad image"))):
        assert classify(exc) == "user", exc
    for exc in (TypeError("x"), AttributeError("x"), IndexError("x"), WorkItemError("local", len, "item", ZeroDivisionError())):
        assert classify(exc) == "bug", exc
    from placeloc.core.errors import WorkerLostError

    for exc in (MemoryError(), WorkerLostError("x"), WorkItemError("local", len, "item", MemoryError())):
        assert classify(exc) == "environment", exc
    # a raw ValueError from a library or a builtin is not a message for the user: a bug
    try:
        np.zeros(3).reshape(2, 2)
    except ValueError as exc:
        assert classify(exc) == "bug"
    try:
        float("abc")
    except ValueError as exc:
        assert classify(exc) == "bug"


# ----------------------------------------------------------------- 6. parameters that cannot work

@pytest.mark.parametrize("override,expect", [
    ("executor.retries=-1", "executor.retries: -1 is out of range; it must be >= 0"),
    ("executor.workers=0", "executor.workers: 0 is out of range; it must be >= 1"),
    ("ground_truth.tolerance=-2", "ground_truth.tolerance: -2 is out of range"),
    ("ground_truth.radius=0", "ground_truth.radius: 0.0 is out of range; it must be > 0"),
    ("ground_truth.exclude_recent=-1", "ground_truth.exclude_recent: -1 is out of range; it must be >= 0"),
    ("seqslam.v_min=2.0", "seqslam.v_min (2.0) is larger than seqslam.v_max (1.2)"),
    ("reference.images=[1, 2]", "reference.images must be a string or null"),
    ("query.fingerprint=md5", "query.fingerprint: 'md5' is not allowed; choose one of stat, content"),
])
def test_common_ranges_types_and_cross_key_rules(route, override, expect):
    with pytest.raises(ConfigError, match=re_escape(expect)):
        load_config(route / "config.yaml", [override])


@pytest.mark.parametrize("method,override,key", [
    ("pirf", "ef_search=0", "pirf.ef_search"), ("pirf", "n_features=0", "pirf.n_features"),
    ("pirf", "tau=-0.1", "pirf.tau"), ("pirf", "kdtree_trees=0", "pirf.kdtree_trees"), ("pirf", "hnsw_m=0", "pirf.hnsw_m"),
    ("umap", "query_thickness_px=0", "umap.query_thickness_px"),
    ("seqslam", "images_per_task=0", "seqslam.images_per_task"), ("seqslam", "gaussian_sigma=-1", "seqslam.gaussian_sigma"),
    ("seqslam", "ocm_epsilon=-1", "seqslam.ocm_epsilon"),
    ("seqslam", "patch=40", "seqslam.patch (40) is larger than the thumbnail (64x32)"),
])
def test_parameters_that_cannot_work_are_refused(route, method, override, key):
    data = {"method": method, "reference": {"images": str(route / "reference")}, "query": {"images": str(route / "query")}}
    if method == "umap":
        data["umap"] = {"model": str(ROOT / "configs" / "umap_corridor.yaml"), "mode": "umap"}
    with pytest.raises(ConfigError, match=re_escape(key)):
        load_config(data=data, overrides=[f"{method}.{override}"])


def re_escape(text: str) -> str:
    import re

    return re.escape(text)


def test_keys_whose_default_is_none_have_a_declared_type(route):
    from placeloc.core.params import declared_types
    from placeloc.umap.params import UMapParams

    types = declared_types(UMapParams)
    assert types["ca.fallback_step_m"] == (float,) and types["model"] == (str,)
    data = {"method": "umap", "reference": {"images": str(route / "reference")}, "query": {"images": str(route / "query")},
            "umap": {"model": str(ROOT / "configs" / "umap_corridor.yaml"), "mode": "umap"}}
    with pytest.raises(ConfigError, match=r"umap.ca.fallback_step_m must be a number or null, got 'far'"):
        load_config(data=data, overrides=["umap.ca.fallback_step_m=far"])
    with pytest.raises(ConfigError, match=r"umap.sensor_csv must be a string or null, got \[1, 2\]"):
        load_config(data=data, overrides=["umap.sensor_csv=[1, 2]"])
    cfg = load_config(data=data, overrides=["umap.ca.fallback_step_m=2"])
    assert cfg["umap"]["ca"]["fallback_step_m"] == 2.0 and isinstance(cfg["umap"]["ca"]["fallback_step_m"], float)


# ----------------------------------------------------------------- 8. messages that mislead

def test_permission_denied_image_is_not_called_corrupt(route, monkeypatch):
    img = sorted((route / "query").glob("*.png"))[0]
    import os

    real_open = os.open

    def denied(path, *a, **k):  # what open(2) raises on a file without read permission (tests run as root)
        if Path(path) == img:
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *a, **k)

    monkeypatch.setattr(os, "open", denied)  # images are read through os.open
    with pytest.raises(ImageError, match="permission denied; make it readable"):
        read_gray(img)
    garbage = route / "query" / "zz.png"
    garbage.write_bytes(b"not a png")
    monkeypatch.undo()
    with pytest.raises(ImageError, match="corrupt or not an image"):
        read_gray(garbage)


def test_artifact_missing_a_dataset_names_file_dataset_and_fix(route, tmp_path):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_stage(cfg, run, "extract", quiet=True)
    with h5py.File(run / "extract.h5", "a") as f:
        del f["query/features"]
        names = list(f["query"].keys())
    assert names  # the group is still there, one dataset is gone
    res = _cli(["localize", str(route / "config.yaml"), "--run-dir", str(run), "-q", "--set", "plots=false"])
    line = _err(res).strip()
    assert res.exit_code == 2 and str(run / "extract.h5") in line and "--force" in line, line


def test_metrics_json_is_valid_after_run(route, tmp_path):
    run = tmp_path / "run"
    cfg = load_config(route / "config.yaml", ["plots=false"])
    run_all(cfg, run, quiet=True)
    assert json.loads((run / "metrics.json").read_text())["n_queries"] == 81


def test_an_interrupt_swallowed_by_a_finaliser_is_raised_again_silently():
    """Python swallows an exception raised inside a finaliser (printing "Exception ignored");
    a Ctrl-C that lands there must still stop the run, without that text."""
    code = (
        "from placeloc.core import interrupts\n"
        "interrupts.install()\n"
        "class Finalised:\n"
        "    def __del__(self):\n"
        "        interrupts._handler(2, None)  # as if Ctrl-C arrived while the finaliser ran\n"
        "Finalised()\n"
        "print('swallowed, run goes on')\n"
        "try:\n"
        "    interrupts.raise_if_interrupted()\n"
        "except KeyboardInterrupt:\n"
        "    print('raised again')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=HANG_S)
    assert proc.stdout.split("\n")[:2] == ["swallowed, run goes on", "raised again"]
    assert proc.stderr == ""
