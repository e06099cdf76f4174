"""The defaults the docs state are the defaults the code has.

Every default lives in a parameter dataclass (a method's ``params.py``, or
``common_params.py`` for the shared sections); the docs repeat some of them for the
reader. This test finds those statements and compares them with the dataclasses:

- the parameter table of docs/seqslam.md (``| key | default | meaning |``);
- prose and table cells of the form ```key`` ... default VALUE`` (``- `radius`: default 25 m``,
  ```pirf.verify_frames``, default 5``, ``(default 1)`` in a key's table row);
- table rows ``| `key` | ... (VALUE) |`` whose meaning ends with the default in brackets.

A statement whose key names no parameter (a generator option, a metric) is left alone.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from placeloc.core import params as P
from placeloc.core.common_params import CommonParams
from placeloc.core.methods import METHOD_NAMES, get_method

ROOT = Path(__file__).resolve().parent.parent
# doc -> the method whose keys it names bare (None: keys are written with their section)
DOCS = {"docs/seqslam.md": "seqslam", "docs/pirf.md": "pirf", "docs/umap.md": "umap", "docs/coembed.md": "coembed",
        "docs/evaluation.md": None, "docs/dask.md": None, "docs/reliability.md": None, "README.md": None,
        "docs/loop-closure.md": None, "docs/retrieval.md": "retrieval"}


def _flat(d: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _defaults(method: str | None) -> dict[str, Any]:
    """Dotted key -> default: the method's own keys bare, the shared ones by section."""
    out = _flat(P.defaults(CommonParams))
    if method is not None:
        out.update(_flat(P.defaults(get_method(method).params)))
    else:
        for name in METHOD_NAMES:
            out.update(_flat(P.defaults(get_method(name).params), f"{name}."))
    return out


def _resolve(key: str, defaults: dict[str, Any], method: str | None) -> str | None:
    if method is not None and key.startswith(method + "."):
        key = key[len(method) + 1:]
    if key in defaults:
        return key
    for section in ("ground_truth", "executor", "reference"):
        if f"{section}.{key}" in defaults:
            return f"{section}.{key}"
    tails = [k for k in defaults if k.endswith("." + key)]
    return tails[0] if len(tails) == 1 else None


def _value(text: str) -> Any:
    text = text.strip().strip("`")
    if text.lower() in ("none", "null"):
        return None
    number = re.fullmatch(r"[-+]?\d[\d,]*(\.\d+)?([eE][-+]?\d+)?", text)
    if number:
        return float(text.replace(",", ""))
    return yaml.safe_load(text)


def _same(stated: Any, default: Any) -> bool:
    if isinstance(default, bool) or isinstance(stated, bool):
        return stated == default
    if isinstance(default, (int, float)) and isinstance(stated, (int, float)):
        return abs(float(stated) - float(default)) <= 1e-12 * max(1.0, abs(float(default)))
    if isinstance(default, (list, tuple)) and isinstance(stated, (list, tuple)):
        return len(stated) == len(default) and all(_same(a, b) for a, b in zip(stated, default))
    return stated == default


PROSE = re.compile(r"`(?P<key>[a-z][a-z0-9_.]*)`[^`\n]{0,60}?\bdefault[: ]+(?P<val>`\[[^\]]*\]`|\[[^\]]*\]"
                   r"|\d+(?:, \d+)+(?=\)|$)|[-+]?\d[\d.,]*(?:[eE][-+]?\d+)?|true|false)")
NUMBER = r"[-+]?\d[\d.]*(?:[eE][-+]?\d+)?"
# "the default `ground_truth.radius` is 25", "`map_ef_search` (64)", "(`refine_radius_m` 0.15 m,"
DEFAULT_KEY = re.compile(r"\bdefault `(?P<key>[a-z][a-z0-9_.]*)`(?: is)?(?: still)? (?P<val>" + NUMBER + ")")
KEY_PAREN = re.compile(r"`(?P<key>[a-z][a-z0-9_.]*)` \((?P<val>" + NUMBER + r")\)")
KEY_UNIT = re.compile(r"\(`(?P<key>[a-z][a-z0-9_.]*)` (?P<val>" + NUMBER + r")(?: ?[a-z%]+)?[,)]")
ROW = re.compile(r"^\| `(?P<key>[a-z][a-z0-9_.]*)` \| [^|]*\((?P<val>[-+]?\d[\d.]*(?:[eE][-+]?\d+)?)\) \|$", re.M)


