"""Every stage declares exactly the parameters it reads (``Stage(keys=..., sections=...)``).

The runner re-runs a stage when a declared key changes and only then, so a key a stage
reads but does not declare leaves a stale result "up to date" (``--set`` has no effect),
and a declared key it never reads re-runs it for nothing. This test runs every
registered method on a tiny smoke configuration (and a few variants, so the keys read
only in one branch are read at least once; all in one run directory, as a user's
``--set`` would), hands each stage a parameter object and a
config that record every attribute and section it reads, and compares:

- read but not declared: an error, unless one of its ancestors declares the key (its
  parents' stamps carry it: ``Method.stage_ancestors``, every earlier stage unless a stage
  names fewer parents) or the key is declared ``affects_result=False`` (block and task sizes);
- declared but never read in any run of the variants: an error.

What counts as a read: attribute access on ``ctx.params`` (nested sections as
``ca.tie_tol``; reading a section object alone does not count, its fields do) and
``ctx.config[...]`` / ``ctx.config.get(...)`` of a top-level section (of one key of it,
``ground_truth.exclude_recent``, when only that key is read), anywhere below
the stage function in this process. Work items sent to other processes get the plain
parameter object, so the smoke runs use one worker. ``method``, ``seed``, ``reference``
and ``query`` are every stage's inputs already; ``executor`` changes where work runs;
``report.html`` shows the whole config, so what the report writer reads is not counted.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest
import yaml

from placeloc.core import methods as M
from placeloc.core import params as P
from placeloc.core.config import load_config
from placeloc.core.methods import BASE_SECTIONS, STAGES, Method, Stage
from placeloc.core.runner import IMAGE_SECTIONS, sees_images

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
ALWAYS_READABLE = set(BASE_SECTIONS) | {"executor"}


# ---------------------------------------------------------------------------- recording
class _Recorder:
    """Stands in for a parameter object and notes the dotted name of every field read."""

    __slots__ = ("_obj", "_prefix", "_reads")

    def __init__(self, obj: Any, prefix: str, reads: set[str]) -> None:
        object.__setattr__(self, "_obj", obj)
        object.__setattr__(self, "_prefix", prefix)
        object.__setattr__(self, "_reads", reads)

    def __getattr__(self, name: str) -> Any:
        obj = object.__getattribute__(self, "_obj")
        fields = {f.name for f in dataclasses.fields(obj)}
        value = getattr(obj, name)
        if name not in fields:
            attr = getattr(type(obj), name, None)
            if isinstance(attr, property):  # a derived value: record the fields it reads
                return attr.fget(self)
            if callable(attr):
                return attr.__get__(self)
            return value
        key = object.__getattribute__(self, "_prefix") + name
        if dataclasses.is_dataclass(value):
            return _Recorder(value, key + ".", object.__getattribute__(self, "_reads"))
        object.__getattribute__(self, "_reads").add(key)
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        raise dataclasses.FrozenInstanceError(name)

    def __reduce__(self) -> Any:
        # Sent to another process: the plain object (reads there are not recorded).
        return (_identity, (object.__getattribute__(self, "_obj"),))


def _identity(x: Any) -> Any:
    return x


class _RecordingConfig(dict):
    """The validated config, noting every top-level section read by key; a section that is
    a mapping notes ``section.key`` for each key read from it, and the whole section when it
    is iterated or copied (so a stage may declare one key of a common section, dotted)."""

    def __init__(self, data: dict, reads: set[str], prefix: str = "") -> None:
        super().__init__(data)
        self.reads = reads
        self.prefix = prefix

    def _wrap(self, key: str, value: Any) -> Any:
        if isinstance(value, dict) and not self.prefix:
            return _RecordingConfig(value, self.reads, f"{key}.")
        self.reads.add(self.prefix + key)
        return value

    def __getitem__(self, key: str) -> Any:
        return self._wrap(key, super().__getitem__(key))

    def get(self, key: str, default: Any = None) -> Any:
        return self._wrap(key, super().get(key, default))

    def _whole(self) -> None:
        if self.prefix:
            self.reads.add(self.prefix[:-1])

    def __iter__(self) -> Any:
        self._whole()
        return super().__iter__()

    def items(self) -> Any:
        self._whole()
        return super().items()

    def values(self) -> Any:
        self._whole()
        return super().values()

    def keys(self) -> Any:
        self._whole()
        return super().keys()


yaml.add_representer(_RecordingConfig, yaml.SafeDumper.represent_dict, Dumper=yaml.SafeDumper)


@dataclasses.dataclass
class Reads:
    keys: dict[str, set[str]] = dataclasses.field(default_factory=lambda: {s: set() for s in STAGES})
    sections: dict[str, set[str]] = dataclasses.field(default_factory=lambda: {s: set() for s in STAGES})
    ran: set[str] = dataclasses.field(default_factory=set)


def recording_method(method: Method, reads: Reads) -> Method:
    """A copy of ``method`` whose stages record what they read into ``reads``."""

    def wrap(name: str, stage: Stage) -> Stage:
        def run(ctx: Any) -> None:
            reads.ran.add(name)
            ctx.params = _Recorder(ctx.params, "", reads.keys[name])
            ctx.config = _RecordingConfig(ctx.config, reads.sections[name])
            stage.run(ctx)

        return dataclasses.replace(stage, run=run)

    return dataclasses.replace(method, stages={n: wrap(n, s) for n, s in method.stages.items()})


def run_recorded(config: dict, run_dir: Path, method: Method, reads: Reads, monkeypatch: pytest.MonkeyPatch,
                 last: str = STAGES[-1]) -> None:
    from placeloc.core import runner
    from placeloc.evaluation import report

    recorder = recording_method(method, reads)
    monkeypatch.setattr(runner, "get_method", lambda name: recorder)
    # report.html shows the whole config (a picture of the settings, not an input of a
    # result): what it reads is not counted.
    write_report = report.write_report
    monkeypatch.setattr(report, "write_report",
                        lambda *a, config=None, **k: write_report(*a, config=None if config is None else dict(dict.items(config)),
                                                                  **k))
    try:
        runner.run_stage(config, run_dir, last, quiet=True)
    finally:
        monkeypatch.undo()


# ---------------------------------------------------------------------------- the check
def _covers(declared: tuple[str, ...], key: str) -> bool:
    """A declared key covers itself; a declared section name covers its fields."""
    return any(key == d or key.startswith(d + ".") for d in declared)


def problems(method: Method, reads: Reads) -> list[str]:
    """Every disagreement between what the stages declare and what they read."""
    layout = set(P.work_layout_keys(method.params))
    out = []
    for name in STAGES:
        stage = method.stages.get(name)
        if stage is None:
            continue
        # what its ancestors declare reaches it through its parents' stamps
        ancestors = [method.stages[a] for a in method.stage_ancestors(name) if a in method.stages]
        earlier_keys = tuple(k for a in ancestors for k in a.keys)
        earlier_sections = tuple(sec for a in ancestors for sec in a.sections)
        if name not in reads.ran:
            out.append(f"{method.name}.{name}: did not run in any smoke variant")
            continue
        for key in sorted(reads.keys[name]):
            # an ancestor's key reaches this one through its parents' stamps
            if key not in layout and not _covers(stage.keys, key) and not _covers(earlier_keys, key):
                out.append(f"{method.name}.{name}: reads {key!r}, not declared in its Stage(keys=...)")
        for key in stage.keys:
            if not any(r == key or r.startswith(key + ".") for r in reads.keys[name]):
                out.append(f"{method.name}.{name}: declares {key!r} but never reads it")
        for sec in sorted(reads.sections[name]):
            top = sec.split(".")[0]
            if top in IMAGE_SECTIONS and not sees_images(method, name):
                # its stamp leaves the image sections out (a stage that does not depend on the images)
                out.append(f"{method.name}.{name}: reads section {top!r}, but no image reaches it (Stage.parents)")
                continue
            if top in ALWAYS_READABLE:
                continue
            if top == method.name:
                out.append(f"{method.name}.{name}: reads ctx.config[{top!r}]; read ctx.params instead")
            elif not _covers(stage.sections, sec) and not _covers(earlier_sections, sec):
                out.append(f"{method.name}.{name}: reads section {sec!r}, not declared in its Stage(sections=...)")
        for sec in stage.sections:
            # a declared section (or one key of it, dotted) is read by any read below it, or
            # by a read of its whole section
            if not any(_covers((sec,), r) or sec.startswith(r + ".") for r in reads.sections[name]):
                out.append(f"{method.name}.{name}: declares section {sec!r} but never reads it")
    return out


# ---------------------------------------------------------------------------- smoke configs
def _preset(name: str, moves: dict[str, str], overrides: dict[str, Any] | None = None) -> dict:
    """A preset of configs/ with its data paths moved (``moves``: old prefix -> new) and
    keys merged in; one worker, no Dask, so every read happens in this process."""
    text = (CONFIGS / name).read_text()
    for old, new in moves.items():
        text = text.replace(old, new)
    data = yaml.safe_load(text)
    data["executor"] = {"kind": "local", "workers": 1}
    for dotted, value in (overrides or {}).items():
        node = data
        *parents, leaf = dotted.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return load_config(data=data, base_dir=CONFIGS)


Variant = "dict | tuple[dict, str]"  # a config, or a config and the last stage to run


def _route_descriptors(tmp: Path) -> None:
    """tmp/ref.npy and tmp/query.npy: 16 random numbers for each image of the bundled route
    (what a user's own descriptors look like to the stages)."""
    rng = np.random.default_rng(0)
    n_ref = len(list((ROOT / "data-samples" / "route" / "reference").glob("*.png")))
    n_query = len(list((ROOT / "data-samples" / "route" / "query").glob("*.png")))
    np.save(tmp / "ref.npy", rng.standard_normal((n_ref, 16)).astype(np.float32))
    np.save(tmp / "query.npy", rng.standard_normal((n_query, 16)).astype(np.float32))


def seqslam_variants(tmp: Path) -> list[Variant]:
    """configs/demo.yaml (the bundled route) and variants reaching the other branches."""
    _route_descriptors(tmp)
    base = {"plots": False}
    return [
        _preset("demo.yaml", {}, {"plots": True}),
        _preset("demo.yaml", {}, {**base, "seqslam.comparison": "sad", "seqslam.sequence_shape": "cone",
                                  "seqslam.v_auto": True, "seqslam.store_difference": False}),
        _preset("demo.yaml", {}, {**base, "seqslam.comparison": "isc", "seqslam.sequence_shape": "hybrid",
                                  "seqslam.search": "centred", "seqslam.edges": "shift"}),
        _preset("demo.yaml", {}, {**base, "seqslam.comparison": "ocm", "seqslam.normalisation": "zscore"}),
        _preset("demo.yaml", {}, {**base, "seqslam.descriptors_reference": str(tmp / "ref.npy"),
                                  "seqslam.descriptors_query": str(tmp / "query.npy"),
                                  "seqslam.descriptor_distance": "l2"}),
        # loop mode (no query: the loops contract, exclude_recent) on the PIRF smoke video
        _preset("seqslam-loops-smoke.yaml", {"../runs/data/omni-smoke": str(_omni_smoke(tmp))}, {"plots": True}),
    ]


def _omni_smoke(tmp: Path) -> Path:
    """The 80-frame omnidirectional loop of configs/pirf-smoke.yaml's header, made once per test."""
    from placeloc.synth.omni import generate

    data = tmp / "omni-smoke"
    if not (data / "mapping" / "poses.csv").is_file():
        generate(data, seed=0, frames=80, test_frames=40, width=240, layout="small", step=0.3)
    return data


def retrieval_variants(tmp: Path) -> list[Variant]:
    """configs/retrieval.yaml (the bundled route), brought descriptors with L2, each search."""
    _route_descriptors(tmp)
    return [
        _preset("retrieval.yaml", {}),
        _preset("retrieval.yaml", {}, {"plots": False, "retrieval.search": "faiss", "retrieval.distance": "l2",
                                       "retrieval.descriptors_reference": str(tmp / "ref.npy"),
                                       "retrieval.descriptors_query": str(tmp / "query.npy")}),
        _preset("retrieval.yaml", {}, {"plots": False, "retrieval.search": "exact", "retrieval.top_k": 5}),
        # loop mode (no query: each frame against the earlier ones, ground_truth.exclude_recent)
        (_preset("retrieval.yaml", {}, {"plots": False, "query.images": None, "ground_truth.kind": "none",
                                        "ground_truth.path": None, "ground_truth.exclude_recent": 20}), "localize"),
    ]


def pirf_variants(tmp: Path) -> list[dict]:
    """configs/pirf-smoke.yaml on its 80-frame generated loop, as its header makes it, and a
    six-frame folder whose last frame is blank."""
    data = _omni_smoke(tmp)
    moves = {"../runs/data/omni-smoke": str(data)}
    # blank_frames is read when a frame has no features: six frames, the last one blank
    blank = tmp / "blank"
    blank.mkdir()
    frames = sorted((data / "mapping").glob("*.png"))[:5]
    for f in frames:
        shutil.copy(f, blank / f.name)
    import cv2

    cv2.imwrite(str(blank / "zz_blank.png"), np.full_like(cv2.imread(str(frames[0])), 128))
    return [
        _preset("pirf-smoke.yaml", moves),
        _preset("pirf-smoke.yaml", moves, {"plots": False, "pirf.map_search": "faiss-hnsw", "pirf.update": "plain",
                                           "pirf.index": "bruteforce", "pirf.index_recall": None,
                                           "pirf.compare_bf": False, "pirf.verify_frames": 0,
                                           "pirf.direction_correction": False}),
        (load_config(data={"method": "pirf", "reference": {"images": str(blank)}, "executor": {"workers": 1},
                           "pirf": {"blank_frames": "empty", "n_pmin": 1}}), "extract"),
    ]


def umap_variants(tmp: Path) -> list[dict]:
    """The eight-frame corridor of tests/test_umap_method.py, alone and with CA; the
    panorama variants; two look-alike rooms with a photo's room named."""
    from test_umap_method import _tiny_corridor

    _tiny_corridor(tmp)
    base = {"method": "umap", "query": {"images": str(tmp / "q")}, "executor": {"workers": 1},
            "ground_truth": {"kind": "poses", "path": str(tmp / "poses.csv")},
            "umap": {"model": str(tmp / "plan.yaml"), "sensor_csv": str(tmp / "sensor.csv"), "mode": "umap",
                     "grid": {"x": [0.4, 11.6, 0.2], "y": [0.4, 2.0, 0.4], "z": 1.14,
                              "headings": [45.0, 135.0, 225.0, 315.0]}},
            "plots": True}
    ca = {**base, "plots": False, "umap": {**base["umap"], "mode": "umap+ca"}}
    from test_umap_room_hints import _twins_run

    # a plan of rooms with a photo's room named (umap.room_hints reads room_hint_margin_m)
    rooms = _twins_run(tmp / "rooms", "frame,room\na.png,room_1 (bedroom)\n")
    return [load_config(data=base, base_dir=tmp), load_config(data=ca, base_dir=tmp),
            *_umap_panorama_variants(tmp / "pano"), rooms]


def _umap_panorama_variants(tmp: Path) -> list[dict]:
    """Three grey panoramas of the room of tests/test_umap_panorama.py: whole panoramas
    (yaw searched, chamfer score with the local refinement) and equirect views."""
    import csv

    import cv2
    from test_umap_panorama import PLAN, _grey_panorama

    (tmp / "q").mkdir(parents=True)
    (tmp / "plan.yaml").write_text(yaml.safe_dump(PLAN))
    rng = np.random.default_rng(2)
    with open(tmp / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "x", "y", "z", "heading_deg"])
        for k, pose in enumerate([(1.2, 1.1, 1.4, 30.0), (4.9, 2.6, 1.4, 200.0), (2.3, 5.8, 1.4, 287.5)]):
            cv2.imwrite(str(tmp / "q" / f"p{k}.png"), _grey_panorama(pose, rng))
            w.writerow([f"p{k}.png", *pose])
    out = []
    # (the oriented chamfer score reads umap.panorama.orientation_spread)
    for kind, score, bins in (("panorama", "chamfer", 1), ("panorama", "chamfer", 4), ("equirect", "iou", 1)):
        out.append(load_config(data={
            "method": "umap", "query": {"images": str(tmp / "q")}, "executor": {"workers": 1},
            "ground_truth": {"kind": "poses", "path": str(tmp / "poses.csv")},
            "umap": {"model": str(tmp / "plan.yaml"), "query_kind": kind,
                     "panorama": {"score": score, "orientation_bins": bins},
                     "grid": {"x": [0.2, 5.8, 0.4], "y": [0.2, 6.8, 0.4], "z": 1.4, "headings": [0.0, 90.0, 180.0, 270.0]}},
            "plots": False}, base_dir=tmp))
    return out


