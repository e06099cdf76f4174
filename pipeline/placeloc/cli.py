"""placeloc command line: parse arguments, call :mod:`placeloc.api`, print one line per result.

Every stage command takes a YAML config and a run directory and writes
``RUN_DIR/<stage>.h5``; earlier stages that are missing or out of date run first, and
stages that are up to date are skipped.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shlex
import sys
import traceback
from pathlib import Path
from typing import Any, List

import typer
from typer.core import TyperGroup

from placeloc.core.interrupts import Terminated, raise_if_interrupted
from placeloc.core.interrupts import install as install_signal_handlers
from placeloc.core.methods import METHOD_NAMES

try:  # Typer 0.2x vendors its own copy of Click; its exceptions are the ones its main() handles
    from typer._click import ClickException
except ImportError:  # older Typer uses Click itself
    from click import ClickException  # type: ignore[no-redef]

# Where a bug goes: the project has no public tracker address yet, so name what to send.
BUG_REPORT = "the placeloc issue tracker, with the traceback above, the command and the config"


_PACKAGE_DIR = str(Path(__file__).resolve().parent)

# What an OSError's errno means for the user, and the usual fix.
_OS_FIXES = {
    "ENOENT": "does not exist; check the path",
    "EACCES": "permission denied; make it readable/writable for you (chmod) or choose another path",
    "EPERM": "operation not permitted; check its owner and permissions, or choose another path",
    "EROFS": "is on a read-only file system; choose a writable place, e.g. another --run-dir",
    "EISDIR": "is a folder where a file was expected; give a file, or remove the folder",
    "ENOTDIR": "a part of the path is a file where a folder was expected; fix the path (is -o/--run-dir a file?)",
    "EEXIST": "already exists as something else (a file where a folder goes?); remove it or choose another path",
    "ELOOP": "is a symbolic link that points to itself (a link loop); fix or remove the link",
    "ENOSPC": "no space left on the device; free space or choose another --run-dir",
    "EDQUOT": "disk quota exceeded; free space or choose another --run-dir",
    "ENAMETOOLONG": "the path is too long; choose a shorter one",
    "EMFILE": "too many open files; raise the limit (ulimit -n) or lower executor.workers",
    "EIO": "an input/output error on the device; check the disk",
}


def _raised_in_placeloc(exc: BaseException) -> bool:
    """True when a ``raise`` statement in placeloc's own code raised ``exc`` (a message
    written for the user); False when it came from Python or a library, or from a builtin
    called by placeloc (``float("abc")``): a raw text."""
    import linecache

    tb = exc.__traceback__
    if tb is None:
        return True  # built, not raised: only placeloc builds errors for the boundary
    while tb.tb_next is not None:
        tb = tb.tb_next
    filename = tb.tb_frame.f_code.co_filename
    if not str(Path(filename).resolve()).startswith(_PACKAGE_DIR):
        return False
    return linecache.getline(filename, tb.tb_lineno).strip().startswith("raise")


def _os_error_line(exc: OSError) -> str:
    """A raw OSError as one line: the file, what its errno means and the usual fix."""
    import errno as errno_names

    text = " ".join(str(exc).split())
    name = errno_names.errorcode.get(exc.errno or -1, "")
    if name not in _OS_FIXES or "; " in text:  # placeloc's own wording (it gives a fix) stays
        if exc.filename and str(exc.filename) not in text:
            return f"{exc.filename}: {text}"
        return text
    where = exc.filename or "a file"
    also = f" (and {exc.filename2})" if getattr(exc, "filename2", None) else ""
    return f"{where}{also}: {_OS_FIXES[name]}"


def _one_line(exc: BaseException) -> str:
    from concurrent.futures.process import BrokenProcessPool

    if isinstance(exc, BrokenProcessPool):
        return ("a worker process was killed (out of memory?); lower executor.workers or the method's size parameters, "
                "free memory, then rerun to resume (finished stages are kept)")
    if isinstance(exc, MemoryError):
        text = " ".join(str(exc).split())
        return (f"out of memory{': ' + text if text else ''}; reduce the data or the size parameters, "
                "or executor.workers, or free memory")
    if isinstance(exc, OSError):
        return _os_error_line(exc)
    if _non_utf8_name(exc):
        from placeloc.core.images import shown_name

        return (f"'{shown_name(exc.object)}' is not valid UTF-8 text (a file or folder name in another encoding); rename it "
                "in UTF-8 (e.g. convmv -f latin1 -t utf8 --notest NAME)")
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def _non_utf8_name(exc: BaseException) -> bool:
    """A name that came from the file system or the command line in another encoding: Python
    holds its bytes as lone surrogates, and writing it as UTF-8 (a log, a report, an HDF5
    string) fails. The user's file name, not a bug."""
    return (isinstance(exc, UnicodeEncodeError) and exc.reason == "surrogates not allowed"
            and isinstance(exc.object, str))


