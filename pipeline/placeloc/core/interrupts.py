"""Ctrl-C and SIGTERM that are never lost.

Python delivers a signal as an exception in whatever code runs at that moment. When that
is a garbage-collection callback (a weakref finaliser, a ``__del__``), the exception is
printed as "Exception ignored" and swallowed, and the run goes on as if nothing happened.
So the command line's handler also records the signal, and the runner checks the record
at every step (:func:`raise_if_interrupted`), and the error boundary once more at the end.
"""

from __future__ import annotations

import signal
import sys
from typing import Any, Callable

_received: list[int] = []


class Terminated(KeyboardInterrupt):
    """SIGTERM, turned into an exception so that cleanup (temporary files, shared arrays,
    worker pools) runs as it does for Ctrl-C."""


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


_on_repeat: list[Callable[[int], None]] = []


def _handler(signum: int, frame: Any) -> None:
    _received.append(signum)
    if len(_received) > 1 and _on_repeat:
        # A second signal while the first is still being handled: the user wants out now,
        # whatever the cleanup is waiting for (the next run removes what is left).
        _on_repeat[0](signum)
    raise _exception(signum)


def _unraisable(unraisable: Any, default: Any = sys.unraisablehook) -> None:
    # The swallowed interrupt is recorded and raised again later: no "Exception ignored" text.
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and _received:
        return
    default(unraisable)


def install(on_repeat: Callable[[int], None] | None = None) -> None:
    """Handle SIGINT and SIGTERM as above (the command line calls this once).
    ``on_repeat(signum)`` is called for a second signal instead of raising again (the
    command line exits at once there)."""
    _on_repeat[:] = [on_repeat] if on_repeat is not None else []
    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)
    sys.unraisablehook = _unraisable


def received() -> int | None:
    """The last signal received, or None."""
    return _received[-1] if _received else None


def raise_if_interrupted() -> None:
    """Raise the interrupt again if a signal came and its exception was swallowed."""
    if _received:
        raise _exception(_received[-1])
