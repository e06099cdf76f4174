"""placeloc's error types: a leaf module (it imports nothing of placeloc), so every layer
can raise them without importing the layer that defines the behaviour.

- :class:`ConfigError`: a config value is missing, unknown, of the wrong type or points
  nowhere (the message names the key and the fix);
- :class:`StageError`: a stage cannot run (missing parent, bad input); the message says
  what to do;
- :class:`RunDirError`: the run directory cannot be used (locked, an image folder, a
  foreign ``config.yaml``);
- :class:`EnvironmentFailure`: the machine failed the run, not the input and not
  placeloc (a worker process killed, by the out-of-memory killer most often); the message
  says what to change.

The command line's error boundary (``placeloc.cli.classify``) sorts every exception into
one of three kinds: ``user`` (one line naming the file or key and the fix, rc 2),
``environment`` (one line, rc 3) and ``bug`` (traceback and where to report it, rc 1).
"""

from __future__ import annotations


class ConfigError(ValueError):
    """A config value is missing, unknown, of the wrong type or points nowhere."""


class StageError(RuntimeError):
    """A stage cannot run (missing parent, bad input); the message says what to do."""


class RunDirError(StageError):
    """The run directory cannot be used (locked by another run, an image folder, a foreign config.yaml)."""


class EnvironmentFailure(RuntimeError):
    """The machine failed the run (a worker killed, memory exhausted); the message says what to change."""


class WorkerLostError(EnvironmentFailure):
    """A worker process died while it ran a work item (killed with SIGKILL: usually the
    out-of-memory killer)."""


class ModelError(ValueError):
    """A map model file (wireframe, floor plan, ZInD home) cannot be used; the message names
    the file and the fix. Here, not in geometry.floorplan, so that the ZInD importer and the
    floor-plan loader (which reads ZInD homes through it) need not import each other."""
