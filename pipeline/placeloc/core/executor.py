"""Map independent work items over a pool of workers, results back in order.

The runner builds one with :func:`placeloc.core.executors.make_executor` from the
``executor:`` config section, and stages call ``executor.map(fn, items)``. ``fn`` must be a module-level function (picklable by
reference) and its results small enough to send back; the calling process alone writes
artifacts. ``workers: 1`` runs in-process, which is also what tests use by default.

Large read-only inputs every item needs (e.g. the reference feature matrix) go in
``shared``: ``executor.map(fn, items, shared=x)`` calls ``fn(item, x)``. Each executor
ships ``shared`` to its workers once per ``map`` (inline: by reference; local: a
memory-mapped ``.npy`` file per array; dask: ``client.scatter(..., broadcast=True)``)
instead of once per task. ``describe(item)`` names an item in the error raised when it
fails for good.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing as mp
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np

Describe = Callable[[Any], str]


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity (``taskset``, a container's
    cpuset), not the machine's count."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


class WorkItemError(RuntimeError):
    """A work item failed in a worker (after the executor's retries); the message names it."""

    def __init__(self, kind: str, fn: Callable, description: str, exc: BaseException, retries: int = 0) -> None:
        tries = f" after {retries} retr{'y' if retries == 1 else 'ies'}" if retries else ""
        super().__init__(f"{kind} executor: {getattr(fn, '__name__', fn)} failed on {description}{tries}: "
                         f"{type(exc).__name__}: {exc}")
        self.description = description
        self.original = exc


def worker_lost(fn: Callable, description: str, workers: int) -> Exception:
    """The one-line error for a worker process that died under a work item (SIGKILL, most
    often from the out-of-memory killer): an environment failure, not a bug."""
    from placeloc.core.errors import WorkerLostError

    return WorkerLostError(f"a worker process was killed (out of memory?) while running {getattr(fn, '__name__', fn)} on "
                           f"{description}; lower executor.workers (now {workers}) or the method's size parameters, "
                           "free memory, then rerun to resume (finished stages are kept)")


def describe_item(item: Any, limit: int = 160) -> str:
    """Default readable name of a work item: a chunk of paths as first .. last, else a short repr."""
    head = item[0] if isinstance(item, tuple) and item else item
    if isinstance(head, (list, tuple)) and head and all(isinstance(p, (str, Path)) for p in head):
        return f"chunk of {len(head)} item(s) {head[0]} .. {head[-1]}"
    if isinstance(item, tuple):
        text = "(" + ", ".join(_short_repr(v) for v in item) + ")"
    else:
        text = _short_repr(item)
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _short_repr(value: Any) -> str:
    """A value as it should appear in one line: an array by its shape, not its numbers."""
    if isinstance(value, np.ndarray):
        return f"array{value.shape} {value.dtype}"
    if isinstance(value, (list, tuple)) and len(value) > 4:
        return f"{type(value).__name__} of {len(value)} ({_short_repr(value[0])}, ...)"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_short_repr(v)}" for k, v in list(value.items())[:4]) + (", ...}" if len(value) > 4 else "}")
    return repr(value)


class Executor:
    kind = "base"

    def map(self, fn: Callable[..., Any], items: Iterable[Any], shared: Any = None,
            describe: Describe | None = None) -> Iterator[Any]:
        """Yield ``fn(item)`` (or ``fn(item, shared)`` when ``shared`` is given) in item order."""
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class InlineExecutor(Executor):
    """In-process: no copies, no serialisation; exceptions propagate unchanged (with a note)."""

    kind = "inline"
    workers = 1

    def map(self, fn: Callable[..., Any], items: Iterable[Any], shared: Any = None,
            describe: Describe | None = None) -> Iterator[Any]:
        for item in items:
            try:
                yield fn(item) if shared is None else fn(item, shared)
            except Exception as exc:
                exc.add_note(f"while running {getattr(fn, '__name__', fn)} on {(describe or describe_item)(item)}")
                raise


# --- worker lifetime: a worker must never outlive the process that started it ---
SHARED_PREFIX = "placeloc-shared-"
_PR_SET_PDEATHSIG = 1