def _check_utf8_path(path: Path | None, what: str) -> None:
    """Refuse, before any work, a path argument that is not valid UTF-8 (the run would fail
    when it first writes the name into its log, report or artifacts)."""
    from placeloc.core.errors import ConfigError
    from placeloc.core.images import is_utf8, shown_name

    if path is not None and not is_utf8(str(path)):
        raise ConfigError(f"{what} '{shown_name(str(path))}' is not valid UTF-8 text (a name in another encoding); rename "
                          "it in UTF-8 (e.g. convmv -f latin1 -t utf8 --notest NAME) or choose another path")


def classify(exc: BaseException) -> str:
    """The one classification of failures (see placeloc.core.errors):

    - ``user``: the input, the config or the files are wrong; placeloc's own errors (every
      exception type defined in placeloc, a ValueError placeloc raised with its message),
      every OSError (worded by errno with the file and the fix), invalid YAML, an image
      OpenCV cannot decode, a file that is not UTF-8;
    - ``environment``: the machine failed the run (a worker killed, memory exhausted);
    - ``bug``: anything else, including a raw ValueError from Python or a library (placeloc
      should have checked the input before: its text would not tell the user what to do).
    A work item's failure is judged by the exception it wraps."""
    import yaml

    from placeloc.core.errors import EnvironmentFailure
    from placeloc.core.executor import WorkItemError

    if isinstance(exc, WorkItemError):
        return classify(exc.original)
    from concurrent.futures.process import BrokenProcessPool

    if isinstance(exc, (EnvironmentFailure, MemoryError, BrokenProcessPool)):
        return "environment"
    if isinstance(exc, (OSError, yaml.YAMLError, UnicodeDecodeError)) or _non_utf8_name(exc):
        return "user"
    cv2 = sys.modules.get("cv2")
    if cv2 is not None and isinstance(exc, cv2.error):
        return "user"
    if isinstance(exc, (RecursionError, WorkItemError)):
        return "bug"
    if type(exc).__module__.split(".")[0] == "placeloc":
        return "user"  # ConfigError, StageError, ImageError, GroundTruthError, PoseError, ResourceError, ...
    if isinstance(exc, ValueError) and _raised_in_placeloc(exc):
        return "user"
    return "bug"


def _stdout_failed(exc: BaseException) -> bool:
    """True when ``exc`` is an OSError raised while writing the standard output (a
    ``typer.echo``/``click.echo`` or ``print`` frame, or the flush after the command): the
    reader of a pipe went away (``| head -1``) or the file it goes to is full (``> /dev/full``)."""
    if not isinstance(exc, OSError):
        return False
    tb = exc.__traceback__
    while tb is not None:
        code = tb.tb_frame.f_code
        module = tb.tb_frame.f_globals.get("__name__", "")
        if code.co_name in ("echo", "secho") and module.split(".")[0] in ("click", "typer") or code.co_name == "_flush_stdout":
            return True
        tb = tb.tb_next
    return False


def _stdout_failure(exc: OSError) -> None:
    """The standard output failed. A closed pipe is what ``| head`` does on purpose: leave
    quietly with rc 0 (the reader took what it wanted), pointing stdout at /dev/null so the
    interpreter's own flush at exit does not fail again. Anything else (a full disk behind
    ``> FILE``, an I/O error) is the environment: one line saying where, rc 3."""
    import errno

    _discard_stdout()
    if exc.errno == errno.EPIPE:
        raise typer.Exit(0)
    name = errno.errorcode.get(exc.errno or -1, "")
    what = {"ENOSPC": "is full (no space left on the device it is redirected to)",
            "EDQUOT": "is over its disk quota"}.get(name, f"cannot be written ({exc.strerror or exc})")
    typer.secho(f"error: the standard output {what}; free space there or redirect the output elsewhere",
                fg="red", err=True)
    raise typer.Exit(3)


def _discard_stdout() -> None:
    """Point the standard output at /dev/null (what is still buffered is dropped)."""
    with contextlib.suppress(Exception):
        fd = sys.stdout.fileno()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)


def _flush_stdout() -> None:
    """Flush the standard output inside the error boundary (a failure is classified there,
    not printed by the interpreter at exit)."""
    sys.stdout.flush()


