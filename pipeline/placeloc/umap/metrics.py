"""Localization error summaries: those of the ``poses`` result contract, re-exported here
where UMap's experiments read them."""

from __future__ import annotations

from placeloc.evaluation.pose_estimates import error_metrics, recall_metrics, yaw_errors

__all__ = ["error_metrics", "recall_metrics", "yaw_errors"]
