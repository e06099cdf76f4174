"""Measure what a stage really needs, to hold the size estimates of placeloc.core.limits to account.

``python tests/resource_probe.py CONFIG RUN_DIR STAGE [--set k=v ...]`` runs the stages
before STAGE (unmeasured), then STAGE alone in a fresh process and prints one JSON line:
the estimate (memory and disk, from placeloc.core.limits.estimate for that stage alone) and the
measurement: the growth of the peak resident memory over the memory held just before the
stage (imports and the parent artifacts' metadata excluded), and the bytes the stage added
to the run directory (its artifact and side outputs).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _peak() -> int:
    """The peak resident memory of this process image (VmHWM). Not ru_maxrss: that keeps
    the peak of the process this one was forked from (a test runner of 400 MB)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _reset_peak() -> None:
    """Start the peak afresh from the memory held now (Linux: clear_refs 5)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _dir_files(run: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(run)): (p.stat().st_size, p.stat().st_mtime_ns) for p in run.rglob("*")
            if p.is_file() and p.name not in ("log.txt", ".lock", "config.yaml")}


def measure(config: str, run_dir: str, stage: str, sets: list[str]) -> dict:
    from placeloc.core.config import load_config
    from placeloc.core.limits import estimate
    from placeloc.core.methods import get_method
    from placeloc.core.runner import image_sets, run_stage

    cfg = load_config(config, sets)
    get_method(cfg["method"])  # import the method's modules before the baseline
    import cv2  # noqa: F401  (every image method imports it; not the stage's own need)
    import h5py  # noqa: F401

    images = image_sets(cfg)
    needs = [n for n in estimate(cfg, images, [stage]) if n.stage == stage]
    run = Path(run_dir)
    before = _dir_files(run) if run.is_dir() else {}
    _reset_peak()
    base = _rss()
    run_stage(cfg, run, stage, quiet=True, force=True)
    peak = _peak()
    after = _dir_files(run)
    written = sum(size for name, (size, mtime) in after.items() if before.get(name) != (size, mtime))
    return {"stage": stage, "method": cfg["method"],
            "estimate_memory": sum(n.memory for n in needs), "measured_memory": max(0, peak - base),
            "estimate_disk": sum(n.disk for n in needs), "measured_disk": written,
            "needs": [n.what for n in needs]}


def probe(config: str | Path, run_dir: str | Path, sets: list[str] | None = None, stages: list[str] | None = None,
          env: dict[str, str] | None = None) -> list[dict]:
    """Measure every stage (or ``stages``) of a run, each in a fresh process, in order."""
    from placeloc.core.methods import STAGES

    rows = []
    for stage in stages or STAGES:
        cmd = [sys.executable, __file__, str(config), str(run_dir), stage] + [f"--set={s}" for s in sets or []]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env={**os.environ, **(env or {})})
        if proc.returncode != 0:
            raise RuntimeError(f"probe of {stage} failed: {proc.stderr[-2000:]}")
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    return rows


if __name__ == "__main__":
    config, run_dir, stage, *rest = sys.argv[1:]
    sets = [a.split("=", 1)[1] for a in rest if a.startswith("--set=")]
    print(json.dumps(measure(config, run_dir, stage, sets)))
