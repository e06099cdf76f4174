"""Result contracts: what a method's localize stage writes, and everything after it.

A method's localize writes exactly one contract into the group ``result`` of
``localize.h5`` (attribute ``kind``): ``ranked`` (query x K reference candidates),
``loops`` (per frame another frame that closes a loop, or none), ``poses`` (metric pose
estimates) or ``map`` (mapped point coordinates). The contract, not the method, owns the
up-front ground-truth check, the evaluate stage, ``placeloc show``, ``report.html``, the
headline figures ``placeloc run`` prints and the ``metrics.json`` schema. A method adds its
own figures through ``Method(result=..., evaluate_extra=hook)`` (an :class:`EvaluateHook`):
the hook receives the stage context and the kind's typed evaluation
(:class:`RankedEvaluation`, :class:`LoopEvaluation`, :class:`PoseEvaluation`,
:class:`MapEvaluation`) after scoring and may add metrics, PR curves and pictures from what
localize wrote; it never re-runs the method. docs/architecture.md ("Result contracts") has
the table.

Each kind's module (:mod:`.ranked`, :mod:`.loops`, :mod:`.pose_estimates`, :mod:`.maps`)
follows :class:`Contract`: a pure ``score(...)`` (arrays and ground truth in, the typed
evaluation out) and ``evaluate(ctx, result)`` that reads the ground truth and calls it;
``finish`` and :func:`evaluate_stage` persist what was scored.
"""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, Sequence

import h5py
import numpy as np

from placeloc.core.artifacts import read_strings, write_tree

KINDS = ("ranked", "loops", "poses", "map")
# contract kind -> the module implementing it (kinds of result, never method names)
_MODULES = {"ranked": "placeloc.evaluation.ranked", "loops": "placeloc.evaluation.loops",
            "poses": "placeloc.evaluation.pose_estimates", "map": "placeloc.evaluation.maps"}
GROUP = "result"


class ContractError(ValueError):
    """A result does not follow its contract (a bug in the method that wrote it, or an
    artifact from an older placeloc); the message names the dataset."""


@dataclass(frozen=True)
class Field:
    """One dataset of a contract: its element kind ('int', 'float', 'str', 'bool') and
    shape as names of lengths (``("Q", "K")``); ``optional`` ones may be absent."""

    dtype: str
    shape: tuple[str, ...]
    optional: bool = False


@dataclass
class Result:
    """A contract read back: its kind, datasets (numpy arrays; names as lists of str) and attributes."""

    kind: str
    data: dict[str, Any]
    attrs: dict[str, Any]

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    def get(self, key: str, default: Any = None) -> Any:
        return self.data.get(key, default)

    def __contains__(self, key: str) -> bool:
        return key in self.data


@dataclass
class Evaluation:
    """A scored contract, shared by the contract's evaluate, the method's hook and finish.

    ``metrics`` becomes metrics.json (a hook may add keys); ``arrays`` are written into
    evaluate.h5; ``pr_curves`` (label -> (recall, precision)) are drawn on one PR plot;
    ``label`` names the method's curve in legends. Each kind adds its typed per-item
    results in a subclass."""

    kind: str
    result: Result
    metrics: dict[str, Any] = field(default_factory=dict)
    arrays: dict[str, Any] = field(default_factory=dict)
    pr_curves: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    label: str = ""
    # the method's own pictures as report.html shows them (placeloc.evaluation.report.MethodPictures:
    # their order and captions), set by its evaluate_extra where it draws some; None: name order
    method_pictures: Any = None


@dataclass
class RankedEvaluation(Evaluation):
    """``ranked``: the ground truth, the Recall@N list, the file names by original index, the
    candidates' separation and the per-query scores (:class:`placeloc.evaluation.matching.MatchScores`)."""

    gt: Any = None
    ns: tuple[int, ...] = (1,)
    ref_names: list[str] = field(default_factory=list)
    q_names: list[str] = field(default_factory=list)
    separation: int = 0
    scores: Any = None


