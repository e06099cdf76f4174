"""Config validation: unknown keys, types, paths, overrides."""

from __future__ import annotations

import pytest
import yaml

from placeloc.core.config import ConfigError, load_config


def _write(tmp_path, data):
    p = tmp_path / "c.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_defaults_relative_paths_and_overrides(route):
    cfg = load_config(route / "config.yaml", ["seqslam.ds=20", "seqslam.comparison=ocm"])
    assert cfg["seqslam"]["ds"] == 20 and cfg["seqslam"]["comparison"] == "ocm"
    assert cfg["seqslam"]["v_min"] == 0.8  # default filled in
    assert cfg["reference"]["images"] == str((route / "reference").resolve())
    assert cfg["ground_truth"]["path"] == str((route / "ground_truth.csv").resolve())


def test_loop_closure_when_query_omitted(route):
    cfg = load_config(data={"method": "seqslam", "reference": {"images": "reference"}}, base_dir=route)
    assert cfg["query"] is None


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"seqslam": {"dss": 3}}, "unknown key 'seqslam.dss' in seqslam; did you mean 'seqslam.ds'\\? known keys: "),
        ({"seqslam": {"enhance_windows": 3}}, "did you mean 'seqslam.enhance_window'\\?"),
        ({"plot": False}, "unknown key 'plot' in the top level; did you mean 'plots'\\?"),
        ({"seqslam": {"ds": "ten"}}, "seqslam.ds must be an integer"),
        ({"seqslam": {"comparison": "foo"}}, "seqslam.comparison: 'foo' is not allowed"),
        ({"seqslam": {"thumbnail": [64]}}, "a list of 2 items"),
        ({"method": "nope"}, "not known"),
        ({"reference": {"images": "missing-folder"}}, "reference.images"),
        ({"ground_truth": {"kind": "csv"}}, "ground_truth.path is missing"),
        ({"colour": 1}, "unknown key 'colour' in the top level; known keys: "),  # nothing near it: no guess
    ],
)
def test_bad_configs_name_the_key(route, patch, message):
    data = {"method": "seqslam", "reference": {"images": "reference"}, "query": {"images": "query"}}
    for k, v in patch.items():
        data[k] = {**data[k], **v} if isinstance(v, dict) and isinstance(data.get(k), dict) else v
    with pytest.raises(ConfigError, match=message):
        load_config(data=data, base_dir=route)


def test_bad_override_syntax(route):
    with pytest.raises(ConfigError, match="key.path=value"):
        load_config(route / "config.yaml", ["seqslam.ds"])


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "none.yaml")


def test_declared_ranges_are_checked_with_the_key_and_the_limit(tmp_path):
    from placeloc.core.config import ConfigError, load_config

    base = {"method": "seqslam", "reference": {"images": str(tmp_path)}}
    with pytest.raises(ConfigError, match=r"seqslam.ds: 0 is out of range; it must be >= 1"):
        load_config(data={**base, "seqslam": {"ds": 0}})
    with pytest.raises(ConfigError, match=r"seqslam.v_step: 0.0 is out of range; it must be > 0"):
        load_config(data={**base, "seqslam": {"v_step": 0.0}})
    with pytest.raises(ConfigError, match=r"seqslam.thumbnail"):
        load_config(data={**base, "seqslam": {"thumbnail": [64, 2]}})
    cfg = load_config(data={**base, "seqslam": {"ds": 1}})
    assert cfg["seqslam"]["ds"] == 1


def test_parameter_objects_are_built_from_the_config_with_nested_sections(tmp_path):
    from placeloc.core.methods import get_method
    from placeloc.core.params import defaults
    from placeloc.umap.params import UMapParams

    d = defaults(UMapParams)
    assert d["ca"]["tie_tol"] == 0.003 and d["grid"]["x"] is None  # the grid covers the model's plan
    p = get_method("umap").build_params({"umap": {**d, "ca": {**d["ca"], "tie_tol": 0.01},
                                                  "grid": {**d["grid"], "x": [0.0, 90.0, 0.1]}}})
    assert p.ca.tie_tol == 0.01 and p.grid.x == (0.0, 90.0, 0.1) and p.camera.width == 160


