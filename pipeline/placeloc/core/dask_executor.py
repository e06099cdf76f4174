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

import contextlib
import logging
import os
import shutil
import signal
import socket
import tempfile
import time
import uuid
from concurrent.futures import CancelledError
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from distributed import Client, LocalCluster

from placeloc.core.common_params import ExecutorParams
from placeloc.core.errors import ConfigError
from placeloc.core.executor import Describe, Executor, WorkItemError, describe_item, ordered_window

log = logging.getLogger("placeloc")

# A scheduler that does not answer within this is taken to be unreachable (fail fast).
CONNECT_TIMEOUT = "5s"
# What the probe waits for: the TCP connection, then the scheduler's greeting.
PROBE_SECONDS = 3.0
# A Dask message starts with its length (8 bytes, little-endian); a scheduler's greeting
# (its handshake) is a few hundred bytes. Anything outside this is not Dask talking.
_HANDSHAKE_BYTES = (8, 1 << 20)


def _scheduler_error(address: str, what: str, detail: str = "") -> ConfigError:
    return ConfigError(f"executor.scheduler: {what} at {address}{detail}; start a scheduler there (dask scheduler), "
                       "fix the address, or set executor.scheduler: local-cluster")


def _check_reachable(address: str, seconds: float = PROBE_SECONDS) -> None:
    """Fail within ``seconds`` when no Dask scheduler answers at a tcp:// address: nothing
    listens (refused or no answer), or something else does (a web server, a peer that
    accepts and never speaks). A Dask scheduler greets a new connection first (its
    handshake), so the probe only listens; Dask's own Client would instead send its
    greeting and wait for a reply without a bound (or read an HTTP reply as a message
    length and run out of memory)."""
    if not address.startswith(("tcp://", "tls://")):
        return
    host, _, port = address.split("://", 1)[1].rpartition(":")
    if not port.isdigit():
        raise ConfigError(f"executor.scheduler: {address!r} has no port; e.g. tcp://host:8786")
    try:
        sock = socket.create_connection((host.strip("[]"), int(port)), timeout=seconds)
    except OSError as exc:
        if isinstance(exc, ConnectionRefusedError):
            reason = "connection refused"
        elif isinstance(exc, TimeoutError):
            reason = f"no answer within {seconds:g} s"
        else:
            reason = exc.strerror or str(exc)
        raise _scheduler_error(address, "cannot reach a Dask scheduler", f" ({reason})") from exc
    if address.startswith("tls://"):
        sock.close()  # the greeting comes after the TLS handshake: Client's own timeout bounds it
        return
    try:
        sock.settimeout(seconds)
        head = b""
        while len(head) < 8:
            chunk = sock.recv(8 - len(head))
            if not chunk:
                raise _scheduler_error(address, "no Dask scheduler answers", " (the peer closed the connection without a word)")
            head += chunk
    except TimeoutError as exc:
        raise _scheduler_error(address, "no Dask scheduler answers",
                               f" (something accepts connections there but says nothing within {seconds:g} s)") from exc
    except OSError as exc:
        raise _scheduler_error(address, "cannot reach a Dask scheduler", f" ({exc.strerror or exc})") from exc
    finally:
        sock.close()
    length = int.from_bytes(head, "little")
    if not _HANDSHAKE_BYTES[0] <= length <= _HANDSHAKE_BYTES[1]:
        shown = head.decode("ascii", "replace") if head.isascii() else head.hex()
        raise _scheduler_error(address, "no Dask scheduler answers", f" (something else does: it sent {shown!r})")


def dask_temp_dir() -> Path:
    """A folder of this run for the workers' scratch space (spilled data, locks), removed
    when the executor closes; named like the shared-array folders so that the next run
    removes it if this one is killed."""
    from placeloc.core.executor import SHARED_PREFIX

    return Path(tempfile.mkdtemp(prefix=f"{SHARED_PREFIX}{os.getpid()}-dask-"))