@dataclass
class LoopEvaluation(Evaluation):
    """``loops``: per frame of the result, whether its match is a candidate (old enough),
    accepted (a candidate at or above the method's threshold), right, whether the frame has
    a loop at all, one true earlier frame (-1: none), the match as a position in the frame
    list (-1: none); the PR curve, the truth matrix with its tolerance, the names by
    original index."""

    names: list[str] = field(default_factory=list)
    candidate: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    correct: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    has_loop: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    example: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    match_local: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    accepted: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    pr: Any = None
    truth: Any = None  # scipy CSR, lower triangular: row i holds the earlier frames that close a loop with i
    tolerance: int = 0


@dataclass
class PoseEvaluation(Evaluation):
    """``poses``: per frame the true and estimated position, the error (m), the yaw error and
    true heading (deg; None without headings), the poses read and each frame's row in them."""

    truth: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    est: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    err: np.ndarray = field(default_factory=lambda: np.zeros(0))
    yaw_err: np.ndarray | None = None
    truth_heading: np.ndarray | None = None
    poses: Any = None
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass
class MapEvaluation(Evaluation):
    """``map``: the evaluated features' estimates and truths (None without a truth file), their
    ids, the landmarks, and a path read out from the map with its truth (drawn when given)."""

    est: np.ndarray | None = None
    truth: np.ndarray | None = None
    eval_ids: np.ndarray | None = None
    landmarks: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    path_est: np.ndarray | None = None
    path_truth: np.ndarray | None = None


class EvaluateHook(Protocol):
    """A method's ``evaluate_extra``: adds its own figures to the kind's typed evaluation
    (metrics, arrays, PR curves, label, pictures into ``ctx.output``), reading only what its
    stages wrote."""

    def __call__(self, ctx: Any, ev: Any) -> None: ...


class Contract(Protocol):
    """What each kind's module provides (the four are checked against it in tests)."""

    SCHEMA: dict[str, Field]
    SECTIONS: tuple[str, ...]
    SHOW_AT_EVALUATE: bool
    CHOOSES_QUERIES: bool
    METRICS_DOC: dict[str, str]

    def check_ground_truth(self, config: dict[str, Any], method: Any) -> None: ...

    def evaluate(self, ctx: Any, res: Result) -> Evaluation: ...

    def finish(self, ctx: Any, ev: Any, plots: bool = True) -> None: ...

    def headline(self, metrics: dict[str, Any]) -> list[str]: ...

    def show(self, run_dir: Path, res: Result | None = None, *, sample: int = 8, failures: int = 8,
             out_dir: Path | None = None, ev: Any = None,
             config: dict[str, Any] | None = None) -> list[Path]: ...


def contract(kind: str) -> Contract:
    """The module implementing contract ``kind``."""
    if kind not in _MODULES:
        raise ContractError(f"unknown result kind {kind!r}; known: {', '.join(KINDS)}")
    return importlib.import_module(_MODULES[kind])


def _check_dtype(name: str, arr: np.ndarray, dtype: str, kind: str) -> None:
    ok = {"int": np.issubdtype(arr.dtype, np.integer), "float": np.issubdtype(arr.dtype, np.floating),
          "bool": arr.dtype == bool, "str": arr.dtype.kind in "OUS"}[dtype]
    if not ok:
        raise ContractError(f"result {kind!r}: dataset {name!r} holds {arr.dtype}, the contract says {dtype}")


