"""Size, memory and disk estimates before the work: refuse a run that cannot fit, with the figure.

Each method registers an estimator in :data:`ESTIMATORS` that reads the validated config
(and the listed image sets) and returns :class:`Need` rows: what is large, the config key
that sets it, and the bytes of memory (per process, times the workers that run at once)
and of disk (written to the run directory). :func:`check_resources` compares them with
the memory available now (``/proc/meminfo`` MemAvailable, or ``PLACELOC_MEMORY_LIMIT_MB``)
and the free space of the run directory (``PLACELOC_DISK_LIMIT_MB`` caps it for tests),
and raises :class:`ResourceError` naming the figure, the limit and the key to change.

Image sizes come from the headers (PNG, JPEG, BMP, PNM, TIFF, WebP, GIF: a few bytes per
file, :func:`placeloc.core.images.image_size`), never from decoding: one 8000x8000 frame
would cost seconds and gigabytes before any check could run.

The estimates are deliberately rough (within a factor of about two): they exist to stop a
run that would need ten or a thousand times the machine, not to pack memory tightly.
"""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from placeloc.core.images import image_size
from placeloc.core.safe_io import ENV_MEGABYTES_MAX, memory_budget


class ResourceError(ValueError):
    """The work would need more memory or disk than there is; the message gives both figures."""


@dataclass
class Need:
    what: str
    key: str
    memory: int = 0  # bytes held at once by the processes doing the work
    disk: int = 0  # bytes written to the run directory
    stage: str = ""  # the stage that needs it ("" for every stage asked about)


def _mb(n: float) -> str:
    if n >= 2**40:
        return f"{n / 2**40:.1f} TiB"
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def env_megabytes(name: str) -> int | None:
    """A size limit in MB from the environment variable ``name`` (None when unset or empty).
    The one parser of placeloc's numeric environment variables: a value that is not a
    finite number from 0 to :data:`ENV_MEGABYTES_MAX` is refused naming the variable."""
    env = os.environ.get(name, "").strip()
    if not env:
        return None
    try:
        value = float(env)
    except ValueError:
        value = float("nan")
    if not math.isfinite(value) or value < 0:
        raise ResourceError(f"{name}={env!r} is not a number of megabytes; set it to e.g. {name}=4096, or unset it "
                            f"(unset {name})")
    if value > ENV_MEGABYTES_MAX:
        raise ResourceError(f"{name}={env!r} is more megabytes than any machine has (at most {ENV_MEGABYTES_MAX}); "
                            f"set it to e.g. {name}=4096, or unset it (unset {name})")
    return int(value * 2**20)


def memory_limit() -> int:
    """Bytes of memory a run may use: PLACELOC_MEMORY_LIMIT_MB if set, else MemAvailable
    (:func:`placeloc.core.safe_io.memory_budget`, after the variable is checked here)."""
    env_megabytes("PLACELOC_MEMORY_LIMIT_MB")  # a bad value is refused, naming the variable
    return memory_budget()