class DaskExecutor(Executor):
    kind = "dask"

    def __init__(self, params: ExecutorParams) -> None:
        self.workers = max(1, int(params.workers))
        self.retries = max(0, int(params.retries))
        self.scheduler = str(params.scheduler or "local-cluster")
        self._cluster: LocalCluster | None = None
        # Dask's INFO chatter (nanny/scheduler lifecycle, set by its own config) would drown
        # placeloc's log in this process; keep its warnings and errors.
        dask_log = logging.getLogger("distributed")
        dask_log.setLevel(max(dask_log.getEffectiveLevel(), logging.WARNING))
        self._scratch: Path | None = None
        if self.scheduler == "local-cluster":
            # Loopback only, no dashboard (bokeh is not a dependency), quiet worker logs, the
            # workers' scratch space in a folder of ours (Dask's default leaves
            # $TMPDIR/dask-scratch-space behind). The worker processes ignore Ctrl-C from
            # their preload on (dask_setup below): the parent handles it and kills them, so
            # a Ctrl-C prints one line instead of every worker's traceback.
            self._scratch = dask_temp_dir()
            import dask

            # the scheduler (in this process) takes its scratch folder from Dask's config
            with dask.config.set({"temporary-directory": str(self._scratch)}):
                self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                             host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR,
                                             local_directory=str(self._scratch), preload=[__name__])
            self.client = Client(self._cluster)
        elif self.scheduler.startswith(("tcp://", "tls://", "inproc://")):
            _check_reachable(self.scheduler)
            try:
                self.client = Client(self.scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError, MemoryError, ValueError) as exc:
                raise _scheduler_error(self.scheduler, "no Dask scheduler answers", f" (no reply within {CONNECT_TIMEOUT})") from exc
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
            _wait_interruptibly(fut)
            return fut.result()
        except Exception as exc:  # the task's own exception, or KilledWorker after repeated worker deaths
            if type(exc).__name__ == "KilledWorker":
                from placeloc.core.executor import worker_lost

                raise worker_lost(fn, describe(item), self.workers) from None
            raise WorkItemError(self.kind, fn, describe(item), exc, self.retries) from exc
        finally:
            fut.release()  # drop the result from the cluster as soon as we hold it

    def close(self) -> None:
        from placeloc.core.interrupts import received

        if received() is not None and self._cluster is not None:
            # Interrupted: a graceful close waits on the workers, which may be mid-task or
            # gone; the command line kills them (they are our child processes) and leaves.
            self._cluster = None
            if self._scratch is not None:
                shutil.rmtree(self._scratch, ignore_errors=True)
                self._scratch = None
            return
        try:
            with _quiet_dask_shutdown():
                try:
                    self.client.close(timeout=10)
                finally:
                    if self._cluster is not None:
                        self._cluster.close(timeout=10)
                        self._cluster = None
        finally:
            if self._scratch is not None:
                shutil.rmtree(self._scratch, ignore_errors=True)
                self._scratch = None


def dask_setup(worker: Any) -> None:
    """Run by each local-cluster worker process at its start (Dask's ``preload``): Ctrl-C
    is the parent's to handle (it kills the workers), so a worker ignores it instead of
    printing its own traceback. (Ignoring Ctrl-C in the parent while the cluster starts
    would reach them earlier, but a Ctrl-C in that window would then be lost, delivered to
    one of Dask's threads; a signal mask does not reach them: Dask starts its worker
    processes from a thread of its own.)"""
    with contextlib.suppress(ValueError):  # not the main thread: leave it
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _wait_interruptibly(fut: Any) -> None:
    """Wait for a future in short naps. Ctrl-C may be delivered to one of Dask's threads:
    Python then runs its handler in the main thread at the next bytecode, and Dask's own
    ``result()`` only looks up every 10 s."""
    from placeloc.core.interrupts import raise_if_interrupted

    nap = 0.001
    while not fut.done():
        time.sleep(nap)
        nap = min(0.05, nap * 2)
        raise_if_interrupted()


@contextlib.contextmanager
def _quiet_dask_shutdown() -> Iterator[None]:
    """After Ctrl-C, Dask's shutdown reports the tasks it cancelled and the connections it
    closed as errors: silence them (placeloc has said "interrupted" once)."""
    from placeloc.core.interrupts import received

    if received() is None:
        yield
        return
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)
