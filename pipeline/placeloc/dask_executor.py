"""The ``executor: dask`` backend: the same ``map`` contract over a ``dask.distributed`` cluster.

``scheduler: local-cluster`` starts a :class:`distributed.LocalCluster` of ``workers``
single-threaded processes (closed again by :meth:`DaskExecutor.close`);
``scheduler: tcp://host:port`` connects to a running ``dask scheduler``. Workers must be
able to import ``pipeline`` and read the image paths the config names (shared filesystem).

Failed tasks are retried by Dask itself (``retries``); a task on a worker that dies is
rescheduled by the scheduler. A task that still fails raises :class:`WorkItemError`
naming the item. Importing this module needs the optional extra ``placeloc[dask]``.
"""

from __future__ import annotations

import logging
import socket
import uuid
from concurrent.futures import CancelledError
from typing import Any, Callable, Iterable, Iterator

from distributed import Client, LocalCluster

from placeloc.config import ConfigError
from placeloc.executor import Describe, Executor, WorkItemError, describe_item, ordered_window

log = logging.getLogger("placeloc")

# A scheduler that does not answer within this is taken to be unreachable (fail fast).
CONNECT_TIMEOUT = "5s"


def _check_reachable(address: str, seconds: float = 3.0) -> None:
    """Fail at once when nothing listens at a tcp:// or tls:// address (a refused or timed
    out connection), instead of waiting out Dask's retries."""
    if not address.startswith(("tcp://", "tls://")):
        return
    host, _, port = address.split("://", 1)[1].rpartition(":")
    if not port.isdigit():
        raise ConfigError(f"executor.scheduler: {address!r} has no port; e.g. tcp://host:8786")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=seconds).close()
    except OSError as exc:
        raise ConfigError(f"executor.scheduler: cannot reach a Dask scheduler at {address} ({exc.strerror or exc}); "
                          "start it (dask scheduler), fix the address, or set executor.scheduler: local-cluster") from exc


class DaskExecutor(Executor):
    kind = "dask"

    def __init__(self, section: dict[str, Any]) -> None:
        self.workers = max(1, int(section.get("workers", 1)))
        self.retries = max(0, int(section.get("retries", 2)))
        self.scheduler = str(section.get("scheduler") or "local-cluster")
        self._cluster: LocalCluster | None = None
        # Dask's INFO chatter (nanny/scheduler lifecycle, set by its own config) would drown
        # placeloc's log in this process; keep its warnings and errors.
        dask_log = logging.getLogger("distributed")
        dask_log.setLevel(max(dask_log.getEffectiveLevel(), logging.WARNING))
        if self.scheduler == "local-cluster":
            # Loopback only, no dashboard (bokeh is not a dependency), quiet worker logs.
            self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                         host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR)
            self.client = Client(self._cluster)
        elif self.scheduler.startswith(("tcp://", "tls://", "inproc://")):
            _check_reachable(self.scheduler)
            try:
                self.client = Client(self.scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError, MemoryError, ValueError) as exc:
                # MemoryError/ValueError: something that is not a Dask scheduler answered
                # (its bytes were read as a message length).
                what = "reach" if isinstance(exc, (OSError, TimeoutError)) else "talk to"
                raise ConfigError(f"executor.scheduler: cannot {what} a Dask scheduler at {self.scheduler} within "
                                  f"{CONNECT_TIMEOUT} ({type(exc).__name__}); start it (dask scheduler), fix the "
                                  "address, or set executor.scheduler: local-cluster") from exc
        else:
            raise ConfigError(f"executor.scheduler: {self.scheduler!r} is neither local-cluster nor an address "
                             "like tcp://host:8786")

    def _window(self) -> int:
        # Two tasks per worker thread keep every worker busy while bounding memory on both sides.
        threads = sum(self.client.nthreads().values()) or self.workers
        return max(2, 2 * threads)

    def map(self, fn: Callable[..., Any], items: Iterable[Any], shared: Any = None,
            describe: Describe | None = None) -> Iterator[Any]:
        describe = describe or describe_item
        tag = f"{getattr(fn, '__name__', 'task')}-{uuid.uuid4().hex[:8]}"
        scattered: list[Any] = []

        def extra() -> tuple:
            if shared is None:
                return ()
            if not scattered:
                # One copy per worker up front; tasks then reference it by key. Wrapped in a list
                # so a dict is scattered as one object, not one future per value.
                scattered.append(self.client.scatter([shared], broadcast=True, hash=False)[0])
            return (scattered[-1],)

        def submit(numbered: tuple[int, Any], attempt: int = 0) -> Any:
            i, item = numbered
            return self.client.submit(fn, item, *extra(), key=f"{tag}-{i}-{attempt}", retries=self.retries, pure=False)

        def result(numbered: tuple[int, Any], fut: Any) -> Any:
            try:
                return self._result(fn, numbered[1], fut, describe)
            except WorkItemError as err:
                # A worker killed mid-stage can take scattered inputs (and tasks waiting on
                # them) with it: the scheduler then cancels those tasks. Scatter the shared
                # input again and run the item once more before giving up on it.
                if not isinstance(err.__cause__, CancelledError):
                    raise
                log.warning("dask: %s was cancelled (a worker died); submitting it again", describe(numbered[1]))
                scattered.clear()
                return self._result(fn, numbered[1], submit(numbered, attempt=1), describe)

        try:
            yield from ordered_window(enumerate(items), submit, self._window(), result)
        finally:
            for fut in scattered:
                fut.release()

    def _result(self, fn: Callable, item: Any, fut: Any, describe: Describe) -> Any:
        try:
            return fut.result()
        except Exception as exc:  # the task's own exception, or KilledWorker after repeated worker deaths
            raise WorkItemError(self.kind, fn, describe(item), exc, self.retries) from exc
        finally:
            fut.release()  # drop the result from the cluster as soon as we hold it

    def close(self) -> None:
        try:
            self.client.close()
        finally:
            if self._cluster is not None:
                self._cluster.close()
                self._cluster = None
