"""Hostile inputs, third round, input/output families (writes and reads inside the run,
no code from a place others can write, bounded parsers, read-only commands, and deeply
nested brackets): each case sets up one fault on tiny data and asserts the outcome
docs/reliability.md promises ("Paths", "Caches", "Sizes"). ``make faults`` runs these with
the earlier rounds and prints one table row per case."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import tracemalloc
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from faults_table import record
from faults_table import run_cli as _cli
from faults_table import stderr_of as _err

from placeloc.core.config import ConfigError, load_config
from placeloc.core.safe_io import UnsafeInputError, load_arrays, name_inside, open_h5_input

PLACELOC = [sys.executable, "-m", "placeloc.cli"]


def _placeloc(*args: str, timeout: float = 120, **env: str) -> subprocess.CompletedProcess:
    """``placeloc ARGS`` in a process of its own (a hang is a failure, not a stuck suite),
    its outcome recorded for the table."""
    proc = subprocess.run([*PLACELOC, *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **env})
    record(proc.returncode, proc.stderr)
    return proc


def _one_error_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert "Traceback" not in stderr, stderr
    assert lines and lines[-1].startswith("error: "), stderr
    return lines[-1]


@pytest.fixture
def small_run(route, tmp_path):
    """The bundled route run to the end (plots on), and its config path."""
    from placeloc.core.runner import run_all

    run_all(load_config(route / "config.yaml"), tmp_path / "run", quiet=True)
    return tmp_path / "run", route / "config.yaml"


# ============================================================ 1. writes and reads stay inside

def _zind_two_floors(tmp_path: Path, keys: tuple[str, str]) -> Path:
    """A zind_data.json with two calibrated floors under the given keys (one square room each)."""
    square = [[-1, -1], [1, -1], [1, 1], [-1, 1]]
    pano = {"label": "room", "is_primary": True, "is_inside": True, "is_ceiling_flat": True, "ceiling_height": 2.0,
            "camera_height": 1.0, "floor_number": 1, "image_path": "panos/a.jpg",
            "floor_plan_transformation": {"translation": [4, 2], "rotation": 0, "scale": 3},
            "layout_complete": {"vertices": square, "doors": [], "openings": [], "windows": [], "internal": []}}
    floor = {"complete_room_01": {"partial_room_01": {"pano_01": pano}}}
    data = {"scale_meters_per_coordinate": {k: 0.5 for k in keys}, "merger": {k: floor for k in keys},
            "redraw": {}, "floorplan_to_redraw_transformation": {}}
    path = tmp_path / "zind_data.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("hostile", ["../../../escaped", "/tmp/placeloc-absolute-floor", "..", "a/b", "a\\b"])
def test_zind_floor_key_cannot_name_a_folder_outside_out(tmp_path, hostile):
    if hostile.startswith("/"):
        hostile = str(tmp_path / "absolute-floor")
    src = _zind_two_floors(tmp_path, ("floor_01", hostile))
    out = tmp_path / "deep" / "er" / "out"
    result = _cli(["import", "zind", str(src), str(out)])
    assert result.exit_code == 2, result.output
    assert "floor key" in _err(result).splitlines()[-1]
    written = {p for p in tmp_path.rglob("*") if p.name in ("floor_plan.yaml", "poses.csv")}
    assert written == set(), written  # refused before any floor is written


def test_zind_floor_folder_that_is_a_link_out_is_refused(tmp_path):
    src = _zind_two_floors(tmp_path, ("floor_01", "floor_02"))
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "floor_02").symlink_to(elsewhere)
    result = _cli(["import", "zind", str(src), str(out)])
    assert result.exit_code == 2 and "leads outside" in _err(result)
    assert list(elsewhere.iterdir()) == []


def test_name_inside_accepts_plain_names_only(tmp_path):
    assert name_inside(tmp_path, "floor_01", "key") == tmp_path / "floor_01"
    for bad in ("", ".", "..", "../x", "x/..", "/etc", "a\0b", " x"):
        with pytest.raises(UnsafeInputError):
            name_inside(tmp_path, bad, "key")


@pytest.mark.parametrize("name", [".lock", "log.txt"])
def test_link_at_run_lock_or_log_is_refused_not_followed(small_run, tmp_path, name):
    run, config = small_run
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (run / name).unlink(missing_ok=True)
    (run / name).symlink_to(victim)
    proc = _placeloc("run", str(config), "--run-dir", str(run), "-q")
    assert proc.returncode == 2
    assert "symbolic link" in _one_error_line(proc.stderr) and name in proc.stderr
    assert victim.read_text() == "precious\n"


def test_fifo_at_run_log_does_not_hang_the_run(small_run):
    run, config = small_run
    (run / "log.txt").unlink()
    os.mkfifo(run / "log.txt")
    proc = _placeloc("run", str(config), "--run-dir", str(run), "-q", timeout=60)
    assert proc.returncode == 2 and "FIFO" in _one_error_line(proc.stderr)


def test_show_embeds_no_png_from_outside_the_run(small_run, tmp_path):
    run, _ = small_run
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG\r\n\x1a\n" + b"TOP-SECRET-BYTES" * 10)
    (run / "leak.png").symlink_to(secret)
    (run / "zero.png").symlink_to("/dev/zero")
    os.mkfifo(run / "pipe.png")
    (run / "fake.png").write_bytes(b"not a png at all")
    result = _cli(["show", str(run), "-q"])
    assert result.exit_code == 0, result.output
    import base64

    html = (run / "report.html").read_text()
    assert base64.b64encode(secret.read_bytes())[:40].decode() not in html
    for name in ("leak.png", "zero.png", "pipe.png", "fake.png"):
        assert f"<h3>{name}</h3>" not in html
    assert "<h3>strips_sample.png</h3><img" in html  # placeloc's own pictures are still there


def _gt_matrix(n_ref: int, n_query: int) -> np.ndarray:
    return np.eye(n_ref, n_query, dtype=bool)


@pytest.mark.parametrize("how", ["external_link", "virtual", "external_raw", "link_to_fifo"])
def test_ground_truth_h5_reading_another_file_is_refused(route, tmp_path, how):
    """The dataset's data would come from another file, which no stamp fingerprints."""
    from placeloc.core.runner import image_sets

    cfg0 = load_config(route / "config.yaml")
    sets = image_sets(cfg0)
    n_ref, n_query = len(sets["reference"]), len(sets["query"])
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["gt"] = _gt_matrix(n_ref, n_query)
    gt = tmp_path / "gt.h5"
    with h5py.File(gt, "w") as f:
        if how == "external_link":
            f["gt"] = h5py.ExternalLink(str(other), "gt")
        elif how == "link_to_fifo":
            os.mkfifo(tmp_path / "fifo.h5")
            f["gt"] = h5py.ExternalLink(str(tmp_path / "fifo.h5"), "gt")
        elif how == "virtual":
            layout = h5py.VirtualLayout(shape=(n_ref, n_query), dtype=bool)
            layout[:] = h5py.VirtualSource(str(other), "gt", shape=(n_ref, n_query))
            f.create_virtual_dataset("gt", layout)
        else:
            raw = tmp_path / "raw.bin"
            _gt_matrix(n_ref, n_query).astype(np.uint8).tofile(raw)
            f.create_dataset("gt", shape=(n_ref, n_query), dtype=np.uint8, external=[(str(raw), 0, n_ref * n_query)])
    proc = _placeloc("run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "run"), "-q",
                     "--set", "ground_truth.kind=hdf5", "--set", f"ground_truth.path={gt}", timeout=120)
    assert proc.returncode == 2, proc.stderr
    line = _one_error_line(proc.stderr)
    assert "gt.h5" in line and ("external" in line or "virtual" in line), line