class ErrorBoundaryGroup(TyperGroup):
    """The one error boundary: every command, including ones added later, runs inside it.

    - a user-caused error: one line ``error: ...`` naming the file or key and the fix, rc 2;
    - an environment failure (a worker killed, out of memory): one line with what to change, rc 3;
    - Ctrl-C: one line ``interrupted; rerun to resume``, rc 130;
    - anything else is a bug: the traceback, then one line saying so and where to report it, rc 1.
    """

    def invoke(self, ctx: Any) -> Any:
        _announced.clear()  # one "interrupted" line per command, also when commands run in one process (tests, API)
        try:
            result = super().invoke(ctx)
            _flush_stdout()
            raise_if_interrupted()  # a signal whose exception a garbage-collection callback swallowed
            return result
        except (typer.Exit, typer.Abort, ClickException):
            raise
        except KeyboardInterrupt as exc:
            _announce_interrupt()
            raise typer.Exit(143 if isinstance(exc, Terminated) else 130) from None
        except Exception as exc:
            if _stdout_failed(exc):
                return _stdout_failure(exc)
            kind = classify(exc)
            if kind in ("user", "environment"):
                typer.secho(f"error: {_one_line(exc)}", fg="red", err=True)
                raise typer.Exit(2 if kind == "user" else 3) from None
            traceback.print_exc()
            typer.secho(f"error: this is a bug in placeloc ({type(exc).__name__}), not a problem with your input; "
                        f"please report it to {BUG_REPORT}", fg="red", err=True)
            raise typer.Exit(1) from None


app = typer.Typer(
    cls=ErrorBoundaryGroup,
    help="placeloc: where am I, from images alone. Staged, resumable localization pipelines over image folders, "
    f"with HDF5 artifacts. Methods (a config's `method:`): {', '.join(METHOD_NAMES)}; `placeloc params METHOD` lists "
    "one's settings.",
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


# Set by the global --verbose flag (placeloc --verbose run ...).
_VERBOSE = False
# True in the `placeloc` process itself (main()), not when the app runs inside another
# program (tests, the API): only then may a command change the process's environment.
_STANDALONE = False


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit."),
          verbose: bool = typer.Option(False, "--verbose", "-v",
                                       help="Also show the libraries' log lines (faiss, Dask, ...) and placeloc's "
                                            "debug lines. Give it before the command: placeloc --verbose run ...")) -> None:
    """placeloc: where am I, from images alone."""
    global _VERBOSE
    _VERBOSE = verbose

ConfigArg = typer.Argument(..., help="YAML config (see configs/); relative paths in it start at its folder.")
RunDirOpt = typer.Option(None, "--run-dir", "-o", help="Run directory for artifacts (default: runs/<config name>).")
SetOpt = typer.Option(None, "--set", "-s", help="Override a config value by dotted path, e.g. --set seqslam.ds=20. Repeatable.")
ForceOpt = typer.Option(False, "--force", "-f", help="Re-run even if the artifact is up to date.")
QuietOpt = typer.Option(False, "--quiet", "-q", help="No progress bars, warnings only.")
WaitOpt = typer.Option(False, "--wait", help="If another run holds the run directory, wait for it instead of stopping.")
ReuseOpt = typer.Option(None, "--reuse", metavar="RUN_DIR",
                        help="Another run directory whose artifacts this run may take (hard-linked, not computed) where "
                             "one was made from exactly the same inputs and settings: e.g. UMap's map and its 0.7-1 GB "
                             "index of the same plan, when another folder of photos is localized. Repeatable.")


class _SourceFormatter(logging.Formatter):
    """``placeloc: message`` for our lines, ``faiss.loader: message`` for a library's."""

    def format(self, record: logging.LogRecord) -> str:
        if record.name == "py.warnings":
            # "FILE:LINE: Category: text\n  source line" -> "warning: Category: text", one line
            first = record.getMessage().splitlines()[0] if record.getMessage() else ""
            parts = first.split(": ", 1)
            return f"warning: {parts[1] if len(parts) == 2 and ':' in parts[0] else first}"
        source = "placeloc" if record.name == "placeloc" or record.name.startswith("placeloc.") else record.name
        return f"{source}: {record.getMessage()}" + (f"\n{self.formatException(record.exc_info)}" if record.exc_info else "")


