"""One ``umap.panorama`` setting chosen on development homes and checked on test homes: what
``placeloc experiment umap-halves`` (the score halves' weight) and ``umap-lines`` (the
shortest line a photo keeps) share.

1. Development homes (``placeloc synth home``, seeds 0-12, 20 panoramas each; more than the
   three of ``placeloc experiment umap-homes``, where the defaults already place all but one
   panorama and one panorama decides), each at the five grid origins of that experiment:
   every value of the setting, the rest the defaults. The rule of ``umap-homes`` chooses:
   the highest mean over the homes of each home's worst origin; among values within one
   panorama of one home of it, the one whose answers move least with the grid's origin,
   then the one nearest the default (the plainer: a change must earn its place).
2. Test homes (seeds 20-24, those of ``umap-homes``) at the same origins: the chosen value
   and the default. The default changes only where the chosen value does at least as well
   there (a change must hold where it was not chosen); the table says which.

Every value of a home and origin shares one run folder, so the map is drawn and indexed
once (a localize key re-runs localize alone, an extract key extract and localize). Writes
``OUT/table.md`` and ``OUT/summary.json``.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from placeloc.core.safe_io import read_run_table
from placeloc.experiments import write_summary
from placeloc.experiments.umap_homes import (
    ORIGINS,
    PANORAMAS,
    TEST_SEEDS,
    _drop_index,
    _home,
    _run,
    answer_moves,
    near_the_best,
    within_goal,
    worst_origin_mean,
)

log = logging.getLogger("placeloc")

DEV_SEEDS = tuple(range(13))


class Setting(NamedTuple):
    """The ``umap.panorama`` key swept, its values (``quick``: those of ``--quick``), its
    default and the words the table uses for it: ``column`` heads the table's first column,
    ``noun`` names a value ("weight"), ``default_name`` the default ("the halves' mean")."""

    key: str
    values: tuple[float, ...]
    quick: tuple[float, ...]
    default: float
    column: str
    noun: str
    default_name: str


def _right(run_dir: Path) -> dict[str, tuple[bool, tuple[float, float]]]:
    """frame -> (within 1 m and 30 degrees, the answered plan position), from a run's
    per_query.csv."""
    return {r["frame"]: (within_goal(r), (float(r["x"]), float(r["y"])))
            for r in csv.DictReader(read_run_table(run_dir, "per_query.csv"))}


def sweep(out_dir: Path, setting: Setting, seeds: tuple[int, ...], origins: tuple[float, ...],
          values: tuple[float, ...], group: str, quiet: bool, runs: dict[str, dict[str, Any]]
          ) -> dict[float, dict[str, Any]]:
    """Each value on each home and origin: value -> shares (home by home, each origin),
    wrong answers, and the answers' positions per (home, frame) over the origins."""
    got: dict[float, dict[str, Any]] = {v: {"shares": [], "wrong": 0, "answers": {}} for v in values}
    for seed in seeds:
        data = _home(out_dir, seed)
        for i, frac in enumerate(origins):
            folder = f"{group}-home{seed}-origin{i}"
            for v in values:
                m = _run(out_dir, folder, data, {setting.key: v}, frac, quiet)
                runs[f"{folder}-{setting.key}{v:g}"] = m
                got[v]["shares"].append(float(m["within_1m_30deg"]))
                for frame, (right, xy) in _right(out_dir / folder).items():
                    got[v]["wrong"] += not right
                    got[v]["answers"].setdefault((seed, frame), []).append(xy)
            _drop_index(out_dir / folder)
    return got


def choose(got: dict[float, dict[str, Any]], origins: int, default: float) -> float:
    """The rule of the module docstring over :func:`sweep`'s results (``origins`` runs a home)."""
    near = near_the_best({v: g["shares"] for v, g in got.items()}, origins)
    return min(near, key=lambda v: (answer_moves(got[v]["answers"]), abs(v - default), v))