def test_h5_opener_accepts_plain_and_soft_linked_data(tmp_path):
    path = tmp_path / "ok.h5"
    with h5py.File(path, "w") as f:
        f["group/gt"] = np.ones((3, 3))
        f["alias"] = h5py.SoftLink("/group/gt")
    with open_h5_input(path, "test") as f:
        assert f["alias"][()].sum() == 9


# ============================================================ 2. no code from a place others can write

def _reference_l1(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a[:, None, :].astype(np.int32) - b[None, :, :].astype(np.int32)).mean(axis=2).astype(np.float32)


def _kernel_in_fresh_process(cache_home: Path, umask: int | None = None) -> subprocess.CompletedProcess:
    """Compute a difference block with the uint8 kernel in a new process (the kernel is
    loaded once per process) and compare it with NumPy; prints OK or the mismatch."""
    code = (
        "import os, sys, numpy as np\n"
        + (f"os.umask({umask})\n" if umask is not None else "")
        + "from placeloc.seqslam import l1\n"
        "rng = np.random.default_rng(0)\n"
        "a = rng.integers(0, 256, (50, 64), dtype=np.uint8); b = rng.integers(0, 256, (70, 64), dtype=np.uint8)\n"
        "out = np.zeros((50, 70), np.float32)\n"
        "l1.l1_uint8(a, b, out)\n"
        "ref = np.abs(a[:, None, :].astype(np.int32) - b[None, :, :].astype(np.int32)).mean(axis=2)\n"
        "print('OK' if np.allclose(out, ref) else 'WRONG')\n")
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "XDG_CACHE_HOME": str(cache_home)})