def _setup_logging(quiet: bool) -> None:
    """placeloc's progress lines at INFO (warnings only with --quiet). Libraries speak at
    WARNING and above unless --verbose: faiss, for one, logs at INFO which CPU build it
    loaded ("Could not load library with AVX512 support") on every run that uses it."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_SourceFormatter())
    logging.basicConfig(level=logging.INFO if _VERBOSE else logging.WARNING, handlers=[handler], force=True)
    ours = logging.DEBUG if _VERBOSE else logging.WARNING if quiet else logging.INFO
    logging.getLogger("placeloc").setLevel(ours)
    # Python warnings of the libraries (PIL's DecompressionBombWarning, numpy's RuntimeWarning,
    # ...) go through logging as one line each ("py.warnings: ..."); --quiet silences them,
    # here and, through PYTHONWARNINGS, in the worker processes this command starts.
    logging.captureWarnings(True)
    logging.getLogger("py.warnings").setLevel(logging.ERROR if quiet and not _VERBOSE else logging.WARNING)
    if quiet and not _VERBOSE:
        import warnings

        warnings.simplefilter("ignore")
        if _STANDALONE:
            os.environ["PYTHONWARNINGS"] = "ignore"


def _say_written(folder: Path, names: tuple[str, ...], runs: str) -> None:
    """The last lines of sweep and compare: where the table, figure and runs are."""
    wrote = [n for n in names if (folder / n).is_file()]
    typer.echo(f"wrote {', '.join(str(folder / n) for n in wrote)}")
    typer.echo(f"runs: {folder}/ ({runs}; open one with placeloc show {shlex.quote(str(folder))}/RUN)")


def _fail(exc: Exception) -> None:
    typer.secho(f"error: {_one_line(exc)}", fg=typer.colors.RED, err=True)
    raise typer.Exit(2)


def _stage(stage: str, config: Path, run_dir: Path | None, sets: List[str] | None, force: bool,
           quiet: bool, all_stages: bool = False, wait: bool = False, reuse: List[Path] | None = None) -> None:
    from placeloc.core.config import load_config
    from placeloc.core.runner import run_stage

    _setup_logging(quiet)
    _check_utf8_path(run_dir, "--run-dir")
    # Errors reach the user through ErrorBoundaryGroup (one line, rc 2; a bug: traceback).
    cfg = load_config(config, sets)
    out = run_dir or Path("runs") / config.stem
    if all_stages:
        from placeloc.api import last_stage

        stage = last_stage(cfg)
    for donor in reuse or ():
        if not donor.is_dir():
            raise ValueError(f"--reuse {donor}: not a folder; give a run directory (one holding build-dictionary.h5, "
                             "index.h5, ...)")
    path = run_stage(cfg, out, stage, force=force and not all_stages, quiet=quiet, force_all=force and all_stages,
                     wait=wait, reuse=list(reuse or ()))
    typer.echo(f"{stage}: {path}")
    if all_stages and stage != "evaluate":
        from placeloc.evaluation.report import answer_lines

        for line in answer_lines(out):
            typer.echo(f"  {line}")
        typer.echo(f"evaluate: skipped, no ground truth to score against (ground_truth.kind: none); the answers are in "
                   f"{out}; `placeloc show {shlex.quote(str(out))}` draws them")
    if stage == "evaluate" and (path.parent / "metrics.json").is_file():
        from placeloc.evaluation.contracts import headline
        from placeloc.evaluation.report import format_value

        for key, value in headline(path.parent):
            typer.echo(f"  {key}: {format_value(value)}")
        typer.echo(f"metrics: {path.parent / 'metrics.json'}")
        if (path.parent / "report.html").is_file():
            typer.echo(f"report: {path.parent / 'report.html'}")


@app.command()
def extract(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
            force: bool = ForceOpt, quiet: bool = QuietOpt, wait: bool = WaitOpt) -> None:
    """Stage 1: read the image folders and compute per-image features -> extract.h5."""
    _stage("extract", config, run_dir, set, force, quiet, wait=wait)


@app.command("build-dictionary")
def build_dictionary(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
                     force: bool = ForceOpt, quiet: bool = QuietOpt, wait: bool = WaitOpt) -> None:
    """Stage 2: build the method's map/dictionary/database -> build-dictionary.h5."""
    _stage("build-dictionary", config, run_dir, set, force, quiet, wait=wait)


@app.command("build")
def build(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
          force: bool = ForceOpt, quiet: bool = QuietOpt, wait: bool = WaitOpt) -> None:
    """Alias of build-dictionary."""
    _stage("build-dictionary", config, run_dir, set, force, quiet, wait=wait)


@app.command()
def index(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
          force: bool = ForceOpt, quiet: bool = QuietOpt, wait: bool = WaitOpt) -> None:
    """Stage 3: index the dictionary/database for fast search -> index.h5."""
    _stage("index", config, run_dir, set, force, quiet, wait=wait)


@app.command()
def localize(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
             force: bool = ForceOpt, quiet: bool = QuietOpt, wait: bool = WaitOpt,
             reuse: List[Path] | None = ReuseOpt) -> None:
    """Stage 4: match every query against the reference -> localize.h5 (+ matches.csv)."""
    _stage("localize", config, run_dir, set, force, quiet, wait=wait, reuse=reuse)


@app.command()
def evaluate(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
             force: bool = ForceOpt, quiet: bool = QuietOpt, wait: bool = WaitOpt) -> None:
    """Stage 5: score against ground truth -> evaluate.h5, metrics.json and plots."""
    _stage("evaluate", config, run_dir, set, force, quiet, wait=wait)


@app.command()
def run(config: Path = ConfigArg, run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt,
        force: bool = typer.Option(False, "--force", "-f", help="Re-run every stage."), quiet: bool = QuietOpt,
        wait: bool = WaitOpt, reuse: List[Path] | None = ReuseOpt) -> None:
    """All stages in order; up-to-date stages are skipped, so an interrupted run resumes."""
    _stage("evaluate", config, run_dir, set, force, quiet, all_stages=True, wait=wait, reuse=reuse)


