"""Size, memory and disk estimates before the work: refuse a run that cannot fit, with the figure.

Each method registers an estimator in :data:`ESTIMATORS` that reads the validated config
(and the listed image sets) and returns :class:`Need` rows: what is large, the config key
that sets it, and the bytes of memory (per process, times the workers that run at once)
and of disk (written to the run directory). :func:`check_resources` compares them with
the memory available now (``/proc/meminfo`` MemAvailable, or ``PLACELOC_MEMORY_LIMIT_MB``)
and the free space of the run directory (``PLACELOC_DISK_LIMIT_MB`` caps it for tests),
and raises :class:`ResourceError` naming the figure, the limit and the key to change.

Image sizes come from the PNG/JPEG/BMP headers (a few bytes per file), never from decoding:
one 8000x8000 frame would cost seconds and gigabytes before any check could run.

The estimates are deliberately rough (within a factor of about two): they exist to stop a
run that would need ten or a thousand times the machine, not to pack memory tightly.
"""

from __future__ import annotations

import math
import os
import shutil
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence


class ResourceError(ValueError):
    """The work would need more memory or disk than there is; the message gives both figures."""


@dataclass
class Need:
    what: str
    key: str
    memory: int = 0  # bytes held at once by the processes doing the work
    disk: int = 0  # bytes written to the run directory
    stage: str = ""  # the stage that needs it ("" for every stage asked about)


# What a stage's process holds beyond what it had before the stage, whatever the data's
# size: libraries loaded and code compiled while the stage runs (numba/llvmlite kernels,
# OpenCV, faiss, matplotlib), per method and stage; measured with tests/resource_probe.py
# (figures and command in docs/reliability.md), rounded up.
BASE_MEMORY: dict[str, dict[str, int]] = {
    "seqslam": {"extract": 32 << 20, "build-dictionary": 64 << 20, "index": 64 << 20, "localize": 130 << 20,
                "evaluate": 100 << 20},
    "umap": {"extract": 100 << 20, "build-dictionary": 64 << 20, "index": 100 << 20, "localize": 100 << 20,
             "evaluate": 100 << 20},
    "pirf": {"extract": 64 << 20, "build-dictionary": 32 << 20, "index": 64 << 20, "localize": 64 << 20,
             "evaluate": 32 << 20},
    "coembed": {"extract": 16 << 20, "build-dictionary": 16 << 20, "index": 16 << 20, "localize": 40 << 20,
                "evaluate": 64 << 20},
}


def _mb(n: float) -> str:
    if n >= 2**40:
        return f"{n / 2**40:.1f} TiB"
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def env_megabytes(name: str) -> int | None:
    """A size limit in MB from the environment variable ``name`` (None when unset)."""
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
    return int(value * 2**20)


def memory_limit() -> int:
    """Bytes of memory a run may use: PLACELOC_MEMORY_LIMIT_MB if set, else MemAvailable."""
    env = env_megabytes("PLACELOC_MEMORY_LIMIT_MB")
    if env is not None:
        return env
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 1 << 62  # unknown: do not refuse


def disk_free(folder: Path) -> int:
    """Free bytes where ``folder`` lives (PLACELOC_DISK_LIMIT_MB caps it, for tests)."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    env = env_megabytes("PLACELOC_DISK_LIMIT_MB")
    return min(free, env) if env is not None else free


# ----------------------------------------------------------------- image headers

def image_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) from a PNG, JPEG, BMP or PNM header; None when the format is not one
    of those or the header is damaged (the decoder then reports the file)."""
    # A raw descriptor and one 32-byte read: a buffered file object costs several times the
    # system calls, and every image of a traverse is checked before extract.
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        head = os.read(fd, 32)
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            return struct.unpack(">II", head[16:24])
        if head[:2] == b"BM" and len(head) >= 26:
            w, h = struct.unpack("<ii", head[18:26])
            return abs(w), abs(h)
        if head[:2] in (b"P5", b"P6", b"P2", b"P3"):
            fields = head[2:].split()
            return (int(fields[0]), int(fields[1])) if len(fields) >= 2 else None
        if head[:2] == b"\xff\xd8":
            with open(fd, "rb", closefd=False) as fh:
                return _jpeg_size(fh)
    except (OSError, ValueError, struct.error):
        return None
    finally:
        os.close(fd)
    return None