def test_kernel_cache_is_private_under_umask_000(tmp_path):
    proc = _kernel_in_fresh_process(tmp_path, umask=0)
    assert proc.stdout.strip() == "OK", proc.stderr
    folder = tmp_path / "placeloc" / "kernels"
    assert (tmp_path / "placeloc").stat().st_mode & 0o777 == 0o700
    assert folder.stat().st_mode & 0o777 == 0o700
    files = list(folder.iterdir())
    assert files and all(p.stat().st_mode & 0o777 == 0o600 for p in files)


def test_planted_kernel_with_a_valid_embedded_checksum_is_not_loaded(tmp_path):
    """The old cache trusted sha256(data) stored in the file itself: anyone who can write
    the file can make that hold. A planted object now fails the keyed digest and is
    recompiled (the result is right), and is replaced by the real one."""
    import hashlib

    assert _kernel_in_fresh_process(tmp_path).stdout.strip() == "OK"
    folder = tmp_path / "placeloc" / "kernels"
    planted = b"\x7fELF" + b"\x00" * 500  # no valid object: loading it would crash or misbehave
    for obj in folder.glob("*.o"):
        obj.write_bytes(hashlib.sha256(planted).digest() + planted)
    proc = _kernel_in_fresh_process(tmp_path)
    assert proc.stdout.strip() == "OK", proc.stderr
    for obj in folder.glob("*.o"):
        assert planted not in obj.read_bytes()


@pytest.mark.parametrize("fault", ["group_writable_folder", "foreign_owner", "linked_folder"])
def test_kernel_cache_others_can_write_is_not_used(tmp_path, fault):
    if fault == "foreign_owner" and os.geteuid() != 0:
        pytest.skip("needs root to give the folder to another user")
    assert _kernel_in_fresh_process(tmp_path).stdout.strip() == "OK"
    folder = tmp_path / "placeloc" / "kernels"
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    if fault == "group_writable_folder":
        folder.chmod(0o777)
    elif fault == "foreign_owner":
        os.chown(folder, 12345, 12345)
    else:
        real = tmp_path / "elsewhere"
        shutil.move(str(folder), real)
        folder.symlink_to(real)
    proc = _kernel_in_fresh_process(tmp_path)
    assert proc.stdout.strip() == "OK", proc.stderr
    assert "not used" in proc.stderr and "kernels" in proc.stderr
    if fault != "linked_folder":
        assert {p.name: p.read_bytes() for p in folder.iterdir()} == before  # nothing written there either


@pytest.mark.parametrize("state", ["fresh", "group_writable"])
def test_numba_cache_is_pointed_at_a_private_folder(tmp_path, state):
    """numba loads cached machine code and pickled indexes unchecked: `import placeloc` points
    NUMBA_CACHE_DIR at a private folder (not __pycache__ beside the sources), and never at
    one others can write."""
    if state == "group_writable":
        (tmp_path / "placeloc" / "numba").mkdir(parents=True)
        (tmp_path / "placeloc" / "numba").chmod(0o777)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    code = ("import os, placeloc; d = os.environ['NUMBA_CACHE_DIR']; st = os.stat(d); "
            "print(d, st.st_mode & 0o777, st.st_uid == os.geteuid())")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          env={**env, "XDG_CACHE_HOME": str(tmp_path)})
    folder, mode, mine = proc.stdout.split()
    assert int(mode) & 0o077 == 0 and mine == "True", proc.stdout  # private while the process runs
    if state == "fresh":
        assert Path(folder) == tmp_path / "placeloc" / "numba"
    else:
        assert Path(folder) != tmp_path / "placeloc" / "numba" and "not used" in proc.stderr
        assert not Path(folder).exists()  # the temporary folder went with the process


# ============================================================ 3. every parser bounded before it allocates

BILLION_LAUGHS = "a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n" \
                 "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n"


