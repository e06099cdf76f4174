"""Hostile inputs, third round (numbers, shapes, skipped files, failures, the terminal): each
case sets up one fault on tiny data and asserts the clean outcome docs/reliability.md
promises. ``make faults`` runs these with the earlier rounds and prints one row per case."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from faults_table import HANG_S, record
from faults_table import run_cli as _cli
from faults_table import stderr_of as _err

from placeloc.core.config import ConfigError, load_config
from placeloc.core.errors import ModelError

ROOT = Path(__file__).resolve().parent.parent
PLACELOC = [sys.executable, "-m", "placeloc.cli"]


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def _one_line(res, rc: int = 2) -> str:
    """The command failed with ``rc`` and said one line, no traceback; that line."""
    lines = _lines(_err(res))
    assert res.exit_code == rc and len(lines) == 1 and "Traceback" not in _err(res), _err(res)
    return lines[0]


def _popen(args: list[str], **kwargs) -> subprocess.CompletedProcess:
    proc = subprocess.run(PLACELOC + args, capture_output=True, text=True, timeout=HANG_S, **kwargs)
    record(proc.returncode, proc.stderr)
    return proc


# ----------------------------------------------------------------- 4. every number finite, every shape real

@pytest.mark.parametrize("setting,shown", [
    ("ground_truth.radius=.nan", "ground_truth.radius: nan is not a finite number"),
    ("seqslam.v_min=.nan", "seqslam.v_min: nan is not a finite number"),
    ("seqslam.v_max=.inf", "seqslam.v_max: inf is not a finite number"),
    ("ground_truth.tolerance=-.inf", "ground_truth.tolerance: -inf is not a finite number"),
    ("seqslam.thumbnail=[64, .nan]", "seqslam.thumbnail: [64, nan] holds nan, not a finite number"),
    ("seqslam.ds=100000000000000000000000", "seqslam.ds: 100000000000000000000000 is too large a number"),
])
def test_nan_infinity_and_huge_numbers_fail_the_config_check(route, setting, shown):
    """`.nan` compares false with every bound, so a range check alone let it through
    (R@1 0.0 with exit 0, or a traceback stages later): one guard refuses it in every value."""
    with pytest.raises(ConfigError, match=shown.replace("[", r"\[").replace("]", r"\]")):
        load_config(route / "config.yaml", [setting])
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(route.parent / "r"), "-q", "--set", setting])
    assert shown in _one_line(res)


@pytest.mark.parametrize("setting,shown", [
    ("seqslam.ds=true", "seqslam.ds must be an integer, got True (bool)"),
    ("seqslam.ds='10'", "seqslam.ds must be an integer, got '10' (str)"),
    ("ground_truth.radius=far", "ground_truth.radius must be a number, got 'far' (str)"),
    ("ground_truth.radius=1e3", "ground_truth.radius must be a number, got '1e3' (str) (YAML read it as text: write the "
                                "number without quotes, and exponents with a dot and a sign: 1.0e+12)"),
])
def test_bools_and_strings_posing_as_numbers_are_refused(route, setting, shown):
    import re

    with pytest.raises(ConfigError, match=re.escape(shown)):
        load_config(route / "config.yaml", [setting])


def _umap_data(route: Path) -> dict:
    return {"method": "umap", "reference": {"images": str(route / "reference")}, "query": {"images": str(route / "query")},
            "umap": {"model": str(ROOT / "configs" / "umap_corridor.yaml"), "mode": "umap"}}


@pytest.mark.parametrize("setting,shown", [
    ("umap.grid.x=[0, 'a', 1]", r"umap.grid.x\[1\] must be a number, got 'a'"),
    ("umap.grid.x=[0, true, 1]", r"umap.grid.x\[1\] must be a number, got True"),
    ("umap.grid.x=[0, .nan, 1]", r"umap.grid.x: \[0, nan, 1\] holds nan"),
])
def test_items_of_a_list_whose_default_is_null_are_checked(route, setting, shown):
    """``x: tuple[float, float, float] | None``: null by default, so no default item to
    compare with; the annotation gives the item type."""
    with pytest.raises(ConfigError, match=shown):
        load_config(data=_umap_data(route), overrides=[setting])


@pytest.mark.parametrize("ids,shown", [("[1, 'a', 2]", "'a' (str)"), ("[1, 2.5]", "2.5 (float)"), ("[1, true]", "True (bool)")])
def test_coembed_landmark_ids_of_mixed_types(tmp_path, ids, shown):
    """An empty default list shows no item type either: ``tuple[int, ...]`` does."""
    data = {"method": "coembed", "coembed": {"observations": str(tmp_path / "obs.csv")}}
    with pytest.raises(ConfigError, match=r"coembed.landmark_ids\[\d\] must be an integer, got " + shown.replace("(", r"\(").replace(")", r"\)")):
        load_config(data=data, overrides=[f"coembed.landmark_ids={ids}"])


@pytest.mark.parametrize("value,shown", [("1e308", "is more megabytes than any machine has"), ("inf", "is not a number of megabytes"),
                                         ("nan", "is not a number of megabytes"), ("-5", "is not a number of megabytes")])
def test_environment_megabytes_are_parsed_by_one_function(route, tmp_path, monkeypatch, value, shown):
    from placeloc.core.limits import ResourceError, env_megabytes

    monkeypatch.setenv("PLACELOC_DISK_LIMIT_MB", value)
    with pytest.raises(ResourceError, match=f"PLACELOC_DISK_LIMIT_MB='{value}' {shown}"):
        env_megabytes("PLACELOC_DISK_LIMIT_MB")
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"], PLACELOC_DISK_LIMIT_MB=value)
    assert f"PLACELOC_DISK_LIMIT_MB='{value}'" in _one_line(res)
    monkeypatch.setenv("PLACELOC_DISK_LIMIT_MB", "1024")
    assert env_megabytes("PLACELOC_DISK_LIMIT_MB") == 1024 * 2**20


@pytest.mark.parametrize("setting,shown", [
    ("frames=abc", "synth route: frames must be an integer, got 'abc' (str); e.g. --set frames=200"),
    ("frames=true", "synth route: frames must be an integer, got True (bool)"),
    ("step=.inf", "synth route: step must be a number, got inf (float)"),
    ("framez=10", "synth route: unknown setting 'framez'; known: frames, width"),
    ("width=-5", "synth route: width must be >= 1, got -5; e.g. --set width=128"),
])
def test_synth_set_values_are_typed_like_config_values(tmp_path, setting, shown):
    res = _cli(["synth", "route", str(tmp_path / "out"), "--set", setting])
    assert shown in _one_line(res)
    assert not (tmp_path / "out" / "config.yaml").exists()


def test_synth_set_still_takes_good_values(tmp_path):
    from placeloc.synth import parse_settings

    assert parse_settings("route", ["frames=12", "step=7", "shadows=null"]) == {"frames": 12, "step": 7.0, "shadows": None}
    res = _cli(["synth", "route", str(tmp_path / "out"), "--set", "frames=12"])
    assert res.exit_code == 0, _err(res)
    assert len(list((tmp_path / "out" / "reference").glob("*.png"))) == 12



@pytest.mark.parametrize("size", ["height=1", "width=1"])
def test_synth_route_at_the_smallest_size_it_accepts(tmp_path, size):
    """1 is the least a size takes: the generator draws frames of it (no traceback from an
    empty random range)."""
    import cv2

    res = _cli(["synth", "route", str(tmp_path / "out"), "--set", "frames=10", "--set", size])
    assert res.exit_code == 0, _err(res)
    first = sorted((tmp_path / "out" / "reference").glob("*.png"))[0]
    shape = cv2.imread(str(first), cv2.IMREAD_GRAYSCALE).shape
    assert shape[0 if size.startswith("height") else 1] == 1

def test_an_empty_recall_at_list_is_refused_at_config_check(route):
    with pytest.raises(ConfigError, match=r"ground_truth.recall_at: \[\] has 0 item\(s\); it needs at least 1"):
        load_config(route / "config.yaml", ["ground_truth.recall_at=[]"])


def test_show_options_are_checked_and_show_runs_as_a_module(route, tmp_path):
    """`python -m placeloc.cli show` ran main() before show was registered ("No such
    command"); a bad --recall-at was Python's int() message."""
    run = tmp_path / "r"
    assert _cli(["run", str(route / "config.yaml"), "--run-dir", str(run), "-q", "--set", "plots=false"]).exit_code == 0
    proc = _popen(["show", str(run), "--recall-at", "1,x"])
    lines = _lines(proc.stderr)
    assert proc.returncode == 2 and lines == ["error: --recall-at '1,x': give whole numbers from 1, separated by commas, "
                                              "e.g. --recall-at 1,5,10"], proc.stderr
    proc = _popen(["show", str(run), "--recall-at", "1,5", "-q"])
    assert proc.returncode == 0 and "recall@5:" in proc.stdout, proc.stderr


# --- floor plans and ZInD imports: one validator

SQUARE = [[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]]


def _plan(**changes) -> dict:
    plan = {"floor_z": 0.0, "ceiling_z": 2.5, "camera_z": 1.5, "rooms": [{"name": "hall", "polygon": SQUARE}]}
    plan.update(changes)
    return plan


@pytest.mark.parametrize("changes,shown", [
    ({"rooms": [{"polygon": [[0, 0], [4, 3], [4, 0], [0, 3]]}]},
     r"rooms\[0\].polygon is self-intersecting: its edge \[0.0, 0.0\] -> \[4.0, 3.0\] meets the edge \[4.0, 0.0\] -> \[0.0, 3.0\]"),
    ({"rooms": [{"polygon": [[0, 0], [1, 1], [2, 2]]}]}, r"rooms\[0\].polygon has zero area"),
    ({"rooms": [{"polygon": [[0, 0], [0, 0], [0, 0], [1, 1]]}]}, r"rooms\[0\].polygon has fewer than three distinct points"),
    ({"rooms": [{"polygon": [[0, 0], [float("nan"), 0], [2, 2]]}]}, r"rooms\[0\].polygon\[1\]\[0\] = nan is not a finite number"),
    ({"rooms": [{"polygon": [[0, 0], ["4", 0], [2, 2]]}]}, r"rooms\[0\].polygon\[1\]\[0\] = '4' is not a finite number"),
    ({"camera_z": float("nan")}, r"camera_z \(the camera's height above the floor\) = nan is not a finite number"),
    ({"camera_z": 0}, r"camera_z \(the camera's height above the floor\) = 0 must be above 0"),
    ({"ceiling_z": float("inf")}, "ceiling_z = inf is not a finite number"),
    ({"doors": [{"from": [0, 1], "to": [0, "x"]}]}, r"doors\[0\].to\[1\] = 'x' is not a finite number"),
    ({"rooms": [{"polygon": SQUARE, "internal": [[[1, 1], [2, 1], [3, 1]]]}]}, r"rooms\[0\].internal\[0\] has zero area"),
])
def test_floor_plans_that_are_not_real_geometry_are_refused(tmp_path, changes, shown):
    """Loaded from a file through the one loader: one line naming the file and the element."""
    path = tmp_path / "plan.yaml"
    path.write_text(json.dumps(_plan(**changes)).replace("NaN", ".nan").replace("Infinity", ".inf"))
    from placeloc.geometry.floorplan import load_model

    with pytest.raises(ModelError, match=f"{path}: {shown}"):
        load_model(path)


def test_a_simple_l_shaped_room_and_the_outline_form_still_load(tmp_path):
    from placeloc.geometry.floorplan import floor_plan_model

    l_shape = [[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]]
    model = floor_plan_model(_plan(rooms=[{"polygon": l_shape}]))
    assert model.inside(np.array([[0.5, 2.5], [2.0, 2.0]])).tolist() == [True, False]
    spike = [[0, 0], [4, 0], [4, 3], [2, 3], [2, 5], [2, 3], [0, 3]]
    with pytest.raises(ModelError, match="outline is self-intersecting"):
        floor_plan_model({"ceiling_z": 2.5, "outline": spike})


def _zind(tmp_path: Path, *, scale=0.5, camera_height=1.0, vertex=(1, 1), tr_scale=3) -> Path:
    square = [[-1, -1], [1, -1], list(vertex), [-1, 1]]
    pano = {"label": "room", "is_primary": True, "ceiling_height": 2.0, "camera_height": camera_height,
            "image_path": "panos/a.jpg", "floor_plan_transformation": {"translation": [4, 2], "rotation": 0, "scale": tr_scale},
            "layout_complete": {"vertices": square, "doors": [], "openings": [], "windows": [], "internal": []}}
    data = {"scale_meters_per_coordinate": {"floor_01": scale},
            "merger": {"floor_01": {"complete_room_01": {"partial_room_01": {"pano_01": pano}}}}}
    path = tmp_path / "zind_data.json"
    path.write_text(json.dumps(data))  # NaN is written as JSON's NaN, which json.loads reads back
    return path


@pytest.mark.parametrize("kwargs,shown", [
    ({"scale": float("nan")}, "scale_meters_per_coordinate['floor_01'] = nan is not a finite number"),
    ({"scale": 0}, "scale_meters_per_coordinate['floor_01'] = 0 must be above 0"),
    ({"camera_height": float("nan")}, "pano_01 camera_height = nan is not a finite number"),
    ({"tr_scale": -3}, "pano_01 floor_plan_transformation.scale = -3 must be above 0"),
    ({"vertex": (float("nan"), 1)}, "is not a finite number"),
    ({"vertex": (-1, -1)}, "is self-intersecting"),
])
def test_zind_imports_that_are_not_real_geometry_write_nothing(tmp_path, kwargs, shown):
    """`camera_z: nan` was written with exit 0: the importer passes its plan through the
    same validator before it writes anything."""
    source = _zind(tmp_path, **kwargs)
    res = _cli(["import", "zind", str(source), str(tmp_path / "out")])
    assert shown in _one_line(res)
    assert not (tmp_path / "out" / "floor_plan.yaml").exists()


def test_zind_import_of_a_good_tour_still_writes_its_plan(tmp_path):
    res = _cli(["import", "zind", str(_zind(tmp_path)), str(tmp_path / "out")])
    assert res.exit_code == 0, _err(res)
    import yaml

    plan = yaml.safe_load((tmp_path / "out" / "floor_plan.yaml").read_text())
    assert plan["camera_z"] == pytest.approx(1.5)  # 1 camera height x scale 3 x 0.5 m per coordinate


# --- descriptors

def _descriptor_config(tmp_path: Path, route: Path, method: str, d_ref: int, d_query: int) -> Path:
    rng = np.random.default_rng(0)
    np.save(tmp_path / "ref.npy", rng.random((len(list((route / "reference").glob("*.png"))), d_ref)).astype(np.float32))
    np.save(tmp_path / "query.npy", rng.random((len(list((route / "query").glob("*.png"))), d_query)).astype(np.float32))
    cfg = tmp_path / f"{method}.yaml"
    cfg.write_text(f"method: {method}\nreference: {{images: {route / 'reference'}}}\nquery: {{images: {route / 'query'}}}\n"
                   f"ground_truth: {{kind: csv, path: {route / 'ground_truth.csv'}}}\n"
                   f"{method}: {{descriptors_reference: ref.npy, descriptors_query: query.npy}}\n")
    return cfg


@pytest.mark.parametrize("method", ["retrieval", "seqslam"])
def test_descriptors_of_another_dimension_are_refused_before_any_stage(route, tmp_path, method):
    cfg = _descriptor_config(tmp_path, route, method, 64, 32)
    res = _cli(["run", str(cfg), "--run-dir", str(tmp_path / "r"), "-q"])
    assert (f"{method}.descriptors_query: query.npy holds 32-dimensional descriptors but {method}.descriptors_reference "
            "(ref.npy) holds 64-dimensional ones") in _one_line(res)
    assert not (tmp_path / "r" / "extract.h5").exists()


def test_descriptors_of_text_are_one_line(route, tmp_path):
    cfg = _descriptor_config(tmp_path, route, "retrieval", 8, 8)
    np.save(tmp_path / "query.npy", np.array([["a"] * 8] * len(list((route / "query").glob("*.png")))))
    res = _cli(["run", str(cfg), "--run-dir", str(tmp_path / "r"), "-q"])
    assert "query.npy: descriptors must be real numbers, got <U1 values" in _one_line(res)


# --- names that are not UTF-8

LATIN1 = os.fsdecode(b"fr\xe9me")  # "frème" in Latin-1: not valid UTF-8


def test_a_non_utf8_image_name_is_one_line_or_skipped(route, tmp_path):
    from placeloc.core.images import ImageError, list_images

    folder = route / "query"
    (folder / "frame3.png").rename(folder / f"{LATIN1}3.png")
    with pytest.raises(ImageError, match=r"fr\\xe9me3.png: the file name is not valid UTF-8 text"):
        list_images(folder)
    listed = list_images(folder, on_error="skip")
    assert "frame3.png" not in listed.names and len(listed.skipped) == 1 and "not valid UTF-8" in listed.skipped[0]
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"])
    assert r"fr\xe9me3.png: the file name is not valid UTF-8 text" in _one_line(res)


def test_a_non_utf8_run_dir_or_set_value_is_one_line(route, tmp_path):
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / f"{LATIN1}-run"), "-q"])
    assert r"--run-dir '" in _one_line(res) and r"fr\xe9me-run' is not valid UTF-8 text" in _one_line(res)
    res = _cli(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q", "--set", f"query.images={LATIN1}"])
    assert r"--set query.images: 'fr\xe9me' is not valid UTF-8 text" in _one_line(res)


# ----------------------------------------------------------------- 5. nothing skipped in silence

def _frame_as(path: Path, suffix: str) -> Path:
    """The same picture written in another format (OpenCV encodes WebP and GIF)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)  # 3 channels: OpenCV's GIF encoder takes no greyscale
    out = path.with_suffix(suffix)
    ok, data = cv2.imencode(suffix, img)
    assert ok
    out.write_bytes(data.tobytes())
    path.unlink()
    return out


def _synchronous_pair(route: Path, tmp_path: Path) -> Path:
    """Query = a copy of the reference, matched by single-image retrieval: under synchronous
    ground truth every answer is known (query i is reference i, at distance 0)."""
    shutil.rmtree(route / "query")
    shutil.copytree(route / "reference", route / "query")
    cfg = tmp_path / "sync.yaml"
    cfg.write_text(f"method: retrieval\nreference: {{images: {route / 'reference'}}}\nquery: {{images: {route / 'query'}}}\n"
                   "ground_truth: {kind: synchronous}\nplots: false\n")
    return cfg


@pytest.mark.parametrize("suffix", [".webp", ".gif"])
def test_an_image_of_another_format_is_named_and_synchronous_truth_refuses(route, tmp_path, caplog, suffix):
    """A .webp among PNGs was dropped in silence and shifted every later pair (R@1 1.000 ->
    0.208, exit 0). The listing names it; synchronous ground truth refuses the folder."""
    from placeloc.core.images import list_images

    cfg = _synchronous_pair(route, tmp_path)
    good = _cli(["run", str(cfg), "--run-dir", str(tmp_path / "good"), "-q"])
    assert good.exit_code == 0 and json.loads((tmp_path / "good" / "metrics.json").read_text())["recall_at_1"] == 1.0
    _frame_as(route / "query" / "frame5.png", suffix)
    with caplog.at_level(logging.WARNING, logger="placeloc"):
        listed = list_images(route / "query")
    assert len(listed) == len(list_images(route / "reference")) - 1
    assert [name for name, _ in listed.not_read] == [f"frame5{suffix}"]
    assert any(f"1 file(s) not read: frame5{suffix} ({suffix[1:].upper()} is not a format placeloc reads" in r.getMessage()
               for r in caplog.records)
    res = _cli(["run", str(cfg), "--run-dir", str(tmp_path / "bad"), "-q"])
    assert (f"query.images: frame5{suffix} is not read ({suffix[1:].upper()} is not a format placeloc reads"
            in _one_line(res)) and "every later image would pair with the wrong one" in _one_line(res)
    assert not (tmp_path / "bad" / "metrics.json").exists()


def test_an_image_under_another_name_is_named(route):
    from placeloc.core.images import list_images

    (route / "query" / "frame7.png").rename(route / "query" / "frame7.png~")
    (route / "query" / "notes.txt").write_text("taken on a rainy day\n")
    listed = list_images(route / "query")
    assert listed.not_read == [("frame7.png~", "its bytes are an image but its name has no image extension; rename it "
                                                "(e.g. .png) or move it out")]
    assert "notes.txt" in listed.others


def test_synchronous_truth_refuses_folders_whose_positions_shift(route, tmp_path):
    """Same file names in both folders, one frame missing from the query and another added
    at the end: the counts agree but every pair after it is wrong. The first mismatch is named."""
    cfg = _synchronous_pair(route, tmp_path)
    (route / "query" / "frame3.png").unlink()
    shutil.copy(route / "query" / "frame0.png", route / "query" / "frame999.png")
    res = _cli(["run", str(cfg), "--run-dir", str(tmp_path / "r"), "-q"])
    assert ("the first difference is at position 3: reference frame3.png beside query frame4.png"
            in _one_line(res))
    (route / "query" / "frame999.png").unlink()
    res = _cli(["run", str(cfg), "--run-dir", str(tmp_path / "r"), "-q"])
    assert "the reference lists 80 images and the query 79" in _one_line(res)


# ----------------------------------------------------------------- 8. the terminal behaves

def _with_closed_stdout(args: list[str], **env: str) -> subprocess.CompletedProcess:
    """Run placeloc with its stdout a pipe nobody reads any more (what `| head -1` leaves once
    head has its line): the read end is closed before placeloc writes, so every write meets
    EPIPE, however fast either side is."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run(PLACELOC + args, stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=HANG_S,
                              env={**os.environ, **env})
    finally:
        os.close(write_end)
    record(proc.returncode, proc.stderr)
    return proc