def _worker_init(parent_pid: int) -> None:
    """Runs first in every pool worker. Ctrl-C is the parent's to handle (no worker
    tracebacks); when the parent dies, even by kill -9, the worker dies too: the kernel's
    parent-death signal on Linux, and a watchdog thread everywhere."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):  # started with Ctrl-C blocked (_QuietSpawnProcess); ignored now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)

    def watchdog() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watchdog, name="placeloc-parent-watchdog", daemon=True).start()


class _QuietSpawnProcess(mp.get_context("spawn").Process):  # type: ignore[name-defined,misc]
    """A spawned worker whose start no signal can cut short, and that no Ctrl-C reaches
    before it ignores Ctrl-C.

    - The parent writes the worker's instructions to a pipe just after the exec. A handler
      raising in between (SIGTERM, seen once in CI) left the worker reading an empty pipe
      and printing "EOFError: Ran out of input" under the run's one line. So while the
      worker starts, SIGINT and SIGTERM are only recorded, and raised again as soon as
      start() is done: the parent loses neither.
    - SIGINT is also blocked in this thread while the worker starts: a blocked signal
      survives the exec, so the worker starts with Ctrl-C held back, and
      :func:`_worker_init` ignores it before letting it through (without this, a worker
      still importing when Ctrl-C arrives prints its own KeyboardInterrupt traceback).
      Blocked, not ignored: an ignored signal is dropped, and the parent's Ctrl-C with it
      (a Ctrl-C in that window used to be lost: the run went on).
    - A handled signal is reset to its default at exec, so the worker itself still dies
      on SIGTERM."""

    def start(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return super().start()  # only the main thread may set handlers; start as is
        held: list[int] = []

        def hold(signum: int, frame: Any) -> None:
            held.append(signum)

        old = {sig: signal.signal(sig, hold) for sig in (signal.SIGINT, signal.SIGTERM)}
        mask = getattr(signal, "pthread_sigmask", None)  # POSIX only
        previous = mask(signal.SIG_BLOCK, {signal.SIGINT}) if mask is not None else None
        try:
            super().start()
        finally:
            if mask is not None:
                mask(signal.SIG_SETMASK, previous)  # a Ctrl-C held back meanwhile reaches `hold` here
            for sig, handler in old.items():
                # None: a handler set outside Python (an embedding program); the default stands in
                signal.signal(sig, signal.SIG_DFL if handler is None else handler)
            for sig in dict.fromkeys(held):
                signal.raise_signal(sig)


class _QuietSpawnContext(type(mp.get_context("spawn"))):  # type: ignore[misc]
    Process = _QuietSpawnProcess


def _shared_dir_owner(path: Path) -> int | None:
    tail = path.name[len(SHARED_PREFIX):].split("-", 1)[0]
    return int(tail) if tail.isdigit() else None


def remove_stale_shared(tmp_root: str | Path | None = None) -> list[Path]:
    """Delete shared-array folders (``/tmp/placeloc-shared-<pid>-*``) whose process is gone:
    what a killed run left behind."""
    from placeloc.core.artifacts import pid_alive  # h5py is not needed in pool workers

    removed = []
    root = Path(tmp_root or tempfile.gettempdir())
    for p in root.glob(f"{SHARED_PREFIX}*"):
        pid = _shared_dir_owner(p)
        if pid is not None and pid != os.getpid() and pid_alive(pid):
            continue
        if pid is None and time.time() - p.stat().st_mtime < 24 * 3600:
            continue  # an old-style name: only remove when a day old
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed



# --- shared arrays for the process pool: memory-mapped .npy files, loaded once per worker ---
_WORKER_SHARED: dict[str, Any] = {}


def _pack_shared(shared: Any, folder: Path) -> Any:
    """Replace arrays (top level or values of a dict) by the path of a .npy file holding them."""
    def one(name: str, value: Any) -> Any:
        if isinstance(value, np.ndarray) and value.dtype != object:
            path = folder / f"{name}.npy"
            try:
                np.save(path, value, allow_pickle=False)
            except OSError as exc:
                from placeloc.core.artifacts import disk_full_error, is_disk_full

                if is_disk_full(exc):
                    raise disk_full_error(path, value.nbytes) from None
                raise
            return ("__npy__", str(path))
        return value

    if isinstance(shared, dict):
        return {k: one(f"v{i}", v) for i, (k, v) in enumerate(shared.items())}
    return one("shared", shared)


def _unpack_shared(handle: Any, token: str) -> Any:
    if token not in _WORKER_SHARED:
        def one(v: Any) -> Any:
            if isinstance(v, tuple) and len(v) == 2 and v[0] == "__npy__":
                # np.asarray drops the memmap subclass (numba wants plain arrays); pages are shared via the OS cache.
                return np.asarray(np.load(v[1], mmap_mode="r", allow_pickle=False))
            return v

        _WORKER_SHARED.clear()  # one map at a time per run: keep only the current shared input
        _WORKER_SHARED[token] = {k: one(v) for k, v in handle.items()} if isinstance(handle, dict) else one(handle)
    return _WORKER_SHARED[token]


def _call_with_shared(fn: Callable[..., Any], item: Any, handle: Any, token: str) -> Any:
    return fn(item, _unpack_shared(handle, token))


def ordered_window(items: Iterable[Any], submit: Callable[[Any], Any], limit: int,
                   collect: Callable[[Any, Any], Any]) -> Iterator[Any]:
    """Submit ``items`` with at most ``limit`` futures in flight and yield
    ``collect(item, future)`` in submission order; futures still pending when the consumer
    stops (or an item fails) are cancelled. The bound keeps memory flat however many items
    there are."""
    window: deque = deque()
    try:
        for item in items:
            window.append((item, submit(item)))
            if len(window) >= limit:
                yield collect(*window.popleft())
        while window:
            yield collect(*window.popleft())
    finally:
        for _, fut in window:
            fut.cancel()


class LocalExecutor(Executor):
    """A process pool on this machine (spawned, so numba/BLAS threads are not forked)."""

    kind = "local"

    def __init__(self, workers: int) -> None:
        self.workers = workers
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable[..., Any], items: Iterable[Any], shared: Any = None,
            describe: Describe | None = None) -> Iterator[Any]:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=_QuietSpawnContext(),
                                             initializer=_worker_init, initargs=(os.getpid(),))
        tmp = None
        if shared is not None:
            # The folder name carries our pid, so the next run can remove it if we are killed.
            tmp = Path(tempfile.mkdtemp(prefix=f"{SHARED_PREFIX}{os.getpid()}-"))
            handle, token = _pack_shared(shared, tmp), tmp.name

            def submit(item: Any) -> Any:
                return self._pool.submit(_call_with_shared, fn, item, handle, token)
        else:
            def submit(item: Any) -> Any:
                return self._pool.submit(fn, item)
        from concurrent.futures.process import BrokenProcessPool

        try:
            yield from ordered_window(items, submit, 2 * self.workers,
                                      lambda item, fut: self._result(fn, item, fut, describe))
        except BrokenProcessPool:
            # A worker died while the next item was being submitted (the pool refuses new
            # work from then on): the same environment failure as seen on a result.
            raise worker_lost(fn, "one of its work items", self.workers) from None
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)

    def _result(self, fn: Callable, item: Any, fut: Any, describe: Describe | None) -> Any:
        from concurrent.futures.process import BrokenProcessPool

        try:
            return fut.result()
        except BrokenProcessPool:
            raise worker_lost(fn, (describe or describe_item)(item), self.workers) from None
        except Exception as exc:
            raise WorkItemError(self.kind, fn, (describe or describe_item)(item), exc) from exc

    def close(self) -> None:
        if self._pool is None:
            return
        pool, self._pool = self._pool, None
        from placeloc.core.interrupts import received

        if received() is None:
            pool.shutdown(cancel_futures=True)
            return
        # Interrupted: do not wait for the workers to finish their items (a second Ctrl-C
        # would land in that wait). The command line then kills them and leaves without
        # Python's exit handlers, which would join a worker blocked on its queue for ever.
        pool.shutdown(wait=False, cancel_futures=True)
