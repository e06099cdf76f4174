"""What ``make demo`` prints after its run: the sequence and single-image figures side by
side, and why they differ (``python -m placeloc.seqslam.demo RUN_DIR``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any


def spans(indices: list[int]) -> str:
    """Query indices as runs: [0, 1, 2, 7, 80] -> "0-2, 7, 80"."""
    runs: list[list[int]] = []
    for i in sorted(indices):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs)


def why_unmatched(search: str, ds: int, unmatched: list[int]) -> str:
    """Where SeqSLAM leaves queries without a match and why, for the search window in use."""
    if search == "causal":
        where = (f"the causal search (seqslam.search: causal) ends each sequence at its query, so the first ds = {ds} "
                 "queries have too few frames before them")
    else:
        where = (f"the centred search (seqslam.search: centred) needs ds/2 = {ds // 2} frames on either side, so the "
                 "queries that close to an end have none")
    return f"queries {spans(unmatched)} get no match: {where} (seqslam.edges: skip) and count as misses"


def explain(m: dict[str, Any], unmatched_queries: list[int] | None = None) -> str:
    """The headline figures of a SeqSLAM run with one sentence each on what they count;
    ``unmatched_queries``: the queries without a match (from per_query.csv)."""
    n, matched = int(m["n_queries"]), int(m["n_matched"])
    unmatched = n - matched
    lines = [f"SeqSLAM ({m['comparison']}, sequences of ds = {m['ds']} frames), {n} queries:",
             f"  recall_at_1               {m['recall_at_1']:.3f}   best sequence match right, over all {n} queries",
             f"  recall_at_5               {m['recall_at_5']:.3f}   any of the 5 best right (standard Recall@N)",
             f"  auc_pr                    {m['auc_pr']:.3f}   area under precision-recall over the match confidence",
             f"  recall_at_100_precision   {m['recall_at_100_precision']:.3f}   recall while every accepted match is right",
             f"  single_image_recall_at_1  {m['single_image_recall_at_1']:.3f}   each query frame matched alone (no sequence)"]
    if unmatched:
        which = why_unmatched(str(m["search"]), int(m["ds"]), unmatched_queries) if unmatched_queries else (
            f"{unmatched} queries get no match (no full sequence fits there; seqslam.edges: skip) and count as misses")
        lines.append(f"Why the sequence figure is lower: {which};")
        if m["recall_at_1"] * n >= matched - 0.5:
            lines.append(f"  all {matched} matched queries are right, which is why recall_at_1, AUC and recall at 100 % "
                         "precision are the same number. --set seqslam.edges=shift matches the ends too.")
    lines.append("The single-image match needs no sequence, and on this short synthetic route most frames are distinct "
                 "on their own; sequences pay off where single frames are ambiguous (repeated or changed scenes).")
    return "\n".join(lines)


def unmatched_queries(run_dir: Path) -> list[int]:
    """The queries of a run without a best match, from its per_query.csv."""
    import csv

    with (run_dir / "per_query.csv").open(newline="") as fh:
        return [int(r["query"]) for r in csv.DictReader(fh) if not r["best_reference"]]


if __name__ == "__main__":
    run = Path(sys.argv[1])
    print(explain(json.loads((run / "metrics.json").read_text()), unmatched_queries(run)))
