"""The evaluate stage every result contract shares.

Apart from :mod:`placeloc.evaluation.contracts` because it ends by writing report.html, and
the report reads the contracts: this module imports both, neither imports it (only the
method registry does, to give a method without an evaluate of its own this one).
"""

from __future__ import annotations

from typing import Any

import h5py
import numpy as np

from placeloc.evaluation.contracts import Evaluation, contract, read_result


def evaluate_stage(ctx: Any) -> None:
    """The evaluate stage every contract shares: score the localize result, let the
    method's hook add its figures, then write metrics.json, the per-query CSV, the
    contract's pictures, the strips and report.html."""
    from placeloc.evaluation import write_metrics

    res = read_result(ctx.artifact("localize"))
    mod = contract(res.kind)
    ev: Evaluation = mod.evaluate(ctx, res)
    if not ev.label:
        ev.label = ctx.method.name
    if ctx.method.evaluate_extra is not None:
        ctx.method.evaluate_extra(ctx, ev)
    for k, v in ev.arrays.items():
        _write_array(ctx.out, k, v)
    ctx.out.attrs["result_kind"] = res.kind
    write_metrics(ctx.output_dir, ev.metrics, ctx.out)
    plots = bool(ctx.config.get("plots", True))
    mod.finish(ctx, ev, plots=plots)
    if plots:
        from placeloc.evaluation.report import write_report

        # side outputs are staged in ctx.output_dir until the stage commits: read and write there
        if mod.SHOW_AT_EVALUATE:
            mod.show(ctx.run_dir, res, out_dir=ctx.output_dir)
        write_report(ctx.run_dir, config=ctx.config, out_dir=ctx.output_dir)


def _write_array(group: h5py.Group, name: str, value: Any) -> None:
    if isinstance(value, dict):
        sub = group.require_group(name)
        for k, v in value.items():
            _write_array(sub, k, v)
    else:
        group.create_dataset(name, data=np.asarray(value))
