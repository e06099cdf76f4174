"""Map independent work items over a pool of workers, results back in order.

Stages call :func:`make_executor` with the ``executor:`` config section and then
``executor.map(fn, items)``. ``fn`` must be a module-level function (picklable by
reference) and its results small enough to send back; the calling process alone writes
artifacts. ``workers: 1`` runs in-process, which is also what tests use by default.
"""

from __future__ import annotations

import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterable, Iterator


class Executor:
    kind = "base"

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class InlineExecutor(Executor):
    kind = "inline"

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        for item in items:
            yield fn(item)


class LocalExecutor(Executor):
    """A process pool on this machine (spawned, so numba/BLAS threads are not forked)."""

    kind = "local"

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("spawn"))
        # Bounded look-ahead keeps memory flat however many items there are.
        items = iter(items)
        window = []
        for item in items:
            window.append(self._pool.submit(fn, item))
            if len(window) >= 2 * self.workers:
                yield window.pop(0).result()
        for fut in window:
            yield fut.result()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


def make_executor(section: dict[str, Any]) -> Executor:
    kind = section.get("kind", "local")
    if kind == "dask":
        try:
            from pipeline.dask_executor import DaskExecutor  # optional extra
        except ImportError as exc:
            raise RuntimeError(f"executor.kind: dask is not available ({exc}); "
                               "install it with pip install 'placeloc[dask]' or use executor.kind: local") from exc

        return DaskExecutor(section)
    workers = int(section.get("workers", 1))
    return InlineExecutor() if workers <= 1 else LocalExecutor(workers)
