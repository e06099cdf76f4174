"""`placeloc run` on one's own images, with no ground truth: the method runs, the answers are
written, and the run ends after localize with exit 0 (there is nothing to score); asking
for evaluate itself is still a one-line user error."""

from __future__ import annotations

import csv
from pathlib import Path

from faults_table import run_cli, stderr_of


def test_run_without_ground_truth_stops_after_localize(route: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    result = run_cli(["run", str(route / "config.yaml"), "--run-dir", str(run), "-q", "--set", "ground_truth.kind=none",
                      # the demo's comparison, the one that survives the route's night segment
                      "--set", "seqslam.comparison=abs_zncc"])
    assert result.exit_code == 0, stderr_of(result)
    assert "evaluate: skipped, no ground truth" in result.output
    assert (run / "localize.h5").is_file() and not (run / "evaluate.h5").exists()
    with (run / "matches.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    # the bundled route's query follows the reference: most answers lie inside the true
    # span of its ground truth, which the run never read
    with (route / "ground_truth.csv").open() as fh:
        span = {int(r["query"]): (int(r["ref_first"]), int(r["ref_last"])) for r in csv.DictReader(fh)}
    matched = [(int(r["query"]), int(r["reference"])) for r in rows if r["reference"] != ""]
    assert len(matched) >= len(rows) // 2
    # the terminal shows the first five answers, each the query's and the matched reference's image
    first = [r for r in rows if r["reference"] != ""][:5]
    for r in first:
        assert f"  {r['query_image']}: reference_image {r['reference_image']}, confidence {r['confidence']}\n" \
            in result.output
    inside = sum(span[q][0] <= ref <= span[q][1] for q, ref in matched)
    assert inside >= 0.8 * len(matched), (inside, len(matched))

    explicit = run_cli(["evaluate", str(route / "config.yaml"), "--run-dir", str(run), "-q",
                        "--set", "ground_truth.kind=none", "--set", "seqslam.comparison=abs_zncc"])
    assert explicit.exit_code == 2
    assert "ground_truth.kind is none" in stderr_of(explicit)
