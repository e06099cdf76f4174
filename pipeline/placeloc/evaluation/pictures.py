"""Pictures, and a method's passes over stored matrices, on threads while evaluate goes on
scoring and writing.

Evaluate's pictures (the difference matrices, the strips, the PR and Recall@N charts) are
independent of each other and of the tables written beside them, and most of a picture's
time is spent where Python lets go of the GIL: encoding the PNG (OpenCV's encoder,
:func:`placeloc.evaluation.raster.save_png`), decoding the strips' images, NumPy's
percentiles over a matrix. So the evaluate stage opens :func:`background` and its
contract and method hooks hand each picture to :func:`draw`; the stage waits for all of
them (:meth:`Pictures.wait`) before it writes the report, which shows them.

Outside :func:`background` (a method's own code, a test, ``placeloc show``) :func:`draw`
draws at once, on the caller's thread. A picture that fails fails the stage, as it would
drawn inline: the first error is raised by :meth:`Pictures.wait`, after every other
picture has finished, so no thread is left writing into a run folder that is being
cleaned up.

A method's own pass that mostly waits on the disk or runs in NumPy's GIL-free loops (SeqSLAM
reads its stored D and D^ for the dissimilarity ratio) goes to :func:`alongside`: it runs
on a thread of its own, not behind the pictures, while the stage writes its tables (which
hold the GIL), and the stage takes its figures with :meth:`Pictures.settle` before it
writes metrics.json. The pass returns its figures and a second function files them on the
stage's thread, so no thread writes into the evaluation while the stage reads it.
"""

from __future__ import annotations

import contextvars
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

# At most this many pictures at once: evaluate draws four or five, and each mostly waits on
# the GIL between its encoder's stretches, so more threads only add switching.
MOST_THREADS = 4

_CURRENT: contextvars.ContextVar[Pictures | None] = contextvars.ContextVar("placeloc_pictures", default=None)


class Pictures:
    """A small thread pool for pictures; ``threads`` 1 (or one core) draws inline."""

    def __init__(self, threads: int) -> None:
        self._pool = ThreadPoolExecutor(threads, thread_name_prefix="placeloc-picture") if threads > 1 else None
        self._futures: list[Future[Any]] = []
        # passes: a thread of their own (behind the pictures they would wait for a picture
        # thread), each with the function that files its result on the stage's thread
        self._passes = ThreadPoolExecutor(1, thread_name_prefix="placeloc-pass") if threads > 1 else None
        self._pending: list[tuple[Future[Any], Callable[[Any], None]]] = []

    def draw(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        if self._pool is None:
            fn(*args, **kwargs)
        else:
            self._futures.append(self._pool.submit(fn, *args, **kwargs))

    def alongside(self, fn: Callable[[], Any], then: Callable[[Any], None]) -> None:
        if self._passes is None:
            then(fn())
        else:
            self._pending.append((self._passes.submit(fn), then))

    def settle(self) -> None:
        """Wait for the passes handed over so far; raise the first one's error (after every
        pass has ended), else file their results in the order they were handed over."""
        pending, self._pending = self._pending, []
        _raise_first_error([f for f, _ in pending])
        for f, then in pending:
            then(f.result())

    def wait(self) -> None:
        """Wait for every picture handed over so far; raise the first one's error."""
        futures, self._futures = self._futures, []
        _raise_first_error(futures)

    def close(self) -> None:
        for pool in (self._pool, self._passes):
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)


def _raise_first_error(futures: list[Future[Any]]) -> None:
    """Wait for every one of ``futures``; then raise the first one's error, if any."""
    errors = [exc for exc in (f.exception() for f in futures) if exc is not None]
    if errors:
        raise errors[0]


def picture_threads() -> int:
    """Threads for pictures: the cores this process may use, at most :data:`MOST_THREADS`."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(MOST_THREADS, cores))


@contextmanager
def background(threads: int | None = None) -> Iterator[Pictures]:
    """Within the block, :func:`draw` hands pictures to a pool of ``threads`` (default
    :func:`picture_threads`); the block's end waits for them (and raises the first error),
    also when the block itself raised (then the block's error is the one raised)."""
    pics = Pictures(picture_threads() if threads is None else threads)
    token = _CURRENT.set(pics)
    try:
        yield pics
        pics.settle()
        pics.wait()
    finally:
        _CURRENT.reset(token)
        pics.close()


def draw(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
    """``fn(*args, **kwargs)``: on the open :func:`background` pool, else at once."""
    pics = _CURRENT.get()
    if pics is None:
        fn(*args, **kwargs)
    else:
        pics.draw(fn, *args, **kwargs)


def alongside(fn: Callable[[], Any], then: Callable[[Any], None]) -> None:
    """``then(fn())``: ``fn`` on the open :func:`background` block's pass thread and
    ``then`` on the stage's thread at its :meth:`Pictures.settle`; outside a block, at once.
    ``fn`` must not touch what the stage goes on using (it may read an open artifact: h5py
    serialises its calls); ``then`` files the result (metrics, arrays)."""
    pics = _CURRENT.get()
    if pics is None:
        then(fn())
    else:
        pics.alongside(fn, then)