def validate(kind: str, data: dict[str, Any]) -> None:
    """Check every dataset of ``data`` against ``kind``'s schema: present, element kind,
    and consistent lengths (the same letter is the same length everywhere)."""
    schema: dict[str, Field] = contract(kind).SCHEMA
    sizes: dict[str, int] = {}
    for name, spec in schema.items():
        if name not in data or data[name] is None:
            if spec.optional:
                continue
            raise ContractError(f"result {kind!r}: dataset {name!r} is missing")
        arr = np.asarray(data[name], dtype=object if spec.dtype == "str" else None)
        if arr.ndim != len(spec.shape):
            raise ContractError(f"result {kind!r}: dataset {name!r} has {arr.ndim} dimensions, the contract says "
                                f"{len(spec.shape)} ({' x '.join(spec.shape)})")
        if spec.dtype != "str" or arr.size:
            _check_dtype(name, arr, spec.dtype, kind)
        for letter, n in zip(spec.shape, arr.shape):
            if letter.isdigit():
                continue
            if sizes.setdefault(letter, n) != n:
                raise ContractError(f"result {kind!r}: dataset {name!r} has {letter} = {n}, another dataset {sizes[letter]}")
    unknown = set(data) - set(schema)
    if unknown:
        raise ContractError(f"result {kind!r}: datasets {sorted(unknown)} are not in the contract")


def write_result(parent: h5py.Group, kind: str, data: dict[str, Any], attrs: dict[str, Any] | None = None) -> h5py.Group:
    """Validate ``data`` and write it as ``parent/result`` with attribute ``kind``."""
    validate(kind, data)
    schema: dict[str, Field] = contract(kind).SCHEMA
    g = parent.create_group(GROUP)
    g.attrs["kind"] = kind
    for k, v in (attrs or {}).items():
        g.attrs[k] = v
    for name, arr in data.items():
        if arr is None:
            continue
        if schema[name].dtype == "str":
            g.create_dataset(name, data=np.array([str(x) for x in arr], dtype=object), dtype=h5py.string_dtype())
        else:
            g.create_dataset(name, data=np.asarray(arr))
    return g


def result_kind(f: h5py.File) -> str | None:
    """The contract kind a localize artifact holds (None: none)."""
    g = f.get(GROUP)
    return None if g is None else str(g.attrs.get("kind", ""))


def read_result(f: h5py.File | str | Path) -> Result:
    """The contract in a localize artifact (an open file or its path)."""
    if not isinstance(f, h5py.File):
        with h5py.File(f, "r") as fh:
            return read_result(fh)
    g = f.get(GROUP)
    if g is None or "kind" not in g.attrs:
        raise ContractError(f"{f.filename}: holds no result group; re-run localize (placeloc localize --force)")
    kind = str(g.attrs["kind"])
    schema: dict[str, Field] = contract(kind).SCHEMA
    data: dict[str, Any] = {}
    for name, spec in schema.items():
        if name not in g:
            if not spec.optional:
                raise ContractError(f"{f.filename}: result {kind!r} lacks dataset {name!r}; re-run localize --force")
            continue
        data[name] = read_strings(g[name]) if spec.dtype == "str" else g[name][()]
    attrs = {k: (v.item() if hasattr(v, "item") else v) for k, v in g.attrs.items()}
    return Result(kind, data, attrs)


def names_by_index(index: np.ndarray, names: list[str], n_listed: int) -> list[str]:
    """File names by original index (position in the folder's listing) from a contract's
    indices and names; images the contract does not hold (skipped) get ""."""
    out = [""] * max(int(n_listed), int(np.max(index)) + 1 if len(index) else 0)
    for i, nm in zip(index, names):
        out[int(i)] = nm
    return out


def localize_result(run_dir: str | Path) -> Result | None:
    """The contract of a run directory's localize.h5 (None when there is none yet)."""
    path = Path(run_dir) / "localize.h5"
    if not path.is_file():
        return None
    with h5py.File(path, "r") as f:
        if result_kind(f) is None:
            return None
        return read_result(f)