def _jpeg_size(fh: Any) -> tuple[int, int] | None:
    fh.seek(2)
    for _ in range(10000):
        marker = fh.read(2)
        if len(marker) < 2 or marker[0] != 0xFF:
            return None
        kind = marker[1]
        if kind in (0xD8, 0x01) or 0xD0 <= kind <= 0xD7:
            continue
        length = struct.unpack(">H", fh.read(2))[0]
        # SOF0..SOF15 carry the frame size, except DHT (C4), JPG (C8) and DAC (CC).
        if 0xC0 <= kind <= 0xCF and kind not in (0xC4, 0xC8, 0xCC):
            _, h, w = struct.unpack(">BHH", fh.read(5))
            return w, h
        fh.seek(length - 2, 1)
    return None


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

def _workers(config: dict[str, Any]) -> int:
    return max(1, int(config["executor"].get("workers", 1)))


def _count(images: dict[str, Any]) -> int:
    return sum(len(s) for s in images.values())


def _decode_need(config: dict[str, Any], images: dict[str, Any], bytes_per_pixel: int, why: str,
                 stages: Sequence[str]) -> list[Need]:
    # Only ``extract`` decodes images: a later stage alone must not open every image's header.
    if "extract" not in stages:
        return []
    pixels, path = largest_image(images)
    if not pixels:
        return []
    return [Need(f"{why} of the largest image {path} ({pixels / 1e6:.1f} megapixels) x {_workers(config)} worker(s)",
                 "the image size (resize the images) or executor.workers", memory=pixels * bytes_per_pixel * _workers(config),
                 stage="extract")]