def coembed_variants(tmp: Path) -> list[dict]:
    """configs/coembed-abcd.yaml on a short ABCD world, with each solver."""
    from placeloc.synth import generate

    data = tmp / "abcd"
    generate("coembed", data, seed=0, steps=300)
    moves = {"../runs/coembed-abcd-data": str(data)}
    camera = tmp / "camera"
    generate("coembed", camera, seed=0, world="camera", frames=40)
    cam = yaml.safe_load((camera / "camera.yaml").read_text())
    cam["plots"] = False
    perspective = {**cam, "coembed": {**cam["coembed"], "camera_model": "perspective", "perspective_iterations": 2}}
    from test_coembed_pipeline import _marker_frames

    _marker_frames(tmp / "frames")
    np.savetxt(tmp / "landmarks.csv", [[3, 0, 0], [8, 1, 0], [21, 0, 1]], delimiter=",", header="feature,x,y", comments="",
               fmt="%g")
    markers = {"method": "coembed", "coembed": {"source": "aruco+sift", "images": str(tmp / "frames"), "image_values": "xy",
                                                "landmarks": str(tmp / "landmarks.csv")}}
    return [
        _preset("coembed-abcd.yaml", moves, {"coembed.alpha_grid": [1.0, 100.0]}),
        _preset("coembed-abcd.yaml", moves, {"plots": False, "coembed.solver": "isomap",
                                             "coembed.isomap_neighbors_grid": [5, 8]}),
        _preset("coembed-abcd.yaml", moves, {"plots": False, "coembed.solver": "pcamd", "coembed.pcamd_max_iter": 3}),
        _preset("coembed-abcd.yaml", moves, {"plots": False, "coembed.alpha_select": "fixed"}),
        load_config(data=cam, base_dir=camera),
        load_config(data=perspective, base_dir=camera),
        (load_config(data=markers, base_dir=tmp), "extract"),
    ]