# ---------------------------------------------------------------------------------------
# What a run sees of the contracts
# ---------------------------------------------------------------------------------------
def check_ground_truth(config: dict[str, Any], method: Any) -> None:
    """The up-front ground-truth check, before any stage runs: ``method``'s contract
    builds its ground truth from the config and the image lists (a bad file or a missing
    frame is one error naming the file and the fix)."""
    kind = method.result_kind(config)
    if kind is not None:
        contract(kind).check_ground_truth(config, method)


def truth_given(config: dict[str, Any], method: Any) -> bool:
    """Whether evaluate has something to score ``method``'s result against. The map
    contract reports the map's own figures without a truth file; every other contract
    needs ``ground_truth`` (a user's own video or traverse usually has none: `placeloc run`
    then stops after localize instead of failing at evaluate)."""
    kind = method.result_kind(config)
    if kind is None or kind == "map":
        return True
    return (config.get("ground_truth") or {}).get("kind", "none") != "none"


def stage_seconds(run_dir: Path, stages: Sequence[str]) -> dict[str, float]:
    """Wall seconds each stage before evaluate took (its artifact's ``seconds``; a stage
    the method passes through took none)."""
    out: dict[str, float] = {}
    for stage in stages:
        path = Path(run_dir) / f"{stage}.h5"
        if stage == "evaluate" or not path.is_file():
            continue
        with h5py.File(path, "r") as f:
            if "seconds" in f.attrs:
                out[stage] = float(f.attrs["seconds"])
    return out


def add_timing(metrics: dict[str, Any], seconds: dict[str, float], frames: int) -> None:
    """The one timing key every contract reports: ``seconds_per_frame``, every stage before
    evaluate (extraction included) over the frames localized (queries, loop-closure frames,
    pose frames, mapped steps), with the stages' own seconds under ``stage_seconds``."""
    metrics["seconds_per_frame"] = sum(seconds.values()) / frames if frames > 0 and seconds else None
    metrics["stage_seconds"] = {k: round(v, 4) for k, v in seconds.items()}


def evaluate_stage(ctx: Any) -> None:
    """The evaluate stage every contract shares: score the localize result, let the
    method's hook add its figures, then write metrics.json, the per-query CSV, the
    contract's pictures, the strips and report.html."""
    from placeloc.core.stage_names import STAGES
    from placeloc.evaluation import write_metrics
    from placeloc.evaluation.pictures import background, draw

    res = read_result(ctx.artifact("localize"))
    mod = contract(res.kind)
    plots = bool(ctx.config.get("plots", True))
    # pictures handed to pictures.draw (the method's and the contract's) are drawn on threads
    # while the scoring and the tables go on; the block's end waits for them, before the
    # report that shows them
    with background() as side:
        ev: Evaluation = mod.evaluate(ctx, res)
        if not ev.label:
            ev.label = ctx.method.name
        # the strips from the evaluation in memory (not per_query.csv read back), so they are
        # drawn while the method's figures and the tables are made; side outputs are staged
        # in ctx.output_dir until the stage commits
        if plots and mod.SHOW_AT_EVALUATE:
            draw(mod.show, ctx.run_dir, res, out_dir=ctx.output_dir, ev=ev, config=ctx.config)
        if ctx.method.evaluate_extra is not None:
            ctx.method.evaluate_extra(ctx, ev)
        own_truth = method_truth(ctx.method, ctx.params)
        if own_truth:
            ev.metrics["scored_against"] = own_truth
        add_timing(ev.metrics, stage_seconds(ctx.run_dir, [s for s in STAGES if s in ctx.method.stages]), frames_of(ev))
        # the contract's tables and charts first (they hold the GIL), while a method's pass
        # handed to pictures.alongside runs; then its figures, then metrics.json
        mod.finish(ctx, ev, plots=plots)
        side.settle()
        write_tree(ctx.out, ev.arrays)
        ctx.out.attrs["result_kind"] = res.kind
        clean = write_metrics(ctx.output_dir, ordered(ev.metrics, getattr(mod, "COUNTS", ())), ctx.out)
    if plots:
        from placeloc.evaluation.report import write_report

        write_report(ctx.run_dir, config=ctx.config, out_dir=ctx.output_dir, method_pictures=ev.method_pictures,
                     **report_parts(res.kind, clean))