def test_sweep_refuses_alias_config(route, tmp_path):
    bad = tmp_path / "sweep.yaml"
    bad.write_text((route / "config.yaml").read_text() + BILLION_LAUGHS.replace("a:", "laughs_a:", 1))
    proc = _placeloc("sweep", str(bad), "--grid", "seqslam.ds=10,20", "-o", str(tmp_path / "sw"), timeout=60)
    assert proc.returncode == 2 and "alias" in _one_error_line(proc.stderr)


@pytest.mark.parametrize("where", ["sweep_file", "grid"])
def test_hundred_thousand_deep_bracket_is_one_line(route, tmp_path, where):
    deep = "[" * 100_000
    config = route / "config.yaml"
    grid = "seqslam.ds=10"
    if where == "sweep_file":
        config = tmp_path / "deep.yaml"
        config.write_text("method: seqslam\nx: " + deep + "\n")
    else:
        grid = "seqslam.ds=" + deep
    proc = _placeloc("sweep", str(config), "--grid", grid, "-o", str(tmp_path / "sw"), timeout=60)
    assert proc.returncode == 2
    assert "nested" in _one_error_line(proc.stderr)


def test_config_yaml_attribute_with_aliases_does_not_hang_show(small_run):
    """`show` reads the config stamped in the run's artifacts through the same bounded loader."""
    run, _ = small_run
    from placeloc.evaluation.report import run_config

    with h5py.File(run / "evaluate.h5", "r+") as f:
        f.attrs["config_yaml"] = BILLION_LAUGHS + "d2: [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n" * 20
    cfg = run_config(run)  # evaluate's stamp is no longer a config: the chain ends at localize
    assert cfg["method"] == "seqslam"
    result = _cli(["show", str(run), "-q"])
    assert result.exit_code == 0, result.output


def _npz_with_header_shape(path: Path, shape: tuple[int, int]) -> None:
    """An .npz whose member's .npy header claims ``shape`` of bool, the data deflated zeros:
    what a few hundred KB can claim."""
    header = np.lib.format.header_data_from_array_1_0(np.zeros((1, 1), bool))
    header["shape"] = shape
    import io
    import zipfile

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("gt.npy", buf.getvalue() + b"\0" * 4096)  # the data the header promises is never reached


def test_huge_npz_ground_truth_is_refused_from_its_header(tmp_path):
    """30000 x 30000 (900 MB of bool) in a ~900 KB file: refused before the array is read."""
    from placeloc.evaluation.ground_truth import GroundTruth, GroundTruthError

    path = tmp_path / "gt.npz"
    _npz_with_header_shape(path, (30000, 30000))
    assert path.stat().st_size < 2 << 20
    tracemalloc.start()
    try:
        with pytest.raises(GroundTruthError, match="30000 x 30000"):
            GroundTruth.from_config({"kind": "hdf5", "path": str(path)}, n_ref=100, n_query=100)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50 << 20, peak


def test_npy_loop_matrix_bounded_by_frames(tmp_path):
    path = tmp_path / "m.npy"
    np.save(path, np.zeros((300, 300), bool))
    with pytest.raises(UnsafeInputError, match="300 x 300"):
        load_arrays(path, "ground_truth.path", max_bytes=100 * 100 * 8)
    assert load_arrays(path, "ground_truth.path", max_bytes=300 * 300)["array"].shape == (300, 300)


@pytest.mark.parametrize("kind", ["csv", "hdf5", "poses"])
def test_ground_truth_path_dev_zero_is_refused_at_once(route, tmp_path, kind):
    proc = _placeloc("run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "run"), "-q",
                     "--set", f"ground_truth.kind={kind}", "--set", "ground_truth.path=/dev/zero", timeout=120)
    assert proc.returncode == 2
    assert "/dev/zero" in _one_error_line(proc.stderr) and "character device" in proc.stderr


def test_config_file_dev_zero_and_fifo_are_refused(tmp_path):
    os.mkfifo(tmp_path / "fifo.yaml")
    for path in ("/dev/zero", str(tmp_path / "fifo.yaml")):
        proc = _placeloc("run", path, "--run-dir", str(tmp_path / "run"), timeout=30)
        assert proc.returncode == 2 and "not a regular file" in _one_error_line(proc.stderr)