def row(label: str, g: dict[str, Any], origins: int) -> str:
    """One line of the tables: mean share, worst run, mean of each home's worst origin, homes
    right at every origin, wrong answers, answers moving with the origin."""
    shares = np.asarray(g["shares"], float).reshape(-1, origins)
    perfect = int((shares.min(axis=1) == 1.0).sum())
    moves = answer_moves(g["answers"])
    return (f"| {label} | {shares.mean():.2%} | {shares.min():.0%} | {worst_origin_mean(g['shares'], origins):.2%} | "
            f"{perfect} of {len(shares)} | {g['wrong']} | {moves[0]} / {moves[1]} |")


def verdict(setting: Setting, chosen: float, test: dict[float, dict[str, Any]], origins: int) -> str:
    """The table's last line: the default the test homes leave (module docstring, 2): the
    chosen value where its mean of each home's worst origin there is at least the default's,
    else the default."""
    d = setting.default
    if chosen == d:
        return f"The rule chose {setting.default_name} itself: the default stays {d:g}."
    holds = worst_origin_mean(test[chosen]["shares"], origins) >= worst_origin_mean(test[d]["shares"], origins) - 1e-12
    return (f"On the test homes the chosen {setting.noun} does {'at least as well as' if holds else 'worse than'} "
            f"{setting.default_name} by the same measure: the default " + (f"is {chosen:g}." if holds else f"stays {d:g}."))


def run(setting: Setting, out_dir: Path, quick: bool = False, quiet: bool = False) -> Path:
    """The whole experiment (module docstring) for ``setting``: its tables into
    ``OUT/table.md``, every run's metrics into ``OUT/summary.json``."""
    out_dir = Path(out_dir).resolve()
    dev_seeds, test_seeds = (DEV_SEEDS[:2], TEST_SEEDS[:1]) if quick else (DEV_SEEDS, TEST_SEEDS)
    origins = ORIGINS[:2] if quick else ORIGINS
    values = setting.quick if quick else setting.values
    runs: dict[str, dict[str, Any]] = {}
    dev = sweep(out_dir, setting, dev_seeds, origins, values, "dev", quiet, runs)
    chosen = choose(dev, len(origins), setting.default)
    test = sweep(out_dir, setting, test_seeds, origins, tuple(sorted({chosen, setting.default})), "test", quiet, runs)
    write_summary(out_dir, runs)
    head = [f"| {setting.column} | mean share | worst run | mean of each home's worst origin | homes right at every "
            "origin | wrong answers | answers moving > 0.1 / 0.05 m |", "|---|---|---|---|---|---|---|"]
    per = len(dev_seeds) * len(origins) * PANORAMAS
    mark = f" ({setting.default_name})"
    lines = [f"Development homes (seeds {dev_seeds[0]}-{dev_seeds[-1]}, {PANORAMAS} panoramas each), grid origins "
             + ", ".join(f"{f:.2f}" for f in origins) + f" of a step ({per} answers a {setting.noun}); the rest the "
             "defaults:", "", *head]
    lines += [row(f"{v:g}" + (mark if v == setting.default else ""), dev[v], len(origins)) for v in values]
    lines += ["", f"Chosen by the rule (the highest mean of each home's worst origin; within one panorama of one home of "
              f"it, the fewest answers moving with the origin, then the nearest to {setting.default:g}): **{chosen:g}**.",
              "", f"Test homes (seeds {', '.join(map(str, test_seeds))}), the same origins:", "", *head]
    lines += [row(f"{v:g}" + (" (chosen)" if v == chosen else "") + (mark if v == setting.default else ""),
                  test[v], len(origins)) for v in sorted(test)]
    lines += ["", verdict(setting, chosen, test, len(origins))]
    (out_dir / "table.md").write_text("\n".join(lines) + "\n")
    if not quiet:
        print("\n".join(lines))
    return out_dir / "summary.json"
