"""The five stages of every method, in order: the one list.

A leaf module (it imports nothing), so the registry (:mod:`placeloc.core.methods`), the runner
and the readers of a run directory (the report) share it without importing each other.
"""

STAGES = ("extract", "build-dictionary", "index", "localize", "evaluate")