@app.command("params")
def params_(method: str = typer.Argument("", help="A method (seqslam, pirf, umap, coembed, retrieval, ...); "
                                                   "left out: the sections every config shares.")) -> None:
    """List every setting with its default, allowed values and meaning (from the parameter dataclasses)."""
    from placeloc.core import params as P
    from placeloc.core.common_params import CommonParams
    from placeloc.core.config import ConfigError
    from placeloc.core.methods import METHOD_NAMES, get_method

    if method and method not in METHOD_NAMES:
        raise ConfigError(f"params: {method!r} is not a method; choose one of {', '.join(METHOD_NAMES)}")
    rows = P.describe(get_method(method).params, f"{method}.") if method else P.describe(CommonParams)
    width = max(len(k) for k, *_ in rows)
    for key, default, allowed, text in rows:
        shown = "null" if default is None else str(default).lower() if isinstance(default, bool) else str(default)
        typer.echo(f"{key:<{width}}  {shown}" + (f"  ({allowed})" if allowed else "") + (f"\n{'':<{width}}    {text}" if text else ""))
    if not method:
        typer.echo(f"\nEach method's own section: placeloc params METHOD ({', '.join(METHOD_NAMES)}).")


@app.command()
def inspect(file: Path = typer.Argument(..., help="An artifact (.h5) written by placeloc.")) -> None:
    """Explain an artifact: its stage, provenance (config, inputs, version) and contents."""
    from placeloc.core.artifacts import describe

    try:
        typer.echo(describe(file))
    except (IsADirectoryError, FileNotFoundError):
        raise
    except OSError as exc:
        from placeloc.core.artifacts import unusable_reason

        # h5py's text alone does not name the file, nor say what a truncated one means
        raise ValueError(f"{file}: cannot be read as a placeloc artifact: {unusable_reason(file) or _one_line(exc)}; "
                         "run its stage again (placeloc STAGE CONFIG -o RUN_DIR -f)") from exc


@app.command()
def plan(model: Path = typer.Argument(..., help="A floor plan (floor_plan.yaml), a ZInD zind_data.json or a wireframe: "
                                                "what umap.model names."),
         out: Path | None = typer.Option(None, "--out", help="Folder for plan.png and view.png (default "
                                                             "runs/plan-<the file's name>)."),
         floor: str | None = typer.Option(None, help="The floor of a zind_data.json, e.g. floor_01 (umap.floor)."),
         at: str | None = typer.Option(None, help="X,Y in metres: also draw view.png, the map's lines as a 360 deg "
                                                  "camera there would see them, to hold against a photo taken there."),
         heading: float = typer.Option(0.0, help="The view's centre column, degrees (0 along +x, counter-clockwise)."),
         photo: Path | None = typer.Option(None, help="A 360 deg photo taken at --at: its lines against the map's "
                                                      "there (photo.png), at the heading where they match best."),
         z: float | None = typer.Option(None, help="The camera height in metres (default the plan's camera_z; "
                                                   "umap.grid.z)."),
         step: float | None = typer.Option(None, help="The grid's step in metres (default umap.grid.step_m's)."),
         wall_margin: float | None = typer.Option(None, help="The grid's least distance from a wall in metres "
                                                             "(default umap.grid.wall_margin_m's)."),
         rooms_for: Path | None = typer.Option(None, "--rooms-for", help="A folder of photos (what query.images "
                                                                         "names): also write rooms.csv, a row for "
                                                                         "each photo with its room left empty, to "
                                                                         "fill in and give as umap.room_hints."),
         look_alike: bool = typer.Option(True, "--look-alike/--no-look-alike",
                                         help="Say which rooms another room looks like from inside (a plan of rooms "
                                              "with a camera height; a few seconds): photos taken in a look-alike "
                                              "room need their room named (umap.room_hints).")) -> None:
    """Check a floor plan before localizing against it: its rooms and their areas, doors and
    windows, camera height, the places localize searches and the rooms that look alike from
    inside, printed, and drawn in plan.png (with --at, view.png too; with --photo, photo.png;
    with --rooms-for, a rooms.csv to fill in)."""
    from placeloc.core.images import ImageError
    from placeloc.umap.plan_report import (
        draw,
        look_alike_lines,
        look_alike_rooms,
        photo_at,
        point_note,
        rooms_template,
        summarise,
    )

    point = None
    if at is not None:
        try:
            point = tuple(float(v) for v in at.split(","))
        except ValueError:
            point = ()
        if len(point) != 2 or not all(math.isfinite(v) for v in point):
            _fail(ValueError(f"--at {at!r}: give the point as X,Y in metres, e.g. --at 2.5,1.2"))
    if photo is not None and point is None:
        _fail(ValueError("--photo needs --at X,Y: where the photo was taken"))
    if rooms_for is not None and not rooms_for.is_dir():
        _fail(ValueError(f"--rooms-for {rooms_for}: not a folder; give the folder of photos (what query.images names)"))
    summary, built = summarise(model, floor=floor, step_m=step, wall_margin_m=wall_margin, z=z)
    for line in summary.lines() + ([point_note(built, point)] if point is not None else []):
        if line:
            typer.echo(line)
    alike = None
    if look_alike and summary.kind == "rooms" and summary.z is not None:
        alike = look_alike_rooms(built, z=summary.z, wall_margin_m=summary.wall_margin_m)
        for line in look_alike_lines(alike):
            typer.echo(line)
    held = None
    if photo is not None and point is not None:
        if summary.z is None:
            _fail(ValueError("--photo needs a camera height: the plan gives none (camera_z); give --z"))
        held = photo_at(built, point[0], point[1], summary.z, photo)
        heading = held.heading_deg
        typer.echo(f"{photo.name}: its lines match the map's at ({point[0]:g}, {point[1]:g}) best at heading "
                   f"{held.heading_deg:g} deg, score {held.score:.3f} (photo.png; view.png is drawn at that heading)")
    folder = out or Path("runs") / f"plan-{model.stem}"
    for path in draw(summary, built, folder, point, heading, held, alike):
        typer.echo(f"wrote {path}")
    if rooms_for is not None:
        try:
            path, count = rooms_template(summary, rooms_for, folder)
        except (ImageError, ValueError) as exc:
            _fail(exc)
        marked = [a.room for a in alike or [] if a.marked]
        typer.echo(f"wrote {path}: {count} photo{'s' if count != 1 else ''}; fill in the room of each you know (a name "
                   "above), leave the others empty, and give the file as umap.room_hints"
                   + (f"; those taken in {', '.join(marked)} (look-alike rooms) matter most" if marked else ""))


