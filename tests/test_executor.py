"""Executors without Dask: the process pool matches inline, shared inputs, named failures, missing extra."""

from __future__ import annotations

import builtins
from pathlib import Path

import h5py
import numpy as np
import pytest

from placeloc.core.common_params import ExecutorParams
from placeloc.core.config import load_config
from placeloc.core.executor import InlineExecutor, LocalExecutor, WorkItemError, describe_item
from placeloc.core.executors import make_executor
from placeloc.core.runner import run_stage

# Every dataset extract and localize write; compared bit for bit between executors.
ARRAYS = {
    "extract": ["reference/features", "reference/thumbnails", "reference/index",
                "query/features", "query/thumbnails", "query/index"],
    "localize": ["difference", "candidates", "scores", "confidence", "single_best", "single_confidence"],
}


def run_seqslam(route: Path, run: Path, executor: list[str]) -> dict[str, np.ndarray]:
    """extract + localize on the bundled route (small blocks so there are several work items)."""
    cfg = load_config(route / "config.yaml", ["plots=false", "seqslam.block_size=16", *executor])
    run_stage(cfg, run, "localize", quiet=True)
    out = {}
    for stage, names in ARRAYS.items():
        with h5py.File(run / f"{stage}.h5") as f:
            out.update({f"{stage}:{n}": f[n][()] for n in names})
    return out


def assert_identical(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
        assert np.array_equal(a[key], b[key], equal_nan=True), f"{key} differs"


def add_shared(item: int, shared: dict[str, np.ndarray]) -> float:
    return float(shared["a"][item] + shared["b"][item])


def fail_on_three(item: int) -> int:
    if item == 3:
        raise ValueError("item three is bad")
    return item


def test_local_pool_matches_inline(route, tmp_path):
    inline = run_seqslam(route, tmp_path / "inline", ["executor.workers=1"])
    local = run_seqslam(route, tmp_path / "local", ["executor.workers=2"])
    assert len(inline["localize:difference"]) == 80 and inline["localize:difference"].shape[1] == 81
    assert_identical(inline, local)


def test_shared_inputs_reach_every_executor():
    shared = {"a": np.arange(50, dtype=np.float64), "b": np.full(50, 0.5)}
    expected = [i + 0.5 for i in range(50)]
    assert list(InlineExecutor().map(add_shared, range(50), shared=shared)) == expected
    with LocalExecutor(2) as ex:
        assert list(ex.map(add_shared, range(50), shared=shared)) == expected
        # a second map with another shared input must not see the first one (workers cache per map)
        shared2 = {"a": np.zeros(50), "b": np.ones(50)}
        assert list(ex.map(add_shared, range(50), shared=shared2)) == [1.0] * 50


def test_failures_name_the_item():
    with LocalExecutor(2) as ex:
        with pytest.raises(WorkItemError, match=r"fail_on_three failed on item #3: ValueError: item three is bad"):
            list(ex.map(fail_on_three, range(10), describe=lambda i: f"item #{i}"))
    with pytest.raises(ValueError, match="item three") as info:
        list(InlineExecutor().map(fail_on_three, range(10), describe=lambda i: f"item #{i}"))
    assert "item #3" in " ".join(info.value.__notes__)
    chunk = (["/data/a/frame0.png", "/data/a/frame1.png", "/data/a/frame63.png"], {"x": 1}, "stop")
    assert describe_item(chunk) == "chunk of 3 item(s) /data/a/frame0.png .. /data/a/frame63.png"
    assert len(describe_item(list(range(1000)))) <= 160


def test_corrupt_image_in_a_worker_names_the_image(route, tmp_path):
    (route / "query" / "frame5.png").write_bytes(b"not a png")
    cfg = load_config(route / "config.yaml", ["plots=false", "executor.workers=2", "seqslam.images_per_task=64"])
    with pytest.raises(WorkItemError, match=r"describe_chunk failed on chunk of 64 item\(s\) .*frame0.png .. .*frame63.png.*frame5.png"):
        run_stage(cfg, tmp_path / "run", "extract", quiet=True)


def test_dask_missing_gives_a_clear_error(monkeypatch):
    real_import = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name.split(".")[0] in ("dask", "distributed"):
            raise ImportError(f"No module named '{name.split('.')[0]}'")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(__import__("sys").modules, "placeloc.core.dask_executor", raising=False)
    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.raises(ValueError, match=r"pip install 'placeloc\[dask\]'"):
        make_executor(ExecutorParams(kind="dask", workers=2, scheduler="local-cluster", retries=2))
    # the local executor still works without it
    assert isinstance(make_executor(ExecutorParams(kind="local", workers=1)), InlineExecutor)
