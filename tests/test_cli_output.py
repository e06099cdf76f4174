"""What the command line says: where sweep and compare wrote, and library chatter only
with --verbose."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from typer.testing import CliRunner

from placeloc import cli


@pytest.fixture
def restore_logging():
    """The CLI reconfigures the root logger; leave it as pytest had it."""
    root, ours = logging.getLogger(), logging.getLogger("placeloc")
    saved = (root.level, list(root.handlers), ours.level, cli._VERBOSE)
    yield
    root.setLevel(saved[0])
    root.handlers[:] = saved[1]
    ours.setLevel(saved[2])
    cli._VERBOSE = saved[3]


@pytest.mark.parametrize("verbose", [False, True])
def test_library_info_lines_only_with_verbose(verbose, capsys, restore_logging):
    """faiss logs which CPU build it loaded at INFO on every PIRF run
    ("Could not load library with AVX512 support"): hidden unless --verbose; placeloc's own
    progress lines and every library warning show either way."""
    cli._VERBOSE = verbose
    cli._setup_logging(quiet=False)
    logging.getLogger("faiss.loader").info("Could not load library with AVX512 support due to: ...")
    logging.getLogger("faiss.loader").warning("a real problem")
    logging.getLogger("placeloc").info("extract: running seqslam")
    logging.getLogger("placeloc").debug("a debug line")
    err = capsys.readouterr().err.splitlines()
    expected = ["faiss.loader: a real problem", "placeloc: extract: running seqslam"]
    if verbose:
        expected = ["faiss.loader: Could not load library with AVX512 support due to: ...", *expected, "placeloc: a debug line"]
    assert err == expected


def test_verbose_is_a_global_flag(restore_logging):
    res = CliRunner().invoke(cli.app, ["--verbose", "inspect", "nowhere.h5"])
    assert cli._VERBOSE is True and res.exit_code == 2
    assert "--verbose" in CliRunner().invoke(cli.app, ["--help"]).output


def test_sweep_and_compare_say_where_they_wrote(route: Path, tmp_path: Path, restore_logging):
    (route / "config.yaml").write_text((route / "config.yaml").read_text() + "plots: false\n")
    res = CliRunner().invoke(cli.app, ["sweep", str(route / "config.yaml"), "--grid", "seqslam.ds=5,10", "-o",
                                       str(tmp_path / "sw"), "-q"])
    assert res.exit_code == 0, res.output
    lines = res.output.strip().splitlines()
    assert lines[-2] == "wrote " + ", ".join(str(tmp_path / "sw" / n) for n in ("sweep.md", "sweep.csv", "sweep.png"))
    assert lines[-1].startswith(f"runs: {tmp_path / 'sw'}/ (one run directory per combination")
    res = CliRunner().invoke(cli.app, ["compare", str(route / "config.yaml"), "--methods", "sad,zncc", "--run-dir",
                                       str(tmp_path / "cmp"), "-q"])
    assert res.exit_code == 0, res.output
    lines = res.output.strip().splitlines()
    wrote = [str(tmp_path / "cmp" / n) for n in ("table.md", "table.csv", "pr_curves.png")]
    assert lines[-2] == "wrote " + ", ".join(w for w in wrote if Path(w).is_file())
    assert (tmp_path / "cmp" / "table.md").is_file() and lines[-1].startswith(f"runs: {tmp_path / 'cmp'}/")


def test_params_lists_every_setting_with_default_range_and_help():
    """The help of each setting comes from its param(...) declaration, the one home."""
    from placeloc.core import params as P
    from placeloc.core.common_params import CommonParams
    from placeloc.pirf.params import PirfParams

    out = CliRunner().invoke(cli.app, ["params"]).output.splitlines()
    keys = [line.split()[0] for line in out if line and not line.startswith(" ") and not line.startswith("Each")]
    assert keys == [k for k, *_ in P.describe(CommonParams)]
    i = keys.index("ground_truth.radius")
    radius = [line for line in out if line.startswith("ground_truth.radius")][0]
    assert radius.split() == ["ground_truth.radius", "25.0", "(>", "0)"]
    assert "metres within which" in out[out.index(radius) + 1] and i >= 0
    res = CliRunner().invoke(cli.app, ["params", "pirf"])
    assert res.exit_code == 0 and res.output.count("\npirf.") + res.output.startswith("pirf.") == len(P.describe(PirfParams))
    recall = [line.split() for line in res.output.splitlines() if line.startswith("pirf.index_recall ")]
    assert recall == [["pirf.index_recall", "0.97", "(>=", "0.0,", "<=", "1.0)"]]
    res = CliRunner().invoke(cli.app, ["params", "nope"])
    assert res.exit_code == 2 and "'nope' is not a method" in (res.stderr if hasattr(res, "stderr") else res.output)


def test_a_command_the_cli_suggests_can_be_pasted_with_spaces_in_the_path(route: Path, tmp_path: Path,
                                                                         restore_logging):
    """A run folder "run é 1" (a space, an accent): the `placeloc show` the run suggests
    is quoted for the shell, so pasting it shows that folder, not the folders "run", "é", "1"."""
    import shlex

    cfg = tmp_path / "nogt.yaml"  # no ground truth: the run ends by suggesting `placeloc show`
    cfg.write_text(f"method: seqslam\nreference: {{images: {route / 'reference'}}}\nquery: {{images: {route / 'query'}}}\n"
                   "plots: false\n")
    run = tmp_path / "run é 1"
    res = CliRunner().invoke(cli.app, ["run", str(cfg), "-o", str(run), "-q"])
    assert res.exit_code == 0, res.output
    line = next(ln for ln in res.output.splitlines() if "draws them" in ln)
    command = line.split("`")[1]
    assert shlex.split(command) == ["placeloc", "show", str(run)]