@app.command()
def synth(kind: str = typer.Argument(..., help="Data set kind: route (SeqSLAM route pair), corridor (UMap building), home (UMap panoramas), "
                                     "coembed (ABCD world), omni (PIRF video)."),
          out: Path = typer.Argument(..., help="Output folder."),
          seed: int = typer.Option(0, help="Random seed."),
          set: List[str] | None = typer.Option(None, "--set", "-s", help="Generator parameter, e.g. --set frames=200.")) -> None:
    """Generate a synthetic data set with known ground truth."""
    from placeloc.synth import generate, parse_settings

    params = parse_settings(kind, list(set or []))
    try:
        summary = generate(kind, out, seed=seed, **params)
    except (KeyError, TypeError) as exc:  # an unknown kind or generator parameter
        _fail(ValueError(str(exc).strip("'\"")))
    for k, v in summary.items():
        typer.echo(f"{k}: {v}")


@app.command(name="import")
def import_(kind: str = typer.Argument(..., help="Format: zind (a Zillow Indoor Dataset tour's zind_data.json)."),
            source: Path = typer.Argument(..., help="The file to import, e.g. zind_data.json."),
            out: Path = typer.Argument(..., help="Output folder: floor_plan.yaml, poses.csv and rooms.csv (each "
                                                "panorama's room, a umap.room_hints file; one folder per floor when "
                                                "the tour has several and --floor is not given)."),
            floor: str | None = typer.Option(None, help="The floor to import, e.g. floor_01 (default: every floor).")) -> None:
    """Import a home's floor plan and panorama poses for UMap (umap.model, ground_truth.path,
    umap.room_hints)."""
    from placeloc.geometry.floorplan import ModelError
    from placeloc.geometry.zind import import_zind

    if kind != "zind":
        _fail(ValueError(f"import {kind!r}: unknown format; known: zind"))
    if not source.is_file():
        _fail(ValueError(f"{source}: file not found; give the tour's zind_data.json"))
    try:
        summary = import_zind(source, out, floor)
    except ModelError as exc:
        _fail(exc)
    for part in (summary.values() if "floor" not in summary else [summary]):
        typer.echo(", ".join(f"{k}: {v}" for k, v in part.items()))


@app.command()
def compare(config: Path = ConfigArg,
            methods: str = typer.Option("sad,histeq,zncc,abs_zncc,isc,isc_ext,ocm,ocm_ext", help="Comma-separated SeqSLAM comparisons."),
            run_dir: Path | None = RunDirOpt, set: List[str] | None = SetOpt, quiet: bool = QuietOpt) -> None:
    """Run several SeqSLAM image comparisons on one data set; write a table and one PR plot."""
    from placeloc.core.config import ConfigError, load_config
    from placeloc.experiments.compare import compare_methods

    _setup_logging(quiet)
    cfg = load_config(config, set)
    if cfg["method"] != "seqslam":
        raise ConfigError(f"{config}: compare runs SeqSLAM image comparisons, but this config's method is "
                          f"{cfg['method']!r}; give a SeqSLAM config (method: seqslam), e.g. configs/demo.yaml")
    out = run_dir or Path("runs") / f"{config.stem}-compare"
    table = compare_methods(cfg, out, [m.strip() for m in methods.split(",") if m.strip()], quiet=quiet)
    typer.echo(table.read_text())
    _say_written(table.parent, ("table.md", "table.csv", "pr_curves.png"), "one run directory per comparison")


