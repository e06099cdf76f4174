"""The method registry: what each method is called, its config section and its stages.

A method lives in its own subpackage (``pipeline/<name>/``) that exposes ``METHOD``, a
:class:`Method`. Stage functions receive a :class:`pipeline.runner.StageContext` and write
their arrays into ``ctx.out`` (an open HDF5 group); they never open artifacts or parse
YAML themselves. A stage a method does not define passes its input through.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable

STAGES = ("extract", "build-dictionary", "index", "localize", "evaluate")

# name -> module that defines METHOD; imported lazily so one method's deps never load another's.
METHOD_MODULES: dict[str, str] = {
    "seqslam": "pipeline.seqslam.stages",
    "umap": "pipeline.umap.stages",
    "coembed": "pipeline.coembed.stages",
    "pirf": "pipeline.pirf.stages",
}
METHOD_NAMES = tuple(METHOD_MODULES)


@dataclass
class Method:
    name: str
    defaults: dict[str, Any]
    stages: dict[str, Callable[[Any], None]]
    choices: dict[str, tuple] = field(default_factory=dict)
    path_keys: tuple[str, ...] = ()
    # Method-section keys each stage depends on; a stage not listed depends on all of them.
    stage_keys: dict[str, tuple[str, ...]] = field(default_factory=dict)
    # Image traverses the method needs (validated up front); the others are optional.
    required_images: tuple[str, ...] = ("reference",)
    # Extra whole-config checks (cross-field rules); raise ConfigError.
    checker: Callable[[dict], None] | None = None
    description: str = ""

    @property
    def uses_images(self) -> bool:
        return bool(self.required_images)

    def check(self, config: dict) -> None:
        if self.checker is not None:
            self.checker(config)


def get_method(name: str) -> Method:
    if name not in METHOD_MODULES:
        raise KeyError(f"unknown method {name!r}; known: {', '.join(METHOD_NAMES)}")
    return importlib.import_module(METHOD_MODULES[name]).METHOD