def stated_defaults(text: str) -> list[tuple[str, str]]:
    """(key, stated value) for every statement of a default in ``text``."""
    found = []
    for line in text.splitlines():
        for m in PROSE.finditer(line):
            val = m["val"].rstrip(",.")
            if ", " in val and not val.startswith(("[", "`")):  # "default 1, 5, 10, 20": a list
                val = f"[{val}]"
            found.append((m["key"], val))
    for pattern in (DEFAULT_KEY, KEY_PAREN, KEY_UNIT, ROW):
        found += [(m["key"], m["val"]) for m in pattern.finditer(text)]
    return found


@pytest.mark.parametrize("doc", list(DOCS))
def test_stated_defaults_match_the_parameters(doc: str) -> None:
    method = DOCS[doc]
    defaults = _defaults(method)
    text = (ROOT / doc).read_text(encoding="utf-8")
    checked, wrong = [], []
    for key, val in stated_defaults(text):
        dotted = _resolve(key, defaults, method)
        if dotted is None:
            continue
        checked.append(dotted)
        if not _same(_value(val), defaults[dotted]):
            wrong.append(f"{doc}: `{key}` stated default {val}, the code's is {defaults[dotted]!r}")
    assert not wrong, "\n".join(wrong)
    if doc in ("docs/pirf.md", "docs/umap.md", "docs/coembed.md", "docs/evaluation.md"):
        assert checked, f"{doc}: no stated default found (has the wording changed?)"


def test_seqslam_parameter_table_matches_the_parameters() -> None:
    text = (ROOT / "docs/seqslam.md").read_text(encoding="utf-8")
    head = text.index("| key | default | meaning |")
    defaults = _defaults("seqslam")
    rows = 0
    for line in text[head:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        keys_cell, default_cell = (c.strip() for c in line.strip("|").split("|")[:2])
        keys = [k.strip() for k in keys_cell.split(",")]
        values = [default_cell] if len(keys) == 1 else [v.strip() for v in default_cell.split(",")]
        assert len(values) == len(keys), line
        for key, val in zip(keys, values):
            assert key in defaults, f"docs/seqslam.md lists {key!r}, which SeqSLAMParams does not have"
            assert _same(_value(val), defaults[key]), f"docs/seqslam.md: {key} default {val}, the code's is {defaults[key]!r}"
            rows += 1
    assert rows == len(P.defaults(get_method("seqslam").params)), "every SeqSLAM parameter has a row"


def test_the_reader_finds_the_statements_it_should() -> None:
    """A known answer for the statement reader."""
    text = ("- `radius`: default 25 m, the usual value\n"
            "(`pirf.verify_frames`, default 5; not in the paper)\n"
            "| `beta` | path smoothness of eq. (16) (default 1) |\n"
            "| `perspective_iterations` | depth re-estimation rounds (5) |\n"
            "| `standard_recall_at_N` (N from `ground_truth.recall_at`, default 1, 5, 10, 20) | Recall@N |\n"
            "- `recall_at`: default `[1, 5, 10, 20]`, the N\n"
            "The config's default `ground_truth.radius` is still 1.0 (a value PIRF uses)\n")
    assert stated_defaults(text) == [("radius", "25"), ("pirf.verify_frames", "5"), ("beta", "1"),
                                     ("ground_truth.recall_at", "[1, 5, 10, 20]"), ("recall_at", "`[1, 5, 10, 20]`"),
                                     ("ground_truth.radius", "1.0"), ("perspective_iterations", "5")]
    # that last line is what docs/evaluation.md said before: it would fail the check
    assert not _same(_value("1.0"), _defaults(None)["ground_truth.radius"])
