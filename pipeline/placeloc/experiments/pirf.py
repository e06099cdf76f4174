"""``placeloc experiment pirf``: the paper's tables 2-4 and figs. 4-7 on a generated omni video.

One data set (``synth omni``, building layout, 480x240): a mapping run and an unseen test
run. For each update (plain, improved) the full pipeline runs with the default index
(faiss-hnsw, brute force alongside); the other backends reuse the same extract and
dictionary artifacts (hard links: artifacts are replaced, never modified, so sharing is
safe) and are compared against that run's brute-force m_t. Outputs under ``out_dir``:
``tables.md``, ``table2.csv``, ``table3.csv``, ``table4.csv``, ``fig45_mt_seconds.csv``/``.png``,
``fig67_accuracy.png``, ``summary.json`` (run name -> metrics).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

from placeloc.api import load_config, read_metrics, run
from placeloc.evaluation import write_metrics
from placeloc.experiments import pyplot, say, write_summary
from placeloc.pirf.ann import BACKENDS, AnnIndex
from placeloc.pirf.mapping import node_vector
from placeloc.pirf.metrics import PAPER_RADIUS_M, set_agreement
from placeloc.pirf.params import PirfParams, index_settings
from placeloc.pirf.results import read_dictionary, read_index_info, read_node_vectors, read_pirfs, stage_seconds
from placeloc.synth.omni import generate

DEFAULT_INDEX = "faiss-hnsw"
FULL = {"frames": 2000, "test_frames": 400}
QUICK = {"frames": 1200, "test_frames": 300}
TIMING_BACKENDS = ("bruteforce", "flann-kmeans", "flann-kdtree", "faiss-hnsw", "faiss-ivf")


def _data(out: Path, spec: dict[str, int], quiet: bool) -> Path:
    data = out / "data"
    meta = data / "params.json"
    want = {**spec, "width": 480, "layout": "building", "seed": 0}
    if meta.is_file() and json.loads(meta.read_text()) == want:
        return data
    shutil.rmtree(data, ignore_errors=True)
    say("pirf", quiet, f"rendering {spec['frames']} mapping + {spec['test_frames']} test frames")
    generate(data, seed=0, frames=spec["frames"], test_frames=spec["test_frames"], width=480, layout="building",
             workers=min(2, os.cpu_count() or 1))
    meta.write_text(json.dumps(want))
    return data


def _config(data: Path, **pirf: Any) -> dict[str, Any]:
    return load_config(data={
        "method": "pirf", "seed": 0,
        "reference": {"images": str(data / "mapping")}, "query": {"images": str(data / "test")},
        "ground_truth": {"kind": "poses", "path": str(data / "mapping" / "poses.csv"), "radius": PAPER_RADIUS_M},
        "executor": {"workers": min(2, os.cpu_count() or 1)}, "pirf": {"query_poses": str(data / "test" / "poses.csv"), **pirf}})


def _link(src: Path, dst: Path) -> None:
    if dst.exists() or not src.is_file():
        return
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def timing_sweep(dictionary: np.ndarray, queries: list[np.ndarray], sizes: list[int], backends: tuple[str, ...],
                 seed: int = 0) -> list[dict[str, Any]]:
    """Fig. 4-5: mean seconds to compute m_t per query frame, per backend and dictionary prefix."""
    rows = []
    settings = index_settings(PirfParams())
    for n in sizes:
        for b in backends:
            ix = AnnIndex(b, dictionary[:n], settings, seed).build()
            t0 = time.perf_counter()
            for q in queries:
                d2, i = ix.knn2(q)
                node_vector(d2, i, 0.7)
            rows.append({"backend": b, "dictionary_size": n, "build_seconds": ix.build_seconds,
                         "mt_seconds": (time.perf_counter() - t0) / len(queries)})
    return rows


def _backend_run(out: Path, data: Path, upd: str, b: str, rd: Path, m: dict[str, Any], runs: dict[str, dict[str, Any]],
                 t3: list[dict[str, Any]], quiet: bool) -> None:
    """Index + localize with backend ``b`` over ``rd``'s dictionary; compare with its brute-force m_t."""
    bf = read_node_vectors(rd, "bruteforce")
    rb = out / f"omni-{upd}-{b}"
    for stage in ("extract", "build-dictionary"):
        _link(rd / f"{stage}.h5", rb / f"{stage}.h5")
    say("pirf", quiet, f"{upd}: index {b}")
    run(_config(data, update=upd, index=b, compare_bf=False), rb, quiet=quiet)
    mb = read_metrics(rb)
    ag = set_agreement(*read_node_vectors(rb, b), *bf)
    mb["index_build_seconds"] = float(read_index_info(rb)["build_seconds"])
    mb.update({"jaccard_ann_bf": ag["jaccard"], "precision_ann_bf": ag["precision"], "recall_ann_bf": ag["recall"],
               "mt_seconds_bf": m["mt_seconds_bf"]})
    for g in range(3):
        mb[f"accuracy_gap{g}_bf"] = m[f"accuracy_gap{g}_bf"]
    mb = write_metrics(rb, mb)
    runs[f"omni-{upd}-{b}"] = mb
    t3.append({"update": upd, "backend": b, **{k: mb[k] for k in ("jaccard_ann_bf", "precision_ann_bf", "recall_ann_bf",
                                                                    "mt_seconds_ann", "mt_seconds_bf")}})


