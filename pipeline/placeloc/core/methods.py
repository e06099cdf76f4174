"""The method registry and the one template every method follows.

A method lives in its own subpackage (``pipeline/placeloc/<name>/``, imported as
``placeloc.<name>``) whose ``stages.py`` exposes ``METHOD``, a :class:`Method`:

- ``params``: the method's parameter dataclass (``<name>/params.py``, see
  :mod:`placeloc.core.params`): the one home of every default, type, range and help text;
- ``stages``: stage name -> :class:`Stage`, the function plus exactly the parameters and
  common config sections its result depends on.

Stage functions receive a :class:`placeloc.core.runner.StageContext`, read their inputs through
it, call the method's numerical modules with explicit keyword arguments taken from
``ctx.params`` and write arrays into ``ctx.out`` (an open HDF5 group) and side outputs
(CSV, JSON, PNG) through ``ctx.output(name)``. They never open another stage's artifact
by path or parse YAML. A stage a method does not define passes its input through.
``docs/architecture.md`` walks through adding a method.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from placeloc.core import params as P
from placeloc.core.stage_names import STAGES  # noqa: F401 - the one list, re-exported as placeloc.core.methods.STAGES


def _discover() -> dict[str, str]:
    """Method name -> module defining METHOD: every subpackage ``placeloc/<name>/`` with a
    ``stages.py`` is a method (found by listing the package folder, nothing imported), so
    adding a method registers nothing by hand. Imported lazily, so one method's
    dependencies never load another's."""
    root = Path(__file__).resolve().parent.parent  # the package placeloc/, above core/
    return {d.name: f"placeloc.{d.name}.stages" for d in sorted(root.iterdir())
            if d.is_dir() and (d / "stages.py").is_file() and (d / "__init__.py").is_file()}


METHOD_MODULES: dict[str, str] = _discover()
METHOD_NAMES = tuple(METHOD_MODULES)

# Common config sections every stage depends on.
BASE_SECTIONS = ("method", "seed", "reference", "query")


@dataclass(frozen=True)
class Stage:
    """One stage of a method: its function and exactly what its result depends on.

    ``keys`` are dotted keys of the method's parameters (``"ds"``, ``"ca.tie_tol"``; a
    section name covers the whole section); ``sections`` are common config sections beyond
    method, seed, reference and query (``"ground_truth"``, ``"plots"``), or one key of one,
    dotted (``"ground_truth.exclude_recent"``). Changing anything else does not re-run the
    stage. Images, files named by path parameters and the parent
    artifact are always inputs; a key an earlier stage declares reaches this one through
    the parent's stamp, and a key declared ``affects_result=False`` (block and task sizes)
    needs no declaration. tests/test_stage_keys.py runs every method with a parameter
    object that records what each stage reads and fails on any difference.
    """

    run: Callable[[Any], None]
    keys: tuple[str, ...] = ()
    sections: tuple[str, ...] = ()
    # The earlier stages whose artifacts it reads (:meth:`Method.stage_parents`). None: the
    # stage just before it, so that it depends on every stage before it and, through the
    # first, on the images. A stage that needs less says so, and then re-runs only when what
    # it reads changed: UMap's map database is drawn from the floor plan alone (``()``), so
    # adding a photo does not draw the map again nor rewrite its 0.7 GB index. The runner
    # lets a stage open only the artifacts of its parents and theirs, and gives it the images
    # only where the first stage is among them.
    parents: tuple[str, ...] | None = None