def seqslam_needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    from placeloc.seqslam.comparisons import feature_dtype

    p = config["seqslam"]
    w, h = p["thumbnail"]
    pixels = int(w) * int(h)
    fbytes = feature_dtype(p["comparison"], p.get("normalisation", "")).itemsize
    n = _count(images)
    per_task = min(int(p["images_per_task"]), max(1, n))
    workers = _workers(config)
    needs = []
    # extract: a worker holds its chunk's decoded frames, uint8 thumbnails and features;
    # extract.h5 stores thumbnails and features uncompressed, in chunks of up to 1024
    # rows that HDF5 allocates whole (so a traverse rounds up to the next chunk).
    rows = 0
    for s in images.values():
        chunk = min(1024, max(1, len(s)))
        rows += -(-len(s) // chunk) * chunk
    needs.append(Need(f"SeqSLAM thumbnails {w}x{h} x {per_task} images per task x {workers} worker(s)",
                      "seqslam.thumbnail (or seqslam.images_per_task)", stage="extract",
                      memory=(1 + fbytes) * pixels * (n + per_task * workers),
                      disk=(1 + fbytes) * pixels * rows + 64 * n + (1 << 18)))  # + names, index, HDF5's own
    if "reference" in images:
        n_ref = len(images["reference"])
        n_query = len(images["query"]) if "query" in images else n_ref
        block = min(int(p.get("block_size", 1024)), n_query)
        d_block = 4 * n_ref * block
        d_full = 4 * n_ref * n_query if p.get("store_difference") else 0
        top_k = int(p.get("top_k", 10))
        # localize: both traverses' features and about 8 float32 blocks of D at once (D,
        # its enhanced copy, the sequence search's scores and their temporaries);
        # localize.h5 keeps D (chunked: 5% over) when store_difference, matches.csv a row
        # per query, and the ranked result contract a second copy of the candidates (int64)
        # and scores (float32) with both traverses' names and indices.
        # Measured: 138, 214, 299 MB at 1500, 3000, 6000 frames a traverse.
        needs.append(Need(f"the {n_ref} x {n_query} difference matrix, {block} query columns at a time",
                          "seqslam.block_size (memory) or seqslam.store_difference: false (disk)", stage="localize",
                          memory=fbytes * pixels * (n_ref + n_query) + 8 * d_block + 64 * top_k * n_query,
                          disk=d_full * 21 // 20 + (600 + 12 * top_k + 64) * n_query + 64 * n_ref + (1 << 18)))  # + HDF5's own
        # evaluate: D read back a block at a time, with its enhanced copies, the masked
        # minima and the plot's subsamples (about 20 blocks; measured 164, 305, 516 MB at
        # 1500, 3000, 6000 frames); per_query.csv and evaluate.h5 about 800 bytes a query;
        # the PNGs and report.html a few MB.
        # The PNGs (the difference-matrix picture subsamples D to at most 800 x 800, two
        # panels) and report.html, which embeds them again in base64: about 2.5 times their
        # sum (the strips of samples and of failures about 160 kB each; measured 2.6 MiB in
        # all for configs/demo.yaml, 81 queries, estimated 3.5 MiB).
        plotting = bool(config.get("plots", True))
        pictures = (600_000 + 2 * min(n_ref, 800) * min(n_query, 800)) * 5 // 2 if plotting else 0
        needs.append(Need(f"scoring {n_query} queries against {n_ref} references, {block} at a time",
                          "seqslam.block_size", stage="evaluate",
                          memory=(20 * d_block if d_full else 2 * d_block) + 64 * top_k * n_query + (24 << 20 if plotting else 0),
                          disk=800 * n_query + pictures))
    return [n for n in needs if n.stage in stages] + _decode_need(config, images, 8, "decoding", stages)


def pirf_needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    p = config.get("pirf") or {}
    n = _count(images)
    dims = 64 if str(p.get("features", "sift")).startswith("surf") else (61 if p.get("features") == "akaze" else 128)
    per_feature = 4 * dims + 24  # float32 descriptor, position, scale, angle
    # extract.h5 holds at most n_features descriptors a frame: an upper bound (frames with
    # fewer features write less; measured 73 kB a frame on 480x240 synthetic frames).
    n_features = int(p.get("n_features", 1000))
    needs = [Need(f"PIRF features of {n} frames (at most {n_features} a frame)", "pirf.n_features", stage="extract",
                  disk=n * n_features * per_feature)]
    cap = n * int(p.get("n_pmax", 200)) * per_feature  # at most n_pmax PIRFs per window, a window per frame
    # build-dictionary: the windows' PIRFs and the growing dictionary (measured 37 and 106 MB
    # for 80 and 260 frames, against caps of 8.6 and 28 MB).
    needs.append(Need("the PIRF dictionary (at most pirf.n_pmax PIRFs a window)", "pirf.n_pmax", stage="build-dictionary",
                      memory=3 * cap, disk=cap))
    needs.append(Need("the dictionary's ANN index", "pirf.ann", stage="index", memory=2 * cap, disk=cap))
    # SIFT/SURF on one frame: about 240 bytes of scale space per pixel (measured: one
    # 8000x8000 frame took 14.9 GB).
    return [x for x in needs if x.stage in stages] + \
        _decode_need(config, images, 240, "feature extraction (about 240 bytes a pixel)", stages)


def _count_lines(path: Any) -> int:
    """Rows of a text file (a fast count of newlines; 0 when it cannot be read)."""
    try:
        with open(path, "rb") as fh:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: fh.read(1 << 20), b""))
    except (OSError, TypeError):
        return 0


def coembed_needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    p = config["coembed"]
    needs = []
    if p.get("source", "csv") == "csv" and p.get("observations"):
        n_obs = _count_lines(p["observations"])
        # extract: the parsed observation table (about 110 bytes an observation, measured
        # 84 MB for 964,000), stored compressed (measured 8 bytes an observation);
        # localize: the sparse system and its factorisation (measured 193 MB for 964,000:
        # 200 bytes an observation), the path and map CSVs.
        needs.append(Need(f"{n_obs:,} observations ({p['observations']})", "the observation file's size", stage="extract",
                          memory=110 * n_obs, disk=14 * n_obs + (1 << 19)))
        needs.append(Need(f"the co-embedding system of {n_obs:,} observations", "the observation file's size",
                          stage="localize", memory=200 * n_obs, disk=3 * n_obs + (1 << 18)))
    return [x for x in needs if x.stage in stages] + \
        _decode_need(config, images, 240, "feature extraction (about 240 bytes a pixel)", stages)


def _plan_grid_size(p: dict[str, Any], step: float) -> tuple[int, int, float] | None:
    """(x points, y points, share inside the plan) of the grid over ``umap.model``'s plan
    bounds at ``step`` (None when the model cannot be read)."""
    import numpy as np

    from placeloc.geometry.floorplan import load_model, model_bounds

    try:
        model = load_model(p["model"], p.get("floor"))
        lo, hi = model_bounds(model)
    except Exception:  # noqa: BLE001 - any unreadable model: its own check names the problem
        return None
    nx, ny = (math.floor(float(hi[k] - lo[k]) / step + 1e-9) + 1 for k in (0, 1))
    # the share inside, on a grid of at most 200 x 200 over the same box
    sx, sy = np.linspace(lo[0], hi[0], min(nx, 200)), np.linspace(lo[1], hi[1], min(ny, 200))
    xy = np.stack(np.meshgrid(sx, sy, indexing="ij"), -1).reshape(-1, 2)
    return nx, ny, float(np.mean(model.inside(xy)))


def umap_needs(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    p = config["umap"]
    g = p["grid"]
    axes = []
    inside_share = 1.0
    for name in ("x", "y"):
        if g.get(name) is None:
            # the grid covers the model's plan at grid.step_m: its bounding box at that step,
            # of which the positions inside the plan are kept (doorways add a few: +10 %)
            plan = _plan_grid_size(p, float(g.get("step_m") or 0.25))
            if plan is None:  # the model's own check reports an unreadable model
                return _decode_need(config, images, 16, "decoding", stages)
            axes, inside_share = [plan[0], plan[1]], (min(1.0, 1.1 * plan[2]) if g.get("inside_only", True) else 1.0)
            break
        start, stop, step = (float(v) for v in g[name])
        if step <= 0 or stop < start:
            return []  # pose_grid reports these with its own message
        axes.append(math.floor((stop - start) / step + 1e-9) + 1)
    panorama = p.get("query_kind") == "panorama"
    positions = max(1, math.ceil(axes[0] * axes[1] * inside_share))
    views = positions if panorama else positions * max(1, len(g["headings"]))
    size = p.get("panorama" if panorama else "camera") or {}
    w, h = int(size.get("width", 160)), int(size.get("height", 120))
    words = (w * h + 63) // 64
    db = views * words * 8  # one bit per pixel per view
    pooled = 0 if panorama else views * (((w // 8) * (h // 8) + 63) // 64) * 8
    block = min(int(p.get("block", 2048)), views)
    # the chamfer score's index: per position both map images' row spectra, (w // 2 + 1)
    # frequencies x 2h rows of complex64, written 1024 positions at a time (that block and
    # its FFT temporaries: measured 257 and 441 MB for blocks of 770 and 1024 positions of
    # 144 x 72, about 4-5 blocks of spectra) and read whole by localize
    spectra = views * (w // 2 + 1) * 2 * h * 8 if panorama and (p.get("panorama") or {}).get("score", "chamfer") == "chamfer" else 0
    what = f"UMap database of {views:,} views of {w}x{h} (x {g['x'] or 'the plan'}, y {g['y'] or 'the plan'}" + \
        ("" if panorama else f", {len(g['headings'])} headings") + ")"
    key = "umap.grid (a larger step or a smaller range) or the camera size"
    # build-dictionary: the grid (poses, the free-space test) and what HDF5 and the
    # renderer hold of the database as it is written: measured 80, 85 and 199 MB for 46,000
    # and 182,000 views of 160x120 and 182,000 of 40x30, i.e. 40 MB + 204 bytes a view +
    # 0.28 of the database (estimated: 256 bytes and 0.4), and with a pool each worker's
    # block of uint8 views; writes the database, its pooled cells, the poses and the plan.
    # index: per-view counts (and, for panoramas, a dilated copy of the database).
    # localize: the whole database, the pooled cells, poses and per-view scores (about
    # 160 bytes a view; measured 176 and 525 MB for 46,000 and 182,000 views of 160x120).
    pool = block * w * h * _workers(config) if _workers(config) > 1 else 0
    needs = [Need(what, key, stage="build-dictionary", memory=256 * views + db * 2 // 5 + pool,
                  disk=db + pooled + 48 * views + (1 << 20)),
             Need(what, key, stage="index", memory=(2 * db if panorama else 0) + 24 * views + 11 * min(spectra, 1024 * (w // 2 + 1) * 2 * h * 8) // 2,
                  disk=(db if panorama else 0) + 48 * views + spectra),
             Need(what, key, stage="localize", memory=db + pooled + 160 * views + spectra, disk=1 << 20)]
    return [n for n in needs if n.stage in stages] + _decode_need(config, images, 16, "decoding", stages)


# ----------------------------------------------------------------- cross-key rules

def seqslam_rules(config: dict[str, Any]) -> list[str]:
    p = config["seqslam"]
    w, h = p["thumbnail"]
    problems = []
    if p["patch"] > min(w, h):
        problems.append(f"seqslam.patch ({p['patch']}) is larger than the thumbnail ({w}x{h}); "
                        f"it must be <= {min(w, h)} (the smaller thumbnail side)")
    return problems


# Method name -> rules over the validated config that no single key's range can express.
CONFIG_RULES: dict[str, Callable[[dict[str, Any]], list[str]]] = {
    "seqslam": seqslam_rules,
}


def config_problems(config: dict[str, Any]) -> list[str]:
    fn = CONFIG_RULES.get(config["method"])
    return fn(config) if fn else []


def seqslam_input_rules(config: dict[str, Any], images: dict[str, Any]) -> list[str]:
    """A sequence of ds + 1 frames must fit in each traverse (else every query is
    unmatched and Recall@1 is 0 with no word)."""
    ds = int(config["seqslam"]["ds"])
    problems = []
    for role in ("query", "reference"):
        if role in images and ds + 1 > len(images[role]):
            n = len(images[role])
            problems.append(f"seqslam.ds={ds} needs sequences of ds + 1 = {ds + 1} frames, but the {role} traverse "
                            f"({images[role].source}) has {n} image(s); set seqslam.ds to at most {max(1, n - 1)} "
                            f"(e.g. --set seqslam.ds={max(1, min(10, n - 1))})")
            break
    return problems


# Method name -> rules over the config and the listed image sets (counted, never decoded),
# checked before the first stage runs.
INPUT_RULES: dict[str, Callable[[dict[str, Any], dict[str, Any]], list[str]]] = {
    "seqslam": seqslam_input_rules,
}


def check_inputs(config: dict[str, Any], images: dict[str, Any]) -> None:
    """Raise a ConfigError for parameters that cannot work on these inputs."""
    fn = INPUT_RULES.get(config["method"])
    problems = fn(config, images) if fn and images else []
    if problems:
        from placeloc.errors import ConfigError

        raise ConfigError("; ".join(problems))


ESTIMATORS: dict[str, Callable[[dict[str, Any], dict[str, Any], Sequence[str]], list[Need]]] = {
    "seqslam": seqslam_needs,
    "pirf": pirf_needs,
    "coembed": coembed_needs,
    "umap": umap_needs,
}


def estimate(config: dict[str, Any], images: dict[str, Any], stages: Sequence[str]) -> list[Need]:
    """What running ``stages`` (stage names) will need: the method's rows, and the memory a
    stage's process takes for its libraries (:data:`BASE_MEMORY`)."""
    fn = ESTIMATORS.get(config["method"])
    needs = fn(config, images, stages) if fn else []
    for stage in stages:
        base = BASE_MEMORY.get(config["method"], {}).get(stage, 0)
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
        from placeloc.artifacts import mount_point

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