def method_truth(method: Any, params: Any) -> str:
    """The truth a method reads from its own section (``Method(truth_keys=...)``, e.g.
    co-embedding's ``coembed.truth`` and ``coembed.poses``) as "section.key=path" items, so
    that metrics.json and the report name what was scored against; "" for none."""
    keys = dict.fromkeys((getattr(method, "truth_keys", None) or {}).values())
    return ", ".join(f"{method.name}.{k}={getattr(params, k)}" for k in keys if getattr(params, k, None) is not None)


def frames_of(ev: Evaluation) -> int:
    """The frames a result localized: its queries (ranked), frames (loops, poses) or mapped
    steps (map; the method's ``n_steps`` when it reports one, else the features)."""
    m = ev.metrics
    for key in ("n_queries", "n_frames", "n_steps", "n_features"):
        if isinstance(m.get(key), int):
            return int(m[key])
    return 0


def ordered(metrics: dict[str, Any], counts: Sequence[str]) -> dict[str, Any]:
    """metrics.json's order: the headline, the other figures, the time, then the counts and
    settings (the kind's ``COUNTS``, every ``n_*``, and the words: the comparison, solver,
    mode... a method names), then ``headline`` itself."""
    head = [k for k in metrics.get("headline", []) if k in metrics]
    tail = [k for k in metrics if (k in counts or k.startswith("n_") or isinstance(metrics[k], (str, bool)))
            and k not in head and k != "headline"]
    timing = [k for k in ("seconds_per_frame", "stage_seconds") if k in metrics]
    rest = [k for k in metrics if k not in head and k not in tail and k not in timing and k != "headline"]
    out = {k: metrics[k] for k in [*head, *rest, *timing, *tail]}
    if "headline" in metrics:
        out["headline"] = metrics["headline"]
    return out


def headline(run_dir: str | Path) -> list[tuple[str, Any]]:
    """The headline figures of an evaluated run (name, value), in the contract's order,
    from metrics.json; empty when there is none."""
    run_dir = Path(run_dir)
    path = run_dir / "metrics.json"
    res_kind = None
    lo = run_dir / "localize.h5"
    if lo.is_file():
        with h5py.File(lo, "r") as f:
            res_kind = result_kind(f)
    if not path.is_file() or res_kind is None:
        return []
    return headline_of(res_kind, json.loads(path.read_text()))


def report_parts(kind: str | None, metrics: dict[str, Any] | None) -> dict[str, Any]:
    """What report.html shows of the contract: its kind, the headline figures and the
    documented meaning of its metrics (keyword arguments of ``write_report``)."""
    if kind is None:
        return {}
    doc = getattr(contract(kind), "METRICS_DOC", {})
    if metrics:  # explain only the figures this run reports (retrieval has no separated recall)
        doc = {k: v for k, v in doc.items() if _reported(k, metrics)}
    return {"result_kind": kind, "headline": headline_of(kind, metrics) if metrics else [], "metrics_doc": doc}


def _reported(doc_key: str, metrics: dict[str, Any]) -> bool:
    """Whether a documented key ("recall_at_N", "within_0_5m / within_1m", ...) names a key
    of ``metrics`` (N standing for any number)."""
    import re

    for name in doc_key.split(" / "):
        pattern = re.escape(name.strip()).replace("_N", "_[0-9]+")
        if any(re.fullmatch(pattern, k) for k in metrics):
            return True
    return False


def headline_of(kind: str, metrics: dict[str, Any]) -> list[tuple[str, Any]]:
    """The headline figures (name, value) of ``metrics`` for a result of ``kind``."""
    return [(k, metrics[k]) for k in contract(kind).headline(metrics) if k in metrics]