def main(out_dir: Path, quick: bool = False, quiet: bool = False, spec: dict[str, int] | None = None,
         backends: tuple[str, ...] | None = None, timing_backends: tuple[str, ...] | None = None,
         hnsw_mapping: bool = False) -> Path:
    """The paper's tables on generated data. ``spec``/``backends``/``timing_backends``
    override the size and the index backends (see ``experiment_large``); ``hnsw_mapping``
    also maps each update with the incremental HNSW graph (``pirf.map_search``) for Table 2."""
    pyplot()  # its figures need matplotlib: stop now, not after the runs, where it is missing
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = spec or (QUICK if quick else FULL)
    backends = backends or BACKENDS
    timing_backends = timing_backends or TIMING_BACKENDS
    data = _data(out, spec, quiet)
    runs: dict[str, dict[str, Any]] = {}
    t3: list[dict[str, Any]] = []
    first = out / "omni-plain"
    for upd in ("plain", "improved"):
        rd = out / f"omni-{upd}"
        _link(first / "extract.h5", rd / "extract.h5")  # both updates share the PIRFs
        t0 = time.perf_counter()
        say("pirf", quiet, f"{upd}: mapping, {DEFAULT_INDEX} index, localization, evaluation")
        run(_config(data, update=upd, index=DEFAULT_INDEX), rd, quiet=quiet)
        m = read_metrics(rd)
        m["wall_seconds"] = time.perf_counter() - t0
        m["build_seconds"] = stage_seconds(rd, "build-dictionary")
        m["extract_seconds"] = stage_seconds(rd, "extract")
        m["pirfs_per_frame"] = float(np.diff(read_pirfs(rd, "reference")[1]).mean())
        runs[f"omni-{upd}-{DEFAULT_INDEX}"] = m
        t3.append({"update": upd, "backend": DEFAULT_INDEX, **{k: m[k] for k in ("jaccard_ann_bf", "precision_ann_bf", "recall_ann_bf",
                                                                                  "mt_seconds_ann", "mt_seconds_bf")}})
        for b in backends:
            if b in (DEFAULT_INDEX, "bruteforce", "flann-auto"):
                continue
            _backend_run(out, data, upd, b, rd, m, runs, t3, quiet)
        if hnsw_mapping:
            rh = out / f"omni-{upd}-hnsw-mapping"
            _link(rd / "extract.h5", rh / "extract.h5")
            say("pirf", quiet, f"{upd}: mapping with the incremental HNSW graph")
            run(_config(data, update=upd, index=DEFAULT_INDEX, map_search="faiss-hnsw"), rh, quiet=quiet)
            runs[f"omni-{upd}-hnsw-mapping"] = read_metrics(rh)
        write_summary(out, runs)
    # Fig. 4-5: m_t time against dictionary size, on each update's dictionary
    fig_rows = []
    for upd in ("plain", "improved"):
        rd = out / f"omni-{upd}"
        dic = read_dictionary(rd)
        pirfs, off = read_pirfs(rd, "query")
        frames = [t for t in range(len(off) - 1) if off[t + 1] > off[t]][:: max(1, (len(off) - 1) // 40)][:40]
        queries = [pirfs[off[t]:off[t + 1]] for t in frames]
        sizes = sorted({int(round(len(dic) * k / 5)) for k in range(1, 6)})
        say("pirf", quiet, f"{upd}: timing m_t at sizes {sizes}")
        for r in timing_sweep(dic, queries, sizes, timing_backends):
            fig_rows.append({"update": upd, **r})
    _write_outputs(out, runs, t3, fig_rows)
    write_summary(out, runs)
    # The paper's autotuned FLANN last: its autotune takes minutes, and everything else is written by now.
    for upd in ("plain", "improved"):
        _backend_run(out, data, upd, "flann-auto", out / f"omni-{upd}", runs[f"omni-{upd}-{DEFAULT_INDEX}"], runs, t3, quiet)
        _write_outputs(out, runs, t3, fig_rows)
        write_summary(out, runs)
    return out / "summary.json"


def _csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def _f(v: Any, nd: int = 4) -> str:
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))


