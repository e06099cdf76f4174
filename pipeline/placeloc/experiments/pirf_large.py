"""``make experiment-pirf-large``: the PIRF-nav2 figures at a dictionary near 500,000 words.

8,000 mapping frames (about 7.4 laps of the generated 216 m loop) and 400 unseen test
frames, the paper's table 1 parameters. What it shows, one run per row:

- **Table 2**: brute-force mapping against mapping with the incremental HNSW graph
  (``pirf.map_search: faiss-hnsw``), for each update: dictionary, loop closures and their
  precision (as the similarity matched them, and with ``pirf.direction_correction``), and
  the mapping cost per frame, wall and CPU, over the whole run and over its last 10 %
  (where the dictionary is largest).
- **Table 3**: the self-tuned index (``pirf.index_recall``) against brute force on the
  finished dictionary: the chosen efSearch, m_t agreement (Jaccard / precision / recall)
  and m_t time per frame, with the speed ratio measured in the same run.
- **Table 4**: localization of the unseen run at gap 0 and 2.

The machine may be shared, so every step records its wall and CPU seconds and the load
average. The steps run most important first (improved update, brute-force then HNSW
mapping; then the plain update) and the tables are rewritten after each, so a run cut
short still leaves what it measured. The m_t timing sweep of Fig. 4-5 is left to
``make experiment-pirf`` (at 8,000 frames it adds about 10 minutes).
"""

from __future__ import annotations

import json
import os
import resource
import time
from pathlib import Path
from typing import Any

from placeloc.api import read_metrics, run
from placeloc.experiments import pirf as experiment
from placeloc.experiments import say, write_summary
from placeloc.pirf.metrics import PAPER_RADIUS_M, loop_closure_correct
from placeloc.pirf.results import loop_closure_count, read_frame_names, read_index_info, read_loop_closures, stage_seconds
from placeloc.pirf.truth import read_frame_xy

LARGE = {"frames": 8000, "test_frames": 400}
# (update, mapping search) most important first: the default update with both mappings.
STEPS = (("improved", "bruteforce"), ("improved", "faiss-hnsw"), ("plain", "bruteforce"), ("plain", "faiss-hnsw"))


def _cpu() -> float:
    """CPU seconds (user + sys) of this process and its finished children (extraction workers)."""
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def run_name(update: str, map_search: str) -> str:
    return f"omni-{update}" + ("" if map_search == "bruteforce" else "-hnsw-mapping")