def disk_free(folder: Path) -> int:
    """Free bytes where ``folder`` lives (PLACELOC_DISK_LIMIT_MB caps it, for tests)."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    env = env_megabytes("PLACELOC_DISK_LIMIT_MB")
    return min(free, env) if env is not None else free


# ----------------------------------------------------------------- image headers

def largest_image(images: dict[str, Any]) -> tuple[int, Path | None]:
    """(pixels, path) of the largest image named by the image sets (headers only)."""
    best, where = 0, None
    for s in images.values():
        for p in s.paths:
            size = image_size(p)
            if size and size[0] * size[1] > best:
                best, where = size[0] * size[1], p
    return best, where


# ----------------------------------------------------------------- estimators

def workers(config: dict[str, Any]) -> int:
    return max(1, int(config["executor"].get("workers", 1)))


def count_images(images: dict[str, Any]) -> int:
    return sum(len(s) for s in images.values())


def decode_need(config: dict[str, Any], images: dict[str, Any], bytes_per_pixel: int, why: str,
                 stages: Sequence[str], stage: str = "extract") -> list[Need]:
    """Memory for describing the largest image ``bytes_per_pixel`` at a time in ``stage``, as
    many at once as the engine describes concurrently: the workers times the threads each
    describes with (:func:`placeloc.core.imagework.threads_per_task`)."""
    # Only the stage that decodes opens the headers: a later stage alone must not open every image's header.
    if stage not in stages:
        return []
    pixels, path = largest_image(images)
    if not pixels:
        return []
    from placeloc.core.imagework import threads_per_task

    n_workers = workers(config)
    threads = threads_per_task(n_workers, pixels)
    at_once = n_workers * threads
    return [Need(f"{why} of the largest image {path} ({pixels / 1e6:.1f} megapixels) x {at_once} at once "
                 f"({n_workers} worker(s) x {threads} thread(s))",
                 "the image size (resize the images) or executor.workers", memory=pixels * bytes_per_pixel * at_once,
                 stage=stage)]


# ----------------------------------------------------------------- cross-key rules

def _resources(config: dict[str, Any]) -> Any:
    """The method's resources module (``placeloc.<method>.resources``; None when it has none):
    ``needs(config, images, stages)``; ``BASE_MEMORY`` (stage -> what the stage's process
    holds beyond what it had before, whatever the data's size: libraries loaded and kernels
    compiled while it runs, measured with tests/resource_probe.py, figures in
    docs/reliability.md, rounded up); optionally ``config_rules(config)`` and
    ``input_rules(config, images)``."""
    from placeloc.core.methods import get_method

    return get_method(config["method"]).resources


def config_problems(config: dict[str, Any]) -> list[str]:
    """The method's rules over the validated config that no single key's range can express."""
    fn = getattr(_resources(config), "config_rules", None)
    return fn(config) if fn else []


def check_inputs(config: dict[str, Any], images: dict[str, Any]) -> None:
    """Raise a ConfigError for parameters that cannot work on these inputs."""
    fn = getattr(_resources(config), "input_rules", None)
    problems = fn(config, images) if fn and images else []
    if problems:
        from placeloc.core.errors import ConfigError

        raise ConfigError("; ".join(problems))


def estimate(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    """What running ``stages`` (stage names) will need: the method's rows, and the memory a
    stage's process takes for its libraries (the method's ``BASE_MEMORY``)."""
    res = _resources(config)
    needs = res.needs(config, images, stages) if res is not None else []
    for stage in stages:
        base = getattr(res, "BASE_MEMORY", {}).get(stage, 0)
        if base:
            needs.append(Need("placeloc's libraries and compiled kernels while the stage runs", "nothing (a fixed need)",
                              memory=base, stage=stage))
    return needs


def stage_memory(needs: Sequence[Need], stage: str) -> int:
    """What one stage holds at once (its rows, the fixed need included)."""
    return sum(n.memory for n in needs if n.stage == stage)


def check_resources(config: dict[str, Any], images: dict[str, Any], run_dir: Path, stages: Sequence[str]) -> list[Need]:
    """Raise :class:`ResourceError` when what ``stages`` need exceeds the memory or disk there is."""
    needs = estimate(config, images, stages)
    mem = memory_limit()
    cap = env_megabytes("PLACELOC_MEMORY_LIMIT_MB")
    for need in needs:
        if need.key == "nothing (a fixed need)":  # part of each stage's total, not a figure of its own
            continue
        if need.memory > mem and cap is not None:
            raise ResourceError(f"{need.what} needs about {_mb(need.memory)} of memory, more than "
                                f"PLACELOC_MEMORY_LIMIT_MB={os.environ['PLACELOC_MEMORY_LIMIT_MB'].strip()} allows "
                                f"({_mb(mem)}); raise or unset PLACELOC_MEMORY_LIMIT_MB, or reduce {need.key}")
        if need.memory > mem:
            raise ResourceError(f"{need.what} needs about {_mb(need.memory)} of memory; {_mb(mem)} is available "
                                f"(limit: MemAvailable or PLACELOC_MEMORY_LIMIT_MB); reduce {need.key}")
    disk = sum(n.disk for n in needs)
    free = disk_free(run_dir)
    if disk > free:
        from placeloc.core.artifacts import mount_point

        biggest = max(needs, key=lambda n: n.disk)
        cap = env_megabytes("PLACELOC_DISK_LIMIT_MB")
        if cap is not None and cap == free:  # the variable, not the file system, is what is short
            raise ResourceError(f"{run_dir}: the run needs about {disk / 2**20:.0f} MB of disk for {biggest.what}, more than "
                                f"PLACELOC_DISK_LIMIT_MB={os.environ['PLACELOC_DISK_LIMIT_MB'].strip()} allows; raise or "
                                f"unset PLACELOC_DISK_LIMIT_MB, or reduce {biggest.key}")
        raise ResourceError(f"no space left on {mount_point(run_dir)} while writing {run_dir} (needs about "
                            f"{disk / 2**20:.0f} MB for {biggest.what}; {free / 2**20:.0f} MB free); free space, "
                            f"choose another --run-dir or reduce {biggest.key}")
    return needs