def _tiff_header(width: int, height: int) -> bytes:
    """A deflate TIFF's header claiming width x height 8-bit grey, with a tiny strip (the
    pixels are never reached: the size is refused first)."""
    strip = zlib.compress(b"\0" * 64)
    entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 8), (262, 3, 1, 1),
               (273, 4, 1, 0), (277, 3, 1, 1), (278, 4, 1, height), (279, 4, 1, len(strip))]
    ifd_size = 2 + 12 * len(entries) + 4
    data_at = 8 + ifd_size
    entries[5] = (273, 4, 1, data_at)
    out = b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        out += struct.pack("<HHII", tag, typ, count, value) if typ == 4 else struct.pack("<HHIHH", tag, typ, count, value, 0)
    return out + struct.pack("<I", 0) + strip


def test_huge_tiff_is_sized_from_its_header_and_refused_before_decoding(route, tmp_path, monkeypatch):
    from placeloc.core.images import ImageError, decode_image, image_size

    big = tmp_path / "big.tif"
    big.write_bytes(_tiff_header(30000, 30000))
    assert image_size(big) == (30000, 30000)
    monkeypatch.setenv("PLACELOC_MEMORY_LIMIT_MB", "2048")
    with pytest.raises(ImageError, match="30000 x 30000"):
        decode_image(big)
    frames = tmp_path / "frames"
    shutil.copytree(route / "reference", frames)
    shutil.copy(big, frames / "zzz_big.tif")
    proc = _placeloc("run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "run"), "-q",
                     "--set", f"reference.images={frames}", PLACELOC_MEMORY_LIMIT_MB="2048")
    assert proc.returncode == 2 and "900.0 megapixels" in _one_error_line(proc.stderr)


@pytest.mark.parametrize("fmt", ["TIFF", "WEBP", "GIF"])
def test_header_size_of_pillow_formats(tmp_path, fmt):
    from PIL import Image

    from placeloc.core.images import image_size

    path = tmp_path / f"x.{fmt.lower()}"
    Image.fromarray(np.zeros((37, 53, 3), np.uint8)).save(path, fmt)
    assert image_size(path) == (53, 37)


def _png_header(width: int, height: int) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))


def test_strip_drawing_holds_one_decoded_image_not_float_copies(tmp_path):
    """Strips of 4000 x 4000 frames: each panel is shrunk right after its decode, so drawing
    holds about one decoded frame (48 MB as RGB; what extract's estimate already admitted),
    not matplotlib's float copies of every panel (~0.5 GB each at this size)."""
    import cv2

    from placeloc.evaluation.show import Row, draw_strip_figure

    y, x = np.mgrid[0:4000, 0:4000]
    frame = np.stack([x % 256, y % 256, (x + y) % 256], axis=-1).astype(np.uint8)
    names = {}
    for name in ("q.png", "r.png", "t.png"):
        cv2.imwrite(str(tmp_path / name), frame)
        names[name] = tmp_path / name
    del frame, x, y
    rows = [Row("q.png", "r.png", 0.9, False, "t.png")] * 2
    tracemalloc.start()
    try:
        out = draw_strip_figure(rows, [0, 1], names, names, tmp_path / "strips.png", "big frames")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert out is not None and out.stat().st_size > 1000
    assert peak < 200 << 20, f"{peak / 2**20:.0f} MB"