def main(out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    spec = experiment.QUICK if quick else LARGE
    t0, c0, load0 = time.perf_counter(), _cpu(), os.getloadavg()
    data = experiment._data(out, spec, quiet)
    runs: dict[str, dict[str, Any]] = {}
    steps: list[dict[str, Any]] = [{"step": "render", "wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0,
                                    "load_start": load0[0], "load_end": os.getloadavg()[0]}]
    first = out / run_name(*STEPS[0])
    for update, map_search in STEPS:
        name = run_name(update, map_search)
        rd = out / name
        if rd != first:
            experiment._link(first / "extract.h5", rd / "extract.h5")  # every run maps the same PIRFs
        # The brute-force-mapped runs get the self-tuned default index with brute force beside it
        # (Table 3); the HNSW-mapped ones localize by brute force only (their index is not the question).
        index = experiment.DEFAULT_INDEX if map_search == "bruteforce" else "bruteforce"
        say("pirf", quiet, f"{name}: mapping ({update} update, {map_search} search), index {index}, localization")
        t0, c0, load0 = time.perf_counter(), _cpu(), os.getloadavg()
        run(experiment._config(data, update=update, map_search=map_search, index=index, compare_bf=index != "bruteforce"), rd,
            quiet=quiet)
        m = read_metrics(rd)
        m["build_seconds"] = stage_seconds(rd, "build-dictionary")
        m["index_build_seconds"] = float(read_index_info(rd)["build_seconds"])
        if m.get("mt_seconds_bf") and m.get("mt_seconds_ann"):
            m["mt_speedup_vs_bf"] = m["mt_seconds_bf"] / m["mt_seconds_ann"]
        if m.get("mt_total_seconds_bf") and m.get("mt_total_seconds_ann"):
            m["mt_total_speedup_vs_bf"] = m["mt_total_seconds_bf"] / m["mt_total_seconds_ann"]
        runs[name] = m
        steps.append({"step": name, "wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0, "load_start": load0[0],
                      "load_end": os.getloadavg()[0]})
        write_summary(out, runs)
        (out / "steps.json").write_text(json.dumps(steps, indent=2))
        write_tables(out, runs, steps, spec)
    return out / "summary.json"


def precision_by_length(run_dir: Path, poses: Path, lengths: tuple[int, ...], radius: float) -> list[dict[str, Any]]:
    """Loop-closure precision of the first n frames, for each n of ``lengths`` (up to the run's).

    Every step of the method is causal (PIRFs, mapping, the direction correction and the
    geometric check use only earlier frames) and the generator renders the same first
    frames for any length, so the closures among the first n frames are those a run of n
    frames makes: one long run gives the figures at the shorter sizes too.
    """
    names = read_frame_names(run_dir, "reference")
    xy = read_frame_xy(poses, names, range(len(names)), len(names), "mapping poses")
    rows = []
    for kind, c in (("candidates", read_loop_closures(run_dir, candidates=True)), ("loop closures", read_loop_closures(run_dir))):
        ok = loop_closure_correct(xy, c["frame"], c["node"], radius)
        for n in lengths:
            if n <= len(names):
                sel = c["frame"] < n
                rows.append({"frames": n, "kind": kind, "count": int(sel.sum()), "correct": int(ok[sel].sum()),
                             "precision": float(ok[sel].mean()) if sel.any() else float("nan")})
    return rows


def _f(v: Any, nd: int = 3) -> str:
    """A table cell as ``make experiment-pirf`` writes it, 3 decimals unless told."""
    return experiment._f(v, nd)


def _ms(v: Any) -> str:
    return "-" if v is None else f"{1000 * v:.1f}"


def write_tables(out: Path, runs: dict[str, dict[str, Any]], steps: list[dict[str, Any]], spec: dict[str, int]) -> Path:
    """tables.md from the runs measured so far."""
    lines = [f"# PIRF-nav2 at {spec['frames']} mapping frames ({spec['test_frames']} unseen test frames)", "",
             "## Table 2: mapping, brute force against the incremental HNSW graph", "",
             "Correct = the matched node within 1 m of the true position (the paper's criterion). Candidates: score >= tau "
             "(eq. 9), their precision as the similarity matched them and with the direction correction; loop closures: "
             "the candidates the geometric check keeps (pirf.verify_frames). Mapping cost per frame in ms, wall / CPU "
             "(user+sys, all threads); 'end' = the last 10 % of frames, dictionary from the size given.", "",
             "| update | mapping | dictionary | candidates | as matched | direction-corrected | loop closures | correct | precision "
             "| map ms all (wall / CPU) | map ms end (wall / CPU) | frames/s end | end from |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for update, map_search in STEPS:
        m = runs.get(run_name(update, map_search))
        if m is None:
            continue
        lines.append(f"| {update} | {map_search} | {m['dictionary_size']} | {m.get('loop_closure_candidates', '-')} "
                     f"| {_f(m.get('loop_closure_precision_as_matched'), 4)} | {_f(m.get('loop_closure_precision_direction_corrected'), 4)} "
                     f"| {loop_closure_count(m)} | {m['loop_closures_correct']} | {_f(m['loop_closure_precision'], 4)} "
                     f"| {_ms(m['loop_seconds_per_frame'])} / {_ms(m.get('map_cpu_seconds_per_frame'))} "
                     f"| {_ms(m['loop_seconds_per_frame_end'])} / {_ms(m.get('map_cpu_seconds_per_frame_end'))} "
                     f"| {_f(1.0 / m['loop_seconds_per_frame_end'], 1)} | {m['map_end_dictionary_from']} |")
    lines += ["", "## Table 3: the self-tuned index against brute force (query run, m_t)", "",
              "Two tunings, each on a sample grown until 400 of its entries pass the ratio test, with the rule m_t "
              "(recall and Jaccard lower bounds) or nn (neighbour recall, when too few matches): the index stage's on "
              "held-out dictionary entries, then localize's on the query run's own PIRFs (pirf.index_tune_queries), "
              "whose choice is used. The whole query run against brute force is the check. The whole-run ratio counts "
              "the query tuning (its exact search of the sample) as part of the ANN time.", "",
              "| update | index stage: efSearch, sample (matches), rule, m_t recall / Jaccard "
              "| localize: efSearch, sample (matches), rule, m_t recall / Jaccard, seconds "
              "| query run Jaccard | precision | recall | m_t ms ANN | m_t ms BF | ratio | whole run ANN s / BF s, ratio "
              "| index build s |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]

    def tuning(m: dict[str, Any], prefix: str) -> str:
        if m.get(f"{prefix}_value") is None:
            return "-"
        return (f"{m[f'{prefix}_value']}, {m[f'{prefix}_sample']} ({m[f'{prefix}_mt_matched']}), {m[f'{prefix}_rule']}, "
                f"{_f(m[f'{prefix}_mt_recall'])} / {_f(m[f'{prefix}_mt_jaccard'])}")

    for update in ("improved", "plain"):
        m = runs.get(run_name(update, "bruteforce"))
        if m is None:
            continue
        queried = tuning(m, "index_query_tuned")
        if queried != "-":
            queried += f", {_f(m.get('index_query_tuned_seconds'), 1)} s"
        lines.append(f"| {update} | {tuning(m, 'index_tuned')} | {queried} "
                     f"| {_f(m['jaccard_ann_bf'])} | {_f(m['precision_ann_bf'])} "
                     f"| {_f(m['recall_ann_bf'])} | {_ms(m['mt_seconds_ann'])} | {_ms(m['mt_seconds_bf'])} "
                     f"| {_f(m.get('mt_speedup_vs_bf'), 1)}x | {_f(m.get('mt_total_seconds_ann'), 1)} / "
                     f"{_f(m.get('mt_total_seconds_bf'), 1)}, {_f(m.get('mt_total_speedup_vs_bf'), 1)}x "
                     f"| {_f(m['index_build_seconds'], 1)} |")
    lines += ["", f"## Table 4: localization of the unseen run (gap 0 = matched node within {PAPER_RADIUS_M:g} m)", "",
              "| update | mapping | index | gap 0 | gap 2 | gap 0 BF | gap 2 BF |", "|---|---|---|---|---|---|---|"]
    for update, map_search in STEPS:
        m = runs.get(run_name(update, map_search))
        if m is not None:
            lines.append(f"| {update} | {map_search} | {m['index']} | {_f(m['accuracy_gap0'])} | {_f(m['accuracy_gap2'])} "
                         f"| {_f(m.get('accuracy_gap0_bf'))} | {_f(m.get('accuracy_gap2_bf'))} |")
    lengths = tuple(n for n in (1200, 2000, 4000, spec["frames"]) if n <= spec["frames"])
    for update, map_search in STEPS:
        rd = out / run_name(update, map_search)
        if run_name(update, map_search) not in runs:
            continue
        rows = precision_by_length(rd, out / "data" / "mapping" / "poses.csv", lengths, PAPER_RADIUS_M)
        lines += ["", f"## Loop-closure precision by video length ({update} update, {map_search} mapping; the first n frames of "
                  "this run, which a run of n frames reproduces)", "",
                  "| frames | candidates (correct / all) | precision | checked closures (correct / all) | precision |",
                  "|---|---|---|---|---|"]
        by = {(r["frames"], r["kind"]): r for r in rows}
        for n in lengths:
            a, b = by[(n, "candidates")], by[(n, "loop closures")]
            lines.append(f"| {n} | {a['correct']} / {a['count']} | {_f(a['precision'], 4)} | {b['correct']} / {b['count']} "
                         f"| {_f(b['precision'], 4)} |")
    lines += ["", "## Steps (the machine may be shared: wall, CPU and the 1-minute load average at start / end)", "",
              "| step | wall s | CPU s | load |", "|---|---|---|---|"]
    lines += [f"| {s['step']} | {s['wall_s']:.0f} | {s['cpu_s']:.0f} | {s['load_start']:.1f} / {s['load_end']:.1f} |" for s in steps]
    path = out / "tables.md"
    path.write_text("\n".join(lines) + "\n")
    return path