SMOKE: dict[str, Callable[[Path], list[Any]]] = {
    "seqslam": seqslam_variants, "pirf": pirf_variants, "umap": umap_variants, "coembed": coembed_variants,
    "retrieval": retrieval_variants,
}


def _preset_variants(name: str) -> Callable[[Path], list[dict]]:
    """A method without an entry in SMOKE: every preset of configs/ for it whose data is there."""

    def variants(tmp: Path) -> list[dict]:
        out = []
        for path in sorted(CONFIGS.glob("*.yaml")):
            if (yaml.safe_load(path.read_text()) or {}).get("method") == name:
                try:
                    out.append(load_config(path, ["executor.workers=1"]))
                except Exception:  # noqa: BLE001 - data not made: try the next preset
                    continue
        if not out:
            pytest.fail(f"method {name!r} has no smoke configuration: add one to SMOKE in {Path(__file__).name} "
                        f"(or a preset in configs/ whose data is in the repository)")
        return out

    return variants


@pytest.mark.parametrize("name", M.METHOD_NAMES)
def test_every_stage_declares_exactly_the_keys_it_reads(name: str, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    method = M.get_method(name)
    reads = Reads()
    for variant in SMOKE.get(name, _preset_variants(name))(tmp_path):
        config, last = variant if isinstance(variant, tuple) else (variant, STAGES[-1])
        # One run directory for all variants: a stage re-runs where its declared inputs
        # changed, and each variant changes a declared key of the stage whose branch it
        # takes (a branch chosen by an undeclared key is caught by the read of that key).
        run_recorded(config, tmp_path / "run", method, reads, monkeypatch, last)
    found = problems(method, reads)
    assert not found, "\n" + "\n".join(found)


def test_a_planted_omission_is_caught(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Drop ``top_k`` from SeqSLAM's localize declaration (in a copy): the check names it,
    and the copy indeed leaves localize "up to date" when top_k changes."""
    from placeloc.core import runner

    real = M.get_method("seqslam")
    localize = real.stages["localize"]
    assert "top_k" in localize.keys
    planted = dataclasses.replace(real, stages={**real.stages, "localize": dataclasses.replace(
        localize, keys=tuple(k for k in localize.keys if k != "top_k"))})
    reads = Reads()
    config = _preset("demo.yaml", {}, {"plots": False})
    run_recorded(config, tmp_path / "run", planted, reads, monkeypatch)
    undeclared = [p for p in problems(planted, reads) if "not declared" in p]
    assert undeclared == ["seqslam.localize: reads 'top_k', not declared in its Stage(keys=...)"]

    # what the omission costs: with top_k undeclared, --set seqslam.top_k=3 re-runs nothing
    monkeypatch.setattr(runner, "get_method", lambda name: planted)
    before = (tmp_path / "run" / "localize.h5").stat().st_mtime_ns
    runner.run_all(_preset("demo.yaml", {}, {"plots": False, "seqslam.top_k": 3}), tmp_path / "run", quiet=True)
    assert (tmp_path / "run" / "localize.h5").stat().st_mtime_ns == before


def test_a_declared_key_never_read_is_caught(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Declare a key SeqSLAM's localize does not read (``thumbnail``): the check names it."""
    real = M.get_method("seqslam")
    localize = real.stages["localize"]
    planted = dataclasses.replace(real, stages={**real.stages, "localize": dataclasses.replace(
        localize, keys=(*localize.keys, "thumbnail"))})
    reads = Reads()
    run_recorded(_preset("demo.yaml", {}, {"plots": False}), tmp_path / "run", planted, reads, monkeypatch)
    assert "seqslam.localize: declares 'thumbnail' but never reads it" in problems(planted, reads)


def test_the_config_recorder_sees_one_key_of_a_section() -> None:
    reads: set[str] = set()
    config = _RecordingConfig({"ground_truth": {"kind": "csv", "exclude_recent": 5}, "plots": False}, reads)
    assert config["ground_truth"]["exclude_recent"] == 5 and config.get("plots") is False
    assert reads == {"ground_truth.exclude_recent", "plots"}
    dict(config["ground_truth"].items())
    assert "ground_truth" in reads


def test_the_recorder_sees_nested_sections_and_pickles_plain() -> None:
    import pickle

    from placeloc.umap.params import UMapParams

    reads: set[str] = set()
    rec = _Recorder(UMapParams(), "", reads)
    assert rec.ca.tie_tol == UMapParams().ca.tie_tol and rec.tolerance_px == 2
    assert reads == {"ca.tie_tol", "tolerance_px"}
    assert pickle.loads(pickle.dumps(rec)) == UMapParams()