def test_strip_panels_are_shrunk_before_drawing():
    from placeloc.evaluation.show import PANEL_PIXELS, shrink

    img = np.zeros((1000, 2000, 3), np.uint8)
    img[:, 1000:] = 200
    small = shrink(img)
    assert small.shape == (PANEL_PIXELS // 2, PANEL_PIXELS, 3)
    assert small[:, : PANEL_PIXELS // 2 - 1].max() == 0 and small[:, PANEL_PIXELS // 2 + 1:].min() == 200
    assert shrink(np.zeros((40, 60, 3), np.uint8)).shape == (40, 60, 3)


def test_floor_plan_yaml_with_aliases_is_refused(tmp_path):
    from placeloc.core.errors import ModelError
    from placeloc.geometry.floorplan import load_model

    plan = tmp_path / "plan.yaml"
    plan.write_text(BILLION_LAUGHS)
    with pytest.raises(ModelError, match="alias"):
        load_model(plan)


def test_oversized_or_deep_set_values_are_config_errors(route):
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(route / "config.yaml", ["seqslam.ds=" + "[" * 5000])


# ============================================================ 6. read-only commands are read-only

def test_show_with_other_counts_then_run_does_not_rerun_evaluate(small_run):
    run, config = small_run
    from placeloc.core.runner import side_outputs_intact

    before = (run / "evaluate.h5").stat().st_mtime_ns
    result = _cli(["show", str(run), "--sample", "3", "-q"])
    assert result.exit_code == 0, result.output
    assert side_outputs_intact(run / "evaluate.h5")
    assert (run / "show" / "strips_sample.png").is_file() and (run / "show" / "report.html").is_file()
    assert "run/show/strips_sample.png" in result.output.replace(os.sep, "/")
    proc = _placeloc("run", str(config), "--run-dir", str(run))
    assert proc.returncode == 0, proc.stderr
    assert "evaluate: up to date" in proc.stderr
    assert (run / "evaluate.h5").stat().st_mtime_ns == before


def test_show_takes_the_config_from_the_stamps_not_the_newest_file(small_run):
    """Re-run localize with other settings (evaluate.h5 is left from the old run), then touch
    the old evaluate.h5: the report must list the new settings."""
    run, config = small_run
    from placeloc.core.runner import run_stage
    from placeloc.evaluation.report import run_config, stamped_configs

    old = run_config(run)["seqslam"]["ds"]
    new = old + 3
    run_stage(load_config(config, [f"seqslam.ds={new}"]), run, "localize", quiet=True)
    later = (run / "localize.h5").stat().st_mtime_ns + 10**9
    os.utime(run / "evaluate.h5", ns=(later, later))
    assert [s for s, _, _ in stamped_configs(run)] == ["extract", "build-dictionary", "index", "localize"]
    assert run_config(run)["seqslam"]["ds"] == new
    result = _cli(["show", str(run), "-q"])
    assert result.exit_code == 0, result.output
    html = (run / "report.html").read_text()
    assert f"<td>ds</td><td class='num'>{new}</td>" in html
    assert "No metrics.json" in html  # the old evaluate's metrics describe the old settings: left out


@pytest.mark.parametrize("what", ["fifo", "dev_zero_link"])
def test_image_that_is_a_fifo_or_device_is_refused_not_read(tmp_path, what):
    from placeloc.core.images import ImageError, read_gray

    path = tmp_path / "frame.png"
    if what == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/zero")
    with pytest.raises(ImageError, match="not a regular file"):
        read_gray(path)


def test_show_reads_per_query_csv_through_the_run_folder_guard(small_run, tmp_path):
    """A per_query.csv that is a link to a file outside the run is not read as the run's."""
    run, _ = small_run
    outside = tmp_path / "outside.csv"
    shutil.move(str(run / "per_query.csv"), outside)
    (run / "per_query.csv").symlink_to(outside)
    result = _cli(["show", str(run), "-q"])
    assert result.exit_code == 2 and "symbolic link" in _err(result).splitlines()[-1]


@pytest.mark.parametrize("writer", ["text", "hdf5"])
def test_link_planted_at_the_temporary_name_is_not_written_through(tmp_path, writer):
    """The temporary name of an atomic write is predictable (.NAME.tmp-PID): a link planted
    there is replaced, the target keeps its bytes, the file appears where it belongs."""
    from placeloc.core.artifacts import atomic_h5, atomic_open, tmp_path_for

    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    target = tmp_path / ("metrics.json" if writer == "text" else "extract.h5")
    tmp_path_for(target).symlink_to(victim)
    if writer == "text":
        with atomic_open(target) as fh:
            fh.write('{"recall_at_1": 1.0}')
        assert json.loads(target.read_text()) == {"recall_at_1": 1.0}
    else:
        with atomic_h5(target, attrs={"stamp": "s"}) as f:
            f["x"] = np.arange(3)
        with h5py.File(target, "r") as f:
            assert f["x"][()].tolist() == [0, 1, 2]
    assert victim.read_text() == "precious\n" and not target.is_symlink()


def test_run_config_yaml_linked_to_dev_zero_is_refused_at_once(small_run):
    run, config = small_run
    (run / "config.yaml").unlink()
    (run / "config.yaml").symlink_to("/dev/zero")
    proc = _placeloc("run", str(config), "--run-dir", str(run), "-q", timeout=60)
    assert proc.returncode == 2 and "symbolic link" in _one_error_line(proc.stderr)


def test_inspect_names_foreign_storage_and_refuses_a_fifo(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.eye(2)
    linked = tmp_path / "linked.h5"
    with h5py.File(linked, "w") as f:
        f["gt"] = h5py.ExternalLink(str(other), "x")
    result = _cli(["inspect", str(linked)])
    assert result.exit_code == 0 and "/gt is an external link to" in result.output
    os.mkfifo(tmp_path / "pipe.h5")
    proc = _placeloc("inspect", str(tmp_path / "pipe.h5"), timeout=30)
    assert proc.returncode == 2 and "FIFO" in _one_error_line(proc.stderr)


@pytest.mark.parametrize("where", ["zind", "model"])
def test_deeply_nested_json_is_one_line(tmp_path, where):
    path = tmp_path / ("zind_data.json" if where == "zind" else "wire.json")
    path.write_text("[" * 100_000)
    if where == "zind":
        proc = _placeloc("import", "zind", str(path), str(tmp_path / "out"), timeout=60)
        assert proc.returncode == 2 and "nested too deeply" in _one_error_line(proc.stderr)
    else:
        from placeloc.core.errors import ModelError
        from placeloc.geometry.floorplan import load_model

        with pytest.raises(ModelError, match="nested too deeply"):
            load_model(path)


@pytest.mark.parametrize("plant", ["link", "external_link"])
def test_planted_artifact_is_never_up_to_date(small_run, tmp_path, plant):
    """localize.h5 replaced by a link to a copy elsewhere, or given a dataset that is an
    external link: the stage re-runs and writes a plain artifact in place."""
    run, config = small_run
    from placeloc.core.artifacts import read_stamp

    stamp = read_stamp(run / "localize.h5")
    if plant == "link":
        copy = tmp_path / "elsewhere.h5"
        shutil.move(str(run / "localize.h5"), copy)
        (run / "localize.h5").symlink_to(copy)
    else:
        other = tmp_path / "other.h5"
        with h5py.File(other, "w") as f:
            f["x"] = np.zeros(3)
        with h5py.File(run / "localize.h5", "r+") as f:
            f["planted"] = h5py.ExternalLink(str(other), "x")
    assert read_stamp(run / "localize.h5") is None
    proc = _placeloc("run", str(config), "--run-dir", str(run))
    assert proc.returncode == 0, proc.stderr
    assert "localize: running" in proc.stderr
    assert not (run / "localize.h5").is_symlink() and read_stamp(run / "localize.h5") == stamp


def test_mat_matrix_is_checked_from_its_header(tmp_path):
    """MATLAB v5 files: scipy.io.whosmat's shapes are checked before loadmat reads them."""
    from scipy.io import savemat

    path = tmp_path / "gt.mat"
    savemat(path, {"GT": np.zeros((300, 300))})
    with pytest.raises(UnsafeInputError, match="300 x 300 float64"):
        load_arrays(path, "ground_truth.path", max_bytes=100 * 100 * 8)
    assert load_arrays(path, "ground_truth.path", max_bytes=300 * 300 * 8)["GT"].shape == (300, 300)


def test_show_waits_for_a_run_in_progress(small_run):
    """show reads what a running stage is replacing: it waits for the run's lock (an event:
    its "waiting for placeloc pid" line), then draws."""
    import select

    from placeloc.core.runner import lock_run_dir

    run, _ = small_run
    (run / "report.html").unlink()
    with lock_run_dir(run):
        proc = subprocess.Popen([*PLACELOC, "show", str(run)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            line = ""
            while "waiting for placeloc pid" not in line:
                ready, _, _ = select.select([proc.stderr], [], [], 120)
                assert ready, "show neither waited nor finished within 120 s"
                line = proc.stderr.readline()
                assert line or proc.poll() is None, "show finished while the run held the lock"
            assert not (run / "report.html").exists()
        except BaseException:
            proc.kill()
            raise
    out, err = proc.communicate(timeout=120)
    record(proc.returncode, err)
    assert proc.returncode == 0, err
    assert (run / "report.html").is_file()


@pytest.mark.parametrize("value", ["1" * 5000, "!!timestamp 9999999-01-01"])
def test_yaml_value_a_safe_tag_cannot_build_is_one_line(route, tmp_path, value):
    """A 5000-digit integer (past Python's int-string limit) or a malformed timestamp: the
    one loader words it, in a file and in --set alike."""
    config = tmp_path / "c.yaml"
    config.write_text(f"method: seqslam\nseqslam:\n  ds: {value}\n")
    for args in (["run", str(config)], ["run", str(route / "config.yaml"), "--set", f"seqslam.ds={value}"]):
        result = _cli([*args, "--run-dir", str(tmp_path / "run")])
        assert result.exit_code == 2, result.output
        assert "a value cannot be read" in _err(result).splitlines()[-1]


@pytest.mark.parametrize("content", ["[" * 100_000, "[1, 2]"])
def test_damaged_metrics_json_is_one_line_in_show(small_run, content):
    run, _ = small_run
    (run / "metrics.json").write_text(content)
    result = _cli(["show", str(run), "-q"])
    assert result.exit_code == 2, result.output
    assert "metrics.json" in _err(result).splitlines()[-1]


@pytest.mark.parametrize("code", ["ENOLCK", "EOPNOTSUPP"])
def test_a_run_folder_on_a_file_system_without_locks_runs_with_a_warning(route, tmp_path, monkeypatch, code):
    """Older NFS without lockd, SMB mounts and sshfs have no file locks: flock fails with
    ENOLCK or EOPNOTSUPP. The run used to stop with "error: [Errno 37] No locks available",
    naming neither the folder nor a way out; it now runs, and says what is unguarded. Any
    other failure of the lock is still an error."""
    import errno

    import placeloc.core.runner as runner

    def no_locks(fd, op):
        raise OSError(getattr(errno, code), os.strerror(getattr(errno, code)))

    monkeypatch.setattr(runner.fcntl, "flock", no_locks)
    run = tmp_path / "run"
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(run), "-q", "--set", "plots=false"])
    assert res.exit_code == 0, res.output
    assert f"{run}: its file system has no file locks (" in _err(res)  # shown with -q too
    monkeypatch.undo()
    locked = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "locked"), "-q", "--set", "plots=false"])
    assert locked.exit_code == 0, locked.output
    recall = [json.loads((d / "metrics.json").read_text())["recall_at_1"] for d in (run, tmp_path / "locked")]
    assert recall[0] == recall[1]  # the same run, the lock aside
    assert "no file locks" not in _err(locked)

    def broken(fd, op):
        raise OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(runner.fcntl, "flock", broken)
    with pytest.raises(OSError, match="Input/output error"):
        with runner.lock_run_dir(tmp_path / "run"):
            pass


