"""A stage re-runs when, and only when, what it reads changed: ``Stage.parents`` names the
earlier artifacts a stage reads, and the runner stamps it with theirs alone. UMap's map
database and index are drawn from the floor plan only, so a photo added to the folder
re-runs extract and localize but neither draws the map again nor rewrites its index (0.7 GB
at a home's size); an edited plan re-runs the map, not the photos' extract."""

from __future__ import annotations

import logging
import os

import h5py
import pytest
from test_umap_method import _config, _tiny_corridor

from placeloc.core.methods import STAGES, Method, Stage, get_method
from placeloc.core.runner import StageContext, run_all
from placeloc.evaluation.report import stamped_configs


def _write_ids(run_dir) -> dict[str, str]:
    out = {}
    for stage in STAGES:
        with h5py.File(run_dir / f"{stage}.h5", "r") as f:
            out[stage] = str(f.attrs["write_id"])
    return out


def _ran(caplog) -> set[str]:
    return {s for s in STAGES for r in caplog.records if r.getMessage().startswith(f"{s}: running ")}


def test_a_photo_removed_or_a_plan_edited_re_runs_only_what_reads_it(tmp_path, caplog):
    data = _tiny_corridor(tmp_path)
    run = tmp_path / "run"
    run_all(_config(data), run, quiet=True)
    first = _write_ids(run)

    (data / "q" / "f7.png").unlink()                       # a photo fewer
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_all(_config(data), run, quiet=True)
    after_photo = _write_ids(run)
    assert _ran(caplog) == {"extract", "localize", "evaluate"}
    assert [after_photo[s] == first[s] for s in STAGES] == [False, True, True, False, False]
    with h5py.File(run / "localize.h5", "r") as f:
        assert len(f["names"]) == 7
        inputs = f.attrs["inputs"]
    assert '"parents"' in inputs and '"extract"' in inputs and '"index"' in inputs
    # the run's chain of stamps is whole: show and the report read the evaluated run
    assert [s for s, _, _ in stamped_configs(run)] == list(STAGES)

    plan = data / "plan.yaml"                              # the plan edited (its time moved on)
    st = plan.stat()
    os.utime(plan, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_all(_config(data), run, quiet=True)
    assert _ran(caplog) == {"build-dictionary", "index", "localize", "evaluate"}
    assert _write_ids(run)["extract"] == after_photo["extract"]
    assert [s for s, _, _ in stamped_configs(run)] == list(STAGES)


def test_a_stage_opens_only_the_artifacts_it_depends_on(tmp_path):
    umap = get_method("umap")
    assert umap.stage_parents("build-dictionary") == ()
    assert umap.stage_ancestors("localize") == {"extract", "build-dictionary", "index"}
    assert umap.stage_ancestors("evaluate") == {"extract", "build-dictionary", "index", "localize"}
    assert get_method("seqslam").stage_ancestors("index") == {"extract", "build-dictionary"}   # the default chain
    ctx = StageContext(stage="index", method=umap, config={}, run_dir=tmp_path, out=None, executor=None,
                       reads=umap.stage_ancestors("index"))
    with pytest.raises(RuntimeError, match=r"umap.index reads extract.h5, which is not among its parents.*Stage.parents"):
        ctx.artifact("extract")


def test_a_parent_must_be_an_earlier_stage():
    from dataclasses import dataclass

    from placeloc.core.params import Params

    @dataclass(frozen=True)
    class ToyParams(Params):
        pass

    with pytest.raises(ValueError, match=r"toy.index names 'localize' among its parents: a parent is an earlier "
                                         r"stage \(extract, build-dictionary\)"):
        Method(name="toy", params=ToyParams, stages={"index": Stage(lambda ctx: None, parents=("localize",))},
               required_images=())


def test_another_folder_of_photos_takes_the_map_of_an_earlier_run(tmp_path, caplog):
    # The map and its index do not depend on the photos' folder (the query section is left out
    # of their stamps), so `placeloc run --reuse EARLIER_RUN` links them instead of drawing them.
    import shutil

    import yaml
    from typer.testing import CliRunner

    from placeloc.cli import app
    from placeloc.core.runner import stage_inputs

    data = _tiny_corridor(tmp_path)
    first = tmp_path / "first"
    run_all(_config(data), first, quiet=True)
    (data / "q2").mkdir()
    for name in ("f1.png", "f2.png", "f3.png"):
        shutil.copy(data / "q" / name, data / "q2" / name)
    cfg = _config(data)
    cfg["query"]["images"] = str(data / "q2")
    umap = get_method("umap")
    assert stage_inputs(cfg, umap, "build-dictionary", {}, {})["config"] == \
        stage_inputs(_config(data), umap, "build-dictionary", {}, {})["config"]
    assert stage_inputs(cfg, umap, "extract", {}, {})["config"] != stage_inputs(_config(data), umap, "extract", {}, {})["config"]
    (tmp_path / "second.yaml").write_text(yaml.safe_dump(cfg))
    second = tmp_path / "second"
    out = CliRunner().invoke(app, ["run", str(tmp_path / "second.yaml"), "-o", str(second), "--reuse", str(first), "-q"])
    assert out.exit_code == 0, out.output
    for stage in ("build-dictionary", "index"):   # the same files, linked
        assert os.path.samefile(first / f"{stage}.h5", second / f"{stage}.h5")
    assert not os.path.samefile(first / "extract.h5", second / "extract.h5")
    with h5py.File(second / "localize.h5", "r") as f:
        assert len(f["names"]) == 3
    bad = CliRunner().invoke(app, ["run", str(tmp_path / "second.yaml"), "-o", str(tmp_path / "third"),
                                   "--reuse", str(tmp_path / "nowhere")])
    assert bad.exit_code == 2 and "--reuse" in bad.output and "not a folder" in bad.output
    assert not (tmp_path / "third").exists()


def test_the_map_is_built_without_reading_a_photo(tmp_path, caplog, monkeypatch):
    # `placeloc index` of UMap runs the stages the index depends on, not extract: the photos'
    # folder is not even listed
    from placeloc.core import runner
    from placeloc.core.runner import run_stage

    data = _tiny_corridor(tmp_path)
    listed = []
    monkeypatch.setattr(runner, "image_sets", lambda config: listed.append(config) or {})
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="placeloc"):
        run_stage(_config(data), tmp_path / "run", "index", quiet=True)
    assert _ran(caplog) == {"build-dictionary", "index"}
    assert not (tmp_path / "run" / "extract.h5").exists() and listed == []


def test_a_linked_artifact_in_the_donor_is_not_taken(tmp_path):
    # --reuse takes a run's own artifacts only: a symbolic link named index.h5 in the donor
    # (to wherever) is computed instead, as the run-folder guard reads no link
    from placeloc.core.runner import run_stage

    data = _tiny_corridor(tmp_path)
    first = tmp_path / "first"
    run_stage(_config(data), first, "index", quiet=True)
    donor = tmp_path / "donor"
    donor.mkdir()
    for stage in ("build-dictionary", "index"):
        (donor / f"{stage}.h5").symlink_to(first / f"{stage}.h5")
    second = tmp_path / "second"
    run_stage(_config(data), second, "index", quiet=True, reuse=[donor])
    for stage in ("build-dictionary", "index"):
        assert not os.path.samefile(first / f"{stage}.h5", second / f"{stage}.h5")
    run_stage(_config(data), tmp_path / "third", "index", quiet=True, reuse=[first])   # the files themselves: linked
    assert os.path.samefile(first / "index.h5", tmp_path / "third" / "index.h5")
