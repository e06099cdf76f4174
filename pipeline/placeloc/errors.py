"""placeloc's error types: a leaf module (it imports nothing of placeloc), so every layer
can raise them without importing the layer that defines the behaviour.

- :class:`ConfigError`: a config value is missing, unknown, of the wrong type or points
  nowhere (the message names the key and the fix);
- :class:`StageError`: a stage cannot run (missing parent, bad input); the message says
  what to do;
- :class:`RunDirError`: the run directory cannot be used (locked, an image folder, a
  foreign ``config.yaml``).
"""

from __future__ import annotations


class ConfigError(ValueError):
    """A config value is missing, unknown, of the wrong type or points nowhere."""


class StageError(RuntimeError):
    """A stage cannot run (missing parent, bad input); the message says what to do."""


class RunDirError(StageError):
    """The run directory cannot be used (locked by another run, an image folder, a foreign config.yaml)."""