@app.command()
def experiment(name: str = typer.Argument(..., help="Experiment: one of the modules of placeloc/experiments/ with a main() "
                                                   "(seqslam, umap, coembed, pirf, pirf-large, pirf-dictionary, ...)."),
               out: Path | None = typer.Option(None, help="Output folder (default runs/experiment-NAME)."),
               quick: bool = typer.Option(False, help="Smaller variant for smoke runs."),
               quiet: bool = QuietOpt) -> None:
    """Reproduce a paper's experiment; writes its runs, tables and summary.json."""
    from placeloc.core.config import ConfigError
    from placeloc.experiments import EXPERIMENTS, run_experiment

    _setup_logging(quiet)
    if name not in EXPERIMENTS:
        raise ConfigError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}, "
                          "e.g. placeloc experiment seqslam --quick")
    path = run_experiment(name, out, quick=quick, quiet=quiet)
    typer.echo(f"results: {path}")


class _StderrThatMayClose:
    """Standard error that outlives its reader. Progress bars and log lines are not the
    run's results: when their pipe closes (``2>&1 | head -1``) or their file fills up
    (``2> /dev/full``), what is left of them is dropped and the run goes on, instead of a
    progress bar's write stopping the work (or being blamed on the run directory)."""

    def __init__(self, stream: Any) -> None:
        self._stream = stream
        self.closed_by_reader = False

    def write(self, text: str) -> int:
        if not self.closed_by_reader:
            try:
                return self._stream.write(text)
            except OSError:
                self.closed_by_reader = True
        return len(text)

    def flush(self) -> None:
        if not self.closed_by_reader:
            try:
                self._stream.flush()
            except OSError:
                self.closed_by_reader = True

    def __getattr__(self, name: str) -> Any:  # encoding, errors, fileno, isatty, buffer, ...
        return getattr(self._stream, name)


def main() -> None:
    global _STANDALONE
    _STANDALONE = True
    sys.stderr = _StderrThatMayClose(sys.stderr)
    install_signal_handlers(on_repeat=_second_signal)
    try:
        app()
    except SystemExit as exc:
        from placeloc.core.interrupts import received

        if received() is not None:
            _exit_now(exc.code if isinstance(exc.code, int) else 130)
        try:
            sys.stdout.flush()
        except OSError as flush_error:
            _outside_boundary(flush_error)
        raise
    except OSError as exc:
        # What Click prints itself (--help, usage errors) runs outside the boundary: a closed
        # pipe or a full output there must not end in the interpreter's traceback.
        if not _stdout_failed(exc):
            raise
        _outside_boundary(exc)


def _outside_boundary(exc: OSError) -> None:
    """:func:`_stdout_failure` for a write Click made before or after the command ran."""
    try:
        _stdout_failure(exc)
    except typer.Exit as leave:
        raise SystemExit(leave.exit_code) from None


_announced: list[bool] = []


def _announce_interrupt() -> None:
    if not _announced:
        _announced.append(True)
        typer.echo("interrupted; rerun to resume", err=True)


def _second_signal(signum: int) -> None:
    """A second Ctrl-C (or SIGTERM) while the first is being handled: say it once, remove
    this process's shared arrays, kill the workers and leave now (temporary files in the
    run directory are removed by the next run)."""
    import shutil
    import signal
    import tempfile

    from placeloc.core.executor import SHARED_PREFIX

    _announce_interrupt()
    for folder in Path(tempfile.gettempdir()).glob(f"{SHARED_PREFIX}{os.getpid()}-*"):
        shutil.rmtree(folder, ignore_errors=True)
    _exit_now(143 if signum == signal.SIGTERM else 130)