def test_null_is_accepted_where_the_parameter_declares_it(route):
    """pirf.index_recall is ``float | None`` with default 0.97: null (use the search setting
    as given) must pass, a string must not; a plain float key still refuses null."""
    import pytest

    from placeloc.core.config import ConfigError, load_config

    def cfg(**pirf):
        return load_config(data={"method": "pirf", "reference": {"images": str(route / "reference")}, "pirf": pirf})

    assert cfg(index_recall=None)["pirf"]["index_recall"] is None
    with pytest.raises(ConfigError, match="pirf.index_recall must be a number"):
        cfg(index_recall="high")
    with pytest.raises(ConfigError, match="pirf.tau must be a number"):
        cfg(tau=None)


ROOT_CONFIGS = __import__("pathlib").Path(__file__).resolve().parent.parent / "configs"


@pytest.mark.parametrize("case", ["no reference and no query (co-embedding)", "reference only (loop closure)",
                                  "reference and query (the demo)"])
def test_a_runs_own_config_reads_back_as_the_same_config(tmp_path, route, case):
    """The config.yaml a run writes (every key, absent sections as null) is a config placeloc
    reads again: `placeloc localize RUN/config.yaml` must work. Before, a run without a
    reference (UMap on panoramas, co-embedding) wrote `reference: null`, which the loader
    refused."""
    from placeloc.core.runner import write_run_config

    if case.startswith("no reference"):
        from placeloc.synth.coembed import generate

        generate(tmp_path / "data", seed=0, steps=200)  # writes bearing.yaml beside its CSVs
        cfg = load_config(tmp_path / "data" / "bearing.yaml")
        assert cfg["method"] == "coembed" and cfg["reference"] is None and cfg["query"] is None
    elif case.startswith("reference only"):
        cfg = load_config(data={"method": "seqslam", "reference": {"images": "reference"}}, base_dir=route)
    else:
        cfg = load_config(ROOT_CONFIGS / "demo.yaml")
    run = tmp_path / "run"
    run.mkdir()
    write_run_config(run, cfg)
    assert load_config(run / "config.yaml") == cfg


def test_a_method_that_needs_a_reference_says_so_when_it_is_null(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("method: seqslam\nreference: null\n")
    with pytest.raises(ConfigError, match="reference.images is missing"):
        load_config(p)


def test_a_key_given_twice_is_refused_with_both_lines(tmp_path):
    """YAML forbids a key twice in one mapping, but PyYAML keeps the last in silence: a
    second `seqslam:` section would drop the first one's settings (here ds: 10)."""
    p = tmp_path / "c.yaml"
    p.write_text("method: seqslam\nreference: {images: r}\nseqslam:\n  ds: 10\nseqslam:\n  comparison: sad\n")
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert str(info.value) == (f"{p}: not valid YAML: line 5: the key 'seqslam' is given twice (first on line 3); "
                               "YAML keeps only the last, so the first one's settings would be lost: merge them into one")
    with pytest.raises(ConfigError, match=r"^--set 'seqslam=\{ds: 5, ds: 6\}': line 1: the key 'ds' is given twice"):
        load_config(data={"method": "seqslam"}, overrides=["seqslam={ds: 5, ds: 6}"])
    # the same key in different mappings, and a merge key's override, are fine
    from placeloc.core.safe_io import load_yaml

    assert load_yaml("a: 1\nb: {a: 2}\nc: {<<: {d: 1}, d: 2}\n") == {"a": 1, "b": {"a": 2}, "c": {"d": 2}}


def test_a_folder_named_from_the_working_directory_is_pointed_out(route, tmp_path, monkeypatch):
    """`--set query.images=query` typed in the shell is read from the config's folder, like
    every relative path of a config; where that is wrong but the working directory has the
    folder, the error says where it would be."""
    cfg_dir = tmp_path / "configs"
    cfg_dir.mkdir()
    (cfg_dir / "c.yaml").write_text(f"method: seqslam\nreference: {{images: {route / 'reference'}}}\n")
    monkeypatch.chdir(route)
    with pytest.raises(ConfigError) as info:
        load_config(cfg_dir / "c.yaml", ["query.images=query"])
    assert str(info.value) == (f"query.images: {cfg_dir / 'query'} is neither a folder nor a glob that matches files; fix "
                               f"the path (relative paths start at the config's folder, {cfg_dir}); from the working "
                               f"directory it would be {route / 'query'}: give that (an absolute path)")
