"""placeloc: appearance-based localization as a staged batch pipeline.

The package is called ``pipeline`` (the design card's top-level name); the distribution
and the console script are ``placeloc``.
"""

__version__ = "0.1.0"