def _exit_now(code: int) -> None:
    """Leave at once after Ctrl-C or SIGTERM, cleanup done: the run's own ``finally`` blocks
    have removed temporary files and shared arrays and closed the executor. Python's exit
    handlers are skipped on purpose: multiprocessing's joins a worker that may be blocked on
    its queue, and a second Ctrl-C in there left the process waiting for ever. Child
    processes still alive are killed first (they would die with us anyway: parent-death
    signal)."""
    import multiprocessing
    import multiprocessing.resource_tracker
    import signal

    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.flush()
    logging.shutdown()
    # What dying threads and processes would print now is noise after our one line (a
    # pool's manager thread reporting its killed workers, the resource tracker's warning).
    with contextlib.suppress(OSError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
    for child in multiprocessing.active_children():
        with contextlib.suppress(Exception):
            child.kill()
    tracker = getattr(multiprocessing.resource_tracker, "_resource_tracker", None)
    pid = getattr(tracker, "_pid", None)
    if pid:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    os._exit(code)



# ---------------------------------------------------------------------------------------
# Looking at results and sweeping parameters (evaluation layer)
# ---------------------------------------------------------------------------------------
@app.command()
def show(run_dir: Path = typer.Argument(..., help="A run directory (after localize; evaluate adds right/wrong)."),
         sample: int | None = typer.Option(None, min=0, show_default=False,
                                           help="Queries spread over the traverse to draw (default 8). UMap panoramas: "
                                                "how many pictures besides the wrong ones, the doubtful answers first, "
                                                "then others spread over the run."),
         failures: int | None = typer.Option(None, min=0, show_default=False,
                                             help="Most confident wrong matches to draw (needs ground truth; default 8). "
                                                  "UMap panoramas: the wrong answers, the largest error first; "
                                                  "--sample 0 draws only those. Without either option an evaluated "
                                                  "UMap run keeps the pictures evaluate drew."),
         recall_at: str | None = typer.Option(None, help="Also print standard Recall@N for these N, e.g. 1,2,3,15 "
                                                         "(from per_query.csv; N up to its 20 candidates)."),
         quiet: bool = QuietOpt) -> None:
    """Draw the result's pictures (strips query | match | a true one; plan; map) and write RUN_DIR/report.html."""
    from placeloc.core.errors import ConfigError
    from placeloc.core.runner import lock_run_dir
    from placeloc.evaluation.show import ShowError, recall_from_per_query, show_run

    _setup_logging(quiet)
    if not run_dir.is_dir():
        _fail(FileNotFoundError(f"{run_dir} is not a folder; give a run directory, e.g. runs/demo"))
    try:
        # a run in progress is waited for: show reads what its stages are replacing
        with lock_run_dir(run_dir, wait=True):
            pictures, report = show_run(run_dir, sample=sample, failures=failures)
        for path in pictures:
            typer.echo(f"picture: {path}")
        if recall_at:
            ns = [int(n) for n in recall_at.split(",") if n.strip().isdigit() and int(n) >= 1]
            if len(ns) != len([n for n in recall_at.split(",") if n.strip()]):
                raise ConfigError(f"--recall-at {recall_at!r}: give whole numbers from 1, separated by commas, e.g. --recall-at 1,5,10")
            for n, (all_q, with_pos) in recall_from_per_query(run_dir, ns).items():
                fmt = lambda v: "n/a" if v is None else f"{v:.4f}"  # noqa: E731
                typer.echo(f"recall@{n}: {fmt(all_q)} (all queries), {fmt(with_pos)} (queries with a positive)")
    except (ShowError, ValueError) as exc:
        _fail(exc)
    typer.echo(f"report: {report}")


@app.command()
def sweep(config: Path = ConfigArg,
          grid: List[str] = typer.Option(..., "--grid", "-g", help="key=v1,v2,... (repeatable), e.g. --grid seqslam.ds=10,20 or "
                                                                  "--grid seqslam.thumbnail=[64,32],[32,16]"),
          out: Path | None = typer.Option(None, "--out", "-o", help="Sweep folder (default runs/<config name>-sweep)."),
          set: List[str] | None = SetOpt, force: bool = ForceOpt, quiet: bool = QuietOpt) -> None:
    """Run every combination of the grid (each its own run directory, resumable); one table and one plot.

    A stage the combinations share (the same inputs and keys: extract when only a localize
    key varies) is computed once and linked into the other folders.

    Each run draws its own pictures; --set plots=false leaves them out (on small runs they
    cost more than the method) and the table, sweep.png and each run's metrics are the same."""
    import yaml

    from placeloc.core.config import ConfigError, apply_override, read_yaml_file
    from placeloc.core.errors import StageError
    from placeloc.core.images import ImageError
    from placeloc.experiments.sweep import parse_grid, run_sweep

    _setup_logging(quiet)
    try:
        if not config.is_file():
            raise ConfigError(f"config file {config} does not exist")
        raw = read_yaml_file(config) or {}
        for item in set or []:
            apply_override(raw, item)
        table = run_sweep(raw, config.resolve().parent, parse_grid(grid), out or Path("runs") / f"{config.stem}-sweep",
                          quiet=quiet, force=force)
    except (ConfigError, ImageError, StageError, FileNotFoundError, yaml.YAMLError) as exc:
        _fail(exc)
    typer.echo(table.read_text())
    _say_written(table.parent, ("sweep.md", "sweep.csv", "sweep.png"), "one run directory per combination")


# Last, after every command is registered: `python -m placeloc.cli show` ran main() before
# show and sweep (defined below the first such block) existed.
if __name__ == "__main__":
    main()
