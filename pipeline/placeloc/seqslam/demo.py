"""What ``make demo`` prints after its run: the sequence and single-image figures side by
side, and why they differ (``python -m placeloc.seqslam.demo RUN_DIR``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any


def explain(m: dict[str, Any]) -> str:
    """The headline figures of a SeqSLAM run with one sentence each on what they count."""
    n, matched = int(m["n_queries"]), int(m["n_matched"])
    unmatched = n - matched
    lines = [f"SeqSLAM ({m['comparison']}, sequences of ds = {m['ds']} frames), {n} queries:",
             f"  recall_at_1               {m['recall_at_1']:.3f}   best sequence match right, over all {n} queries",
             f"  recall_at_5               {m['recall_at_5']:.3f}   any of the 5 best right (standard Recall@N)",
             f"  auc_pr                    {m['auc_pr']:.3f}   area under precision-recall over the match confidence",
             f"  recall_at_100_precision   {m['recall_at_100_precision']:.3f}   recall while every accepted match is right",
             f"  single_image_recall_at_1  {m['single_image_recall_at_1']:.3f}   each query frame matched alone (no sequence)"]
    if unmatched:
        lines.append(f"Why the sequence figure is lower: {unmatched} queries lie within ds/2 of an end of the traverse, "
                     "where no full sequence fits, so they get no match (seqslam.edges: skip) and count as misses;")
        if m["recall_at_1"] * n >= matched - 0.5:
            lines.append(f"  all {matched} matched queries are right, which is why recall_at_1, AUC and recall at 100 % "
                         "precision are the same number. --set seqslam.edges=shift matches the ends too.")
    lines.append("The single-image match needs no sequence, and on this short synthetic route most frames are distinct "
                 "on their own; sequences pay off where single frames are ambiguous (repeated or changed scenes).")
    return "\n".join(lines)


if __name__ == "__main__":
    print(explain(json.loads((Path(sys.argv[1]) / "metrics.json").read_text())))