@dataclass
class Method:
    name: str
    params: type
    stages: dict[str, Stage]
    # Image traverses the method needs (validated up front); the others are optional.
    required_images: tuple[str, ...] = ("reference",)
    # Extra whole-config checks (cross-field rules); raise ConfigError.
    checker: Callable[[dict], None] | None = None
    # Published source, by authors, title, venue and year (shown by `placeloc inspect`).
    citation: str = ""
    # What the stages need of memory and disk, checked before any stage runs: a module with
    # needs(config, images, stages), BASE_MEMORY and optionally config_rules(config) and
    # input_rules(config, images) (see placeloc.core.limits and e.g. placeloc.seqslam.resources).
    resources: Any = None
    # The result contract its localize writes (placeloc.evaluation.contracts: ranked, loops,
    # poses, map). The contract supplies the evaluate stage (unless the method defines one),
    # the up-front ground-truth check, `placeloc show` and the report.
    result: str | None = None
    # The contract written when the config names no query traverse, if another (SeqSLAM: loops).
    result_without_query: str | None = None
    # Optional hook(ctx, evaluation) run by the contract's evaluate after scoring: the method's
    # own metrics and figures. evaluate_keys: the method parameters the hook reads.
    evaluate_extra: Callable[[Any, Any], None] | None = None
    evaluate_keys: tuple[str, ...] = ()
    # Optional hook(run folder, its result, folder to draw into, *, evaluated, sample, failures,
    # config) -> paths: the method's own pictures that `placeloc show` draws (UMap: each
    # panorama's lines against the map at its answer): for a run not evaluated (no ground
    # truth), where evaluate_extra never ran, and for an evaluated one where show's --sample or
    # --failures (None: not given) ask for another choice than evaluate's.
    show_extra: Callable[..., list[Path]] | None = None
    # Optional hook(run folder, *, evaluated, sample, failures) -> placeloc.evaluation.report.MethodPictures
    # or None: the order and captions report.html gives the method's own pictures, as `placeloc
    # show` (its options) chose them; evaluate hands its choice over in the evaluation instead.
    report_pictures: Callable[..., Any] | None = None
    # Where the contract finds ground truth the method's own parameters name (role -> parameter),
    # e.g. the map contract's {"points": "truth"}; the shared ground_truth section otherwise.
    truth_keys: dict[str, str] = field(default_factory=dict)
    # Path parameters whose file only a later stage reads (key -> that stage): the file is part
    # of that stage's inputs, so editing it re-runs that stage on, not the ones before it.
    # Every other path parameter's file is an input of the first stage.
    file_stages: dict[str, str] = field(default_factory=dict)
    defaults: dict[str, Any] = field(init=False)
    choices: dict[str, tuple] = field(init=False)
    path_keys: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        self.defaults = P.defaults(self.params)
        self.choices = P.choices(self.params)
        self.path_keys = P.path_keys(self.params)
        if self.result is not None and "evaluate" not in self.stages:
            from placeloc.evaluation.contracts import contract, evaluate_stage

            sections = set(contract(self.result).SECTIONS)
            if self.result_without_query is not None:
                sections |= set(contract(self.result_without_query).SECTIONS)
            self.stages = {**self.stages, "evaluate": Stage(evaluate_stage, keys=self.evaluate_keys,
                                                            sections=tuple(sorted(sections)))}
        known = set(self.defaults) | {k for k, _ in P._walk(self.params)}
        for name, stage in self.stages.items():
            if name not in STAGES:
                raise ValueError(f"{self.name}: unknown stage {name!r}")
            for key in stage.keys:
                if key not in known:
                    raise ValueError(f"{self.name}.{name} depends on unknown parameter {key!r}")
        for key, name in self.file_stages.items():
            if key not in self.path_keys or name not in self.stages or key not in self.stages[name].keys:
                raise ValueError(f"{self.name}: file_stages names {key!r} for stage {name!r}: it must be a path "
                                 "parameter that stage declares")
        for name, stage in self.stages.items():
            for parent in stage.parents or ():
                if parent not in STAGES or STAGES.index(parent) >= STAGES.index(name):
                    raise ValueError(f"{self.name}.{name} names {parent!r} among its parents: a parent is an "
                                     f"earlier stage ({', '.join(STAGES[:STAGES.index(name)]) or 'none'})")

    def stage_parents(self, name: str) -> tuple[str, ...]:
        """The stages whose artifacts stage ``name`` reads directly: its declared
        :attr:`Stage.parents`, else the stage before it (none for the first)."""
        declared = self.stages.get(name)
        if declared is not None and declared.parents is not None:
            return tuple(declared.parents)
        i = STAGES.index(name)
        return (STAGES[i - 1],) if i > 0 else ()

    def stage_ancestors(self, name: str) -> frozenset[str]:
        """Every stage whose artifact stage ``name`` depends on: its parents, theirs, ..."""
        found: set[str] = set()
        todo = list(self.stage_parents(name))
        while todo:
            p = todo.pop()
            if p not in found:
                found.add(p)
                todo.extend(self.stage_parents(p))
        return frozenset(found)

    def result_kind(self, config: dict) -> str | None:
        """The result contract this method's localize writes for ``config``."""
        if self.result_without_query is not None and not (config.get("query") or {}).get("images"):
            return self.result_without_query
        return self.result

    @property
    def uses_images(self) -> bool:
        return bool(self.required_images)

    def check(self, config: dict) -> None:
        if self.checker is not None:
            self.checker(config)

    def build_params(self, config: dict) -> Any:
        """The parameter object for a validated config."""
        return P.from_section(self.params, config[self.name])


def get_method(name: str) -> Method:
    if name not in METHOD_MODULES:
        raise KeyError(f"unknown method {name!r}; known: {', '.join(METHOD_NAMES)}")
    return importlib.import_module(METHOD_MODULES[name]).METHOD