def _write_outputs(out: Path, runs: dict[str, dict[str, Any]], t3: list[dict[str, Any]], fig_rows: list[dict[str, Any]]) -> None:
    plt = pyplot()
    p, i = runs[f"omni-plain-{DEFAULT_INDEX}"], runs[f"omni-improved-{DEFAULT_INDEX}"]
    from placeloc.pirf.results import loop_closure_count

    t2 = [{"update": u, "dictionary_size": m["dictionary_size"], "loop_closures": loop_closure_count(m),
           "loop_closures_correct": m["loop_closures_correct"], "loop_closure_precision": m["loop_closure_precision"],
           "map_seconds_per_frame": m["loop_seconds_per_frame"]}
          for u, m in (("plain", p), ("improved", i), *((f"{u} (HNSW mapping)", runs.get(f"omni-{u}-hnsw-mapping")) for u in ("plain", "improved")))
          if m is not None]
    t4 = [{"update": u, "bf": m["accuracy_gap0_bf"], "ann": m["accuracy_gap0"], "bf_gap2": m["accuracy_gap2_bf"], "ann_gap2": m["accuracy_gap2"]}
          for u, m in (("plain", p), ("improved", i))]
    _csv(out / "table2.csv", t2)
    _csv(out / "table3.csv", t3)
    _csv(out / "table4.csv", t4)
    _csv(out / "fig45_mt_seconds.csv", fig_rows)
    lines = ["# PIRF-nav2 on generated omnidirectional video", "",
             f"mapping frames: {p['frames']}, PIRFs/frame: {_f(p.get('pirfs_per_frame'), 1)}", "",
             "## Table 2: dictionary update", "",
             "| update | dictionary | loop closures | correct | precision | map s/frame |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['update']} | {r['dictionary_size']} | {r['loop_closures']} | {r['loop_closures_correct']} | {_f(r['loop_closure_precision'])} "
              f"| {_f(r['map_seconds_per_frame'])} |" for r in t2]
    lines += ["", "## Table 3: m_ann against m_bf (query run)", "", "| update | backend | Jaccard | precision | recall | m_t s (ANN) | m_t s (BF) |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['update']} | {r['backend']} | {_f(r['jaccard_ann_bf'])} | {_f(r['precision_ann_bf'])} | {_f(r['recall_ann_bf'])} "
              f"| {_f(r['mt_seconds_ann'], 5)} | {_f(r['mt_seconds_bf'], 5)} |" for r in t3]
    lines += ["", f"## Table 4: localization accuracy on the unseen run ({DEFAULT_INDEX} as ANN; gap 0 = within 1 m)", "",
              "| update | BF | ANN | BF gap 2 | ANN gap 2 |", "|---|---|---|---|---|"]
    lines += [f"| {r['update']} | {_f(r['bf'])} | {_f(r['ann'])} | {_f(r['bf_gap2'])} | {_f(r['ann_gap2'])} |" for r in t4]
    lines += ["", "## Fig. 4-5: seconds per frame to compute m_t", "", "| update | backend | dictionary | build s | m_t s |", "|---|---|---|---|---|"]
    lines += [f"| {r['update']} | {r['backend']} | {r['dictionary_size']} | {_f(r['build_seconds'], 2)} | {_f(r['mt_seconds'], 5)} |"
              for r in fig_rows]
    (out / "tables.md").write_text("\n".join(lines) + "\n")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, upd in zip(axes, ("plain", "improved")):
        for b in dict.fromkeys(r["backend"] for r in fig_rows):  # the backends that were timed, in order
            rr = [r for r in fig_rows if r["update"] == upd and r["backend"] == b]
            ax.plot([r["dictionary_size"] for r in rr], [r["mt_seconds"] for r in rr], "o-", label=b)
        ax.set_title(f"time to compute m_t, {upd} dictionary", fontsize=10)
        ax.set_xlabel("dictionary size (words)")
        ax.set_ylabel("seconds per query frame (log scale)")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.subplots_adjust(wspace=0.35)
    fig.savefig(out / "fig45_mt_seconds.png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, (upd, m) in zip(axes, (("plain", p), ("improved", i))):
        g = np.arange(3)
        ax.bar(g - 0.2, [m[f"accuracy_gap{k}_bf"] or 0 for k in g], 0.4, label="brute force")
        ax.bar(g + 0.2, [m[f"accuracy_gap{k}"] or 0 for k in g], 0.4, label=DEFAULT_INDEX)
        ax.set_xticks(g)
        ax.set_xlabel("gap tolerance (nodes)")
        ax.set_title(f"localization accuracy of the unseen run, {upd} update", fontsize=10)
        ax.set_ylim(0, 1)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2, frameon=False)
    axes[0].set_ylabel("fraction of query frames correct")
    fig.savefig(out / "fig67_accuracy.png", dpi=100, bbox_inches="tight")
    plt.close(fig)
