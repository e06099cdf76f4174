"""placeloc command line: parse arguments, call :mod:`placeloc.api`, print one line per result.

Every stage command takes a YAML config and a run directory and writes
``RUN_DIR/<stage>.h5``; earlier stages that are missing or out of date run first, and
stages that are up to date are skipped.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import List

import typer

app = typer.Typer(
    help="placeloc: where am I, from images alone. Staged, resumable localization pipelines "
    "(SeqSLAM, PIRF-nav2, UMap, co-embedding) over image folders, with HDF5 artifacts.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain Click help: Typer's rich help prints "<bool>" after every flag with Click 8.2+.
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        from placeloc import __version__

        typer.echo(f"placeloc {__version__}")
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """placeloc: where am I, from images alone."""

ConfigArg = typer.Argument(..., help="YAML config (see configs/); relative paths in it start at its folder.")
RunDirOpt = typer.Option(None, "--run-dir", "-o", help="Run directory for artifacts (default: runs/<config name>).")
SetOpt = typer.Option(None, "--set", "-s", help="Override a config value by dotted path, e.g. --set seqslam.ds=20. Repeatable.")
ForceOpt = typer.Option(False, "--force", "-f", help="Re-run even if the artifact is up to date.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="No progress bars, warnings only.")


def _setup_logging(quiet: bool) -> None:
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO,
                        format="placeloc: %(message)s", stream=sys.stderr, force=True)


def _fail(exc: Exception) -> None:
    typer.secho(f"error: {exc}", fg=typer.colors.RED, err=True)
    raise typer.Exit(2)


def _stage(stage: str, config: Path, run_dir: Path | None, sets: List[str] | None, force: bool,
           quiet: bool, all_stages: bool = False) -> None:
    from placeloc.config import ConfigError, load_config
    from placeloc.executor import WorkItemError
    from placeloc.images import ImageError
    from placeloc.runner import StageError, run_stage

    _setup_logging(quiet)
    try:
        cfg = load_config(config, sets)
        out = run_dir or Path("runs") / config.stem
        path = run_stage(cfg, out, stage, force=force and not all_stages, quiet=quiet, force_all=force and all_stages)
    except (ConfigError, ImageError, StageError, WorkItemError, FileNotFoundError, KeyError, RuntimeError) as exc:
        _fail(exc)
    typer.echo(f"{stage}: {path}")
    if stage == "evaluate" and (path.parent / "metrics.json").is_file():
        typer.echo(f"metrics: {path.parent / 'metrics.json'}")


@app.command()
def extract(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
            force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Stage 1: read the image folders and compute per-image features -> extract.h5."""
    _stage("extract", config, run_dir, set, force, quiet)


@app.command("build-dictionary")
def build_dictionary(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
                     force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Stage 2: build the method's map/dictionary/database -> build-dictionary.h5."""
    _stage("build-dictionary", config, run_dir, set, force, quiet)


@app.command("build")
def build(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
          force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Alias of build-dictionary."""
    _stage("build-dictionary", config, run_dir, set, force, quiet)


@app.command()
def index(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
          force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Stage 3: index the dictionary/database for fast search -> index.h5."""
    _stage("index", config, run_dir, set, force, quiet)


@app.command()
def localize(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
             force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Stage 4: match every query against the reference -> localize.h5 (+ matches.csv)."""
    _stage("localize", config, run_dir, set, force, quiet)


@app.command()
def evaluate(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
             force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Stage 5: score against ground truth -> evaluate.h5, metrics.json and plots."""
    _stage("evaluate", config, run_dir, set, force, quiet)


@app.command()
def run(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
        force: bool = typer.Option(False, "--force", "-f", help="Re-run every stage."), quiet: bool = QuietOpt) -> None:
    """All stages in order; up-to-date stages are skipped, so an interrupted run resumes."""
    _stage("evaluate", config, run_dir, set, force, quiet, all_stages=True)


@app.command()
def inspect(file: Path = typer.Argument(..., help="An artifact (.h5) written by placeloc.")) -> None:
    """Explain an artifact: its stage, provenance (config, inputs, version) and contents."""
    from placeloc.artifacts import describe

    try:
        typer.echo(describe(file))
    except (FileNotFoundError, OSError) as exc:
        _fail(exc)


@app.command()
def synth(kind: str = typer.Argument(..., help="Data set kind: route (SeqSLAM route pair), corridor (UMap building), home (UMap panoramas), "
                                     "coembed (ABCD world), omni (PIRF video)."),
          out: Path = typer.Argument(..., help="Output folder."),
          seed: int = typer.Option(0, help="Random seed."),
          set: List[str] | None = typer.Option(None, "--set", "-s", help="Generator parameter, e.g. --set frames=200.")) -> None:
    """Generate a synthetic data set with known ground truth."""
    import yaml
    from placeloc.synth import generate

    params = {}
    for item in set or []:
        if "=" not in item:
            _fail(ValueError(f"--set {item!r}: expected name=value"))
        k, v = item.split("=", 1)
        params[k.strip()] = yaml.safe_load(v)
    try:
        summary = generate(kind, out, seed=seed, **params)
    except (KeyError, TypeError, ValueError) as exc:
        _fail(exc)
    for k, v in summary.items():
        typer.echo(f"{k}: {v}")


@app.command()
def compare(config: Path = ConfigArg,
            methods: str = typer.Option("sad,histeq,zncc,abs_zncc,isc,isc_ext,ocm,ocm_ext", help="Comma-separated SeqSLAM comparisons."),
            run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt, quiet: bool = QuietOpt) -> None:
    """Run several SeqSLAM image comparisons on one data set; write a table and one PR plot."""
    from placeloc.config import ConfigError, load_config
    from placeloc.experiments.compare import compare_methods

    _setup_logging(quiet)
    try:
        cfg = load_config(config, set)
        out = run_dir or Path("runs") / f"{config.stem}-compare"
        table = compare_methods(cfg, out, [m.strip() for m in methods.split(",") if m.strip()], quiet=quiet)
    except (ConfigError, ValueError) as exc:
        _fail(exc)
    typer.echo(table.read_text())


@app.command()
def experiment(name: str = typer.Argument(..., help="Experiment: seqslam, umap, coembed, pirf, pirf-large."),
               out: Path | None = typer.Option(None, help="Output folder (default runs/experiment-NAME)."),
               quick: bool = typer.Option(False, help="Smaller variant for smoke runs."),
               quiet: bool = QuietOpt) -> None:
    """Reproduce a paper's experiment; writes its runs, tables and summary.json."""
    from placeloc.experiments import run_experiment

    _setup_logging(quiet)
    path = run_experiment(name, out, quick=quick, quiet=quiet)
    typer.echo(f"results: {path}")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
