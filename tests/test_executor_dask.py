"""The Dask executor on a real LocalCluster (2 worker processes): identical results, worker loss, failures."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from placeloc.core import runner  # noqa: E402
from placeloc.core.common_params import ExecutorParams  # noqa: E402
from placeloc.core.config import load_config  # noqa: E402
from placeloc.core.dask_executor import DaskExecutor  # noqa: E402
from placeloc.core.executor import WorkItemError  # noqa: E402
from tests.test_executor import assert_identical, run_seqslam  # noqa: E402


@pytest.fixture(scope="module")
def cluster():
    """One 2-process cluster for the module; executors connect to it by tcp:// address."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as c:
        yield c


@pytest.fixture(scope="module")
def inline(tmp_path_factory):
    from tests.conftest import SAMPLES

    return run_seqslam(SAMPLES, tmp_path_factory.mktemp("inline"), ["executor.workers=1"])


def dask_args(cluster) -> list[str]:
    # 16 images per task: several tasks per map, so a worker can die mid-map
    return ["executor.kind=dask", "executor.workers=2", f"executor.scheduler={cluster.scheduler_address}",
            "seqslam.images_per_task=16"]


def count_and_fail(item: int, log: str) -> int:
    with open(log, "a") as fh:
        fh.write(f"{item}\n")
    raise RuntimeError("this task always fails")


def test_local_cluster_matches_inline(route, tmp_path, inline):
    # scheduler: local-cluster, started and closed by the executor itself
    out = run_seqslam(route, tmp_path / "dask", ["executor.kind=dask", "executor.workers=2"])
    assert_identical(inline, out)


class KillingDaskExecutor(DaskExecutor):
    """After the first result of each map, SIGKILL one worker process (its nanny restarts it)."""

    killed: list[int] = []

    def map(self, fn, items, shared=None, describe=None):
        for i, result in enumerate(super().map(fn, items, shared=shared, describe=describe)):
            if i == 0:
                pids = self.client.run(os.getpid)
                pid = sorted(pids.values())[0]
                os.kill(pid, signal.SIGKILL)
                self.killed.append(pid)
            yield result


def test_killing_a_worker_mid_stage_still_completes(route, tmp_path, inline, cluster, monkeypatch):
    KillingDaskExecutor.killed = []
    monkeypatch.setattr(runner, "make_executor", KillingDaskExecutor)
    out = run_seqslam(route, tmp_path / "killed", dask_args(cluster))
    assert_identical(inline, out)
    # one kill per map: extract reference, extract query (localize runs its difference
    # blocks in-process, on threaded kernels: it maps nothing)
    assert len(KillingDaskExecutor.killed) == 2
    with distributed.Client(cluster) as client:
        client.wait_for_workers(2, timeout=300)  # a hang guard: a loaded machine starts workers slowly
        alive = set(client.run(os.getpid).values())
    assert not alive & set(KillingDaskExecutor.killed)


def test_a_task_that_always_fails_stops_with_the_item_named(cluster, tmp_path):
    log = tmp_path / "attempts.txt"
    ex = DaskExecutor(ExecutorParams(kind="dask", workers=2, scheduler=cluster.scheduler_address, retries=2))
    try:
        jobs = [(i, str(log)) for i in range(4)]
        message = r"dask executor: count_and_fail_job failed on block 0 after 2 retries: RuntimeError: this task always fails"
        with pytest.raises(WorkItemError, match=message):
            for _ in ex.map(count_and_fail_job, jobs, describe=lambda job: f"block {job[0]}"):
                pass
    finally:
        ex.close()
    # Dask retried item 0 itself: 1 try + 2 retries
    assert log.read_text().split().count("0") == 3


def count_and_fail_job(job: tuple[int, str]) -> int:
    return count_and_fail(*job)


def test_corrupt_image_names_the_chunk_and_image(route, tmp_path, cluster):
    (route / "reference" / "frame70.png").write_bytes(b"not a png")
    cfg = load_config(route / "config.yaml", ["plots=false", "executor.retries=1", *dask_args(cluster)])
    with pytest.raises(WorkItemError, match=r"chunk of 16 item\(s\) .*frame64.png .. .*frame79.png after 1 retry.*frame70.png"):
        runner.run_stage(cfg, tmp_path / "run", "extract", quiet=True)


def test_shared_is_broadcast_once_and_released(cluster):
    ex = DaskExecutor(ExecutorParams(kind="dask", workers=2, scheduler=cluster.scheduler_address, retries=0))
    try:
        big = np.arange(200_000, dtype=np.float64)
        got, holders = [], None
        for value in ex.map(_sum_with, range(20), shared=big):
            if holders is None:  # while the map runs, one key holds it, on both workers
                holders = {k: v for k, v in ex.client.who_has().items() if str(k).startswith("ndarray-")}
            got.append(value)
        assert got == [float(big.sum() + i) for i in range(20)]
        assert len(holders) == 1 and len(next(iter(holders.values()))) == 2
        # released when the map ends (asynchronously on the scheduler)
        deadline = time.time() + 300  # a hang guard, not a speed requirement
        while holders.keys() & ex.client.who_has().keys() and time.time() < deadline:
            time.sleep(0.1)
        assert not holders.keys() & ex.client.who_has().keys()
    finally:
        ex.close()


def _sum_with(item: int, shared: np.ndarray) -> float:
    return float(shared.sum() + item)


def add_shared(item: int, shared: np.ndarray) -> int:
    return int(item + shared.sum())


class CancellingDaskExecutor(DaskExecutor):
    """Cancels the first task's future before its result is read, as the scheduler does
    when a dying worker takes a task's scattered input with it."""

    cancelled = 0

    def _result(self, fn, item, fut, describe):
        if type(self).cancelled == 0:
            type(self).cancelled += 1
            self.client.cancel(fut)
        return super()._result(fn, item, fut, describe)


def test_a_cancelled_task_is_submitted_again_with_its_shared_input(cluster):
    CancellingDaskExecutor.cancelled = 0
    ex = CancellingDaskExecutor(ExecutorParams(kind="dask", workers=2, scheduler=cluster.scheduler_address, retries=0))
    try:
        out = list(ex.map(add_shared, range(6), shared=np.arange(4)))
    finally:
        ex.close()
    assert CancellingDaskExecutor.cancelled == 1 and out == [i + 6 for i in range(6)]