def test_params_into_a_closed_pipe_exits_0_quietly():
    proc = _with_closed_stdout(["params"])
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def test_run_into_a_closed_pipe_exits_0_quietly_after_the_run(route, tmp_path):
    proc = _with_closed_stdout(["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "-q"])
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    assert (tmp_path / "r" / "metrics.json").is_file()


def test_a_closed_stderr_does_not_stop_the_run(route, tmp_path):
    """`placeloc run ... 2>&1 | head -1`: the progress bar's next write met EPIPE and stopped
    the run (rc 1, a "bug"). Progress and log lines are dropped once their reader is gone;
    the run finishes, and a bad config still exits 2."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run(PLACELOC + ["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r")],
                              stdout=subprocess.PIPE, stderr=write_end, text=True, timeout=HANG_S)
        bad = subprocess.run(PLACELOC + ["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r2"),
                                         "--set", "seqslam.ds=.nan"], stdout=subprocess.PIPE, stderr=write_end, text=True,
                             timeout=HANG_S)
    finally:
        os.close(write_end)
    record(done.returncode, "")
    assert done.returncode == 0 and "metrics: " in done.stdout and (tmp_path / "r" / "metrics.json").is_file()
    assert bad.returncode == 2


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full on this system")
@pytest.mark.parametrize("args", [["params"], ["--help"]])
def test_a_full_stdout_is_named_not_the_run_dir(args):
    with open("/dev/full", "w") as full:
        proc = subprocess.run(PLACELOC + args, stdout=full, stderr=subprocess.PIPE, text=True, timeout=HANG_S)
    record(proc.returncode, proc.stderr)
    lines = _lines(proc.stderr)
    assert proc.returncode == 3 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: the standard output is full") and "--run-dir" not in lines[0]


@pytest.mark.parametrize("quiet", [True, False])
def test_quiet_silences_library_warnings(route, tmp_path, quiet):
    """Pillow's DecompressionBombWarning (made to fire on the 96 x 48 frames by lowering its
    limit below their 4608 pixels): -q prints nothing of it; without -q it is one line."""
    from PIL import Image

    # The reader asks Pillow for a frame's orientation only when the file has an EXIF block
    # (core/images.py): give one frame one (Orientation 1, upright), so Pillow opens it.
    first = sorted((route / "reference").glob("*.png"))[0]
    exif = Image.Exif()
    exif[0x0112] = 1
    with Image.open(first) as im:
        im.load()
        im.save(first, exif=exif.tobytes())
    code = ("import sys, PIL.Image; PIL.Image.MAX_IMAGE_PIXELS = 3000; sys.argv[0] = 'placeloc'; "
            "from placeloc.cli import main; main()")
    args = ["run", str(route / "config.yaml"), "--run-dir", str(tmp_path / "r"), "--set", "plots=false"] + (["-q"] if quiet else [])
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=HANG_S)
    record(proc.returncode, proc.stderr)
    assert proc.returncode == 0, proc.stderr
    if quiet:
        assert proc.stderr == "", proc.stderr
    else:
        bomb = [ln for ln in proc.stderr.replace("\r", "\n").splitlines() if "DecompressionBombWarning" in ln]
        assert bomb and all(ln.lstrip().startswith("warning: DecompressionBombWarning: Image size (4608 pixels)")
                            or "warning: DecompressionBombWarning" in ln for ln in bomb)
        assert "warnings.warn(" not in proc.stderr


def test_a_wrong_placeloc_shared_data_is_an_error_naming_it(tmp_path, monkeypatch):
    from placeloc.experiments import shared_data_dir

    monkeypatch.setenv("PLACELOC_SHARED_DATA", str(tmp_path / "nowhere"))
    with pytest.raises(ConfigError, match=r"PLACELOC_SHARED_DATA='.*nowhere' does not exist; point it at the shared data"):
        shared_data_dir()
    (tmp_path / "file").write_text("x")
    monkeypatch.setenv("PLACELOC_SHARED_DATA", str(tmp_path / "file"))
    with pytest.raises(ConfigError, match="is a file, not a folder"):
        shared_data_dir()
    monkeypatch.setenv("PLACELOC_SHARED_DATA", str(tmp_path))
    assert shared_data_dir() == tmp_path
    res = _cli(["experiment", "seqslam", "--quick", "--out", str(tmp_path / "e")], PLACELOC_SHARED_DATA=str(tmp_path / "nowhere"))
    assert "PLACELOC_SHARED_DATA=" in _one_line(res)


# ----------------------------------------------------------------- 9. a suite that passes on a busy machine

def test_no_fault_case_measures_the_clock():
    """A case that asserts how long something took fails on a loaded machine: the fault
    cases wait on events (a staging folder, workers ignoring Ctrl-C, a log line) and bound
    their waits only against a hang (faults_table.HANG_S)."""
    import ast

    offenders = []
    for path in sorted((ROOT / "tests").glob("test_faults*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in ("perf_counter", "monotonic") \
                    or isinstance(node, ast.Attribute) and node.attr == "time" and isinstance(node.value, ast.Name) \
                    and node.value.id == "time":
                offenders.append(f"{path.name}:{node.lineno}")
    assert offenders == [], offenders


def test_hidden_files_are_never_frames(route):
    """macOS leaves "._NAME" beside every file it copies to a foreign disk; some are valid
    images. Listed, "._frame1.png" would sort first and shift every frame's index against the
    ground truth in silence. A folder lists as a glob does: hidden files are not frames."""
    import shutil

    from placeloc.core.images import list_images

    before = list_images(route / "query").names
    shutil.copy(route / "query" / "frame1.png", route / "query" / "._frame1.png")  # a valid image
    (route / "query" / "._frame2.png").write_bytes(b"\x00\x05\x16\x07" + bytes(60))  # AppleDouble bytes
    (route / "query" / ".thumb.jpg").write_bytes(b"\xff\xd8\xff")
    listed = list_images(route / "query")
    assert listed.names == before and listed.not_read == [] and listed.skipped == []
    assert {"._frame1.png", "._frame2.png", ".thumb.jpg"} <= set(listed.others)
    assert list_images(str(route / "query" / "*.png")).names == before  # the glob agrees