def test_an_artifact_that_cannot_be_used_is_named_with_why_before_its_stage_runs_again(route, tmp_path, caplog):
    """extract.h5 cut to its first 3000 bytes (a copy that stopped), index.h5 replaced by
    text and localize.h5 by a link: each stage runs again, and the log first says which file
    and why, in words (the byte counts of the truncated file from its own superblock); a
    missing artifact needs no such line. ``placeloc inspect`` says the same of the cut file."""
    import logging

    from placeloc.core.artifacts import unusable_reason
    from placeloc.core.runner import run_stage

    cfg = load_config(route / "config.yaml", ["plots=false"])
    run = tmp_path / "run"
    run_stage(cfg, run, "localize", quiet=True)
    whole = (run / "extract.h5").stat().st_size
    (run / "cut.h5").write_bytes((run / "extract.h5").read_bytes()[:3000])
    shutil.copy(run / "cut.h5", run / "extract.h5")
    (run / "index.h5").write_text("not hdf5\n")
    (run / "elsewhere.h5").write_bytes((run / "localize.h5").read_bytes())
    (run / "localize.h5").unlink()
    (run / "localize.h5").symlink_to(run / "elsewhere.h5")
    assert unusable_reason(run / "missing.h5") is None
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_stage(cfg, run, "localize", quiet=True)
    said = [r.getMessage() for r in caplog.records if "cannot be used" in r.getMessage()]
    assert said == [
        f"extract: {run / 'extract.h5'} cannot be used: truncated, 3,000 of its {whole:,} bytes (a copy that did not "
        "finish, or a full disk); the stage runs again",
        f"index: {run / 'index.h5'} cannot be used: not a readable HDF5 file: file signature not found; the stage runs again",
        f"localize: {run / 'localize.h5'} cannot be used: a symbolic link, which placeloc never writes; the stage runs again"]
    assert (run / "extract.h5").stat().st_size == whole and not (run / "localize.h5").is_symlink()
    res = _cli(["inspect", str(run / "cut.h5")])
    assert _one_error_line(_err(res)) == (
        f"error: {run / 'cut.h5'}: cannot be read as a placeloc artifact: truncated, 3,000 of its {whole:,} bytes (a copy "
        "that did not finish, or a full disk); run its stage again (placeloc STAGE CONFIG -o RUN_DIR -f)")
