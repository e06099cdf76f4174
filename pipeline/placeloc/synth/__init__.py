"""Synthetic data sets with known ground truth (``placeloc synth KIND OUT``).

Each kind is a module-level ``generate(out_dir, seed=..., **params) -> dict`` that writes
images and ground truth under ``out_dir`` and returns a short summary. Registered by name
here and imported lazily.
"""

from __future__ import annotations

import importlib
import inspect
import math
import types
import typing
from pathlib import Path
from typing import Any

SYNTH_KINDS: dict[str, str] = {
    "route": "placeloc.synth.route",
    "corridor": "placeloc.synth.corridor",
    "home": "placeloc.synth.home",
    "coembed": "placeloc.synth.coembed",
    "omni": "placeloc.synth.omni",
}


def generate(kind: str, out_dir: str | Path, seed: int = 0, **params: Any) -> dict[str, Any]:
    if kind not in SYNTH_KINDS:
        raise KeyError(f"unknown synthetic data set {kind!r}; choose one of {', '.join(SYNTH_KINDS)}")
    module = importlib.import_module(SYNTH_KINDS[kind])
    return module.generate(Path(out_dir), seed=seed, **params)


_WORDS = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}


def _setting_types(kind: str) -> dict[str, tuple[tuple[type, ...], Any]]:
    """Name -> (the types a generator setting takes, its default), from the annotations of
    the kind's ``generate`` and of the ``generate_*`` functions it hands settings on to."""
    module = importlib.import_module(SYNTH_KINDS[kind])
    out: dict[str, tuple[tuple[type, ...], Any]] = {}
    for name, fn in vars(module).items():
        if not (name == "generate" or name.startswith("generate_")) or not inspect.isfunction(fn):
            continue
        hints = typing.get_type_hints(fn)
        for pname, par in inspect.signature(fn).parameters.items():
            if pname in ("out_dir", "seed") or par.kind is par.VAR_KEYWORD or pname not in hints:
                continue
            hint = hints[pname]
            union = isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union
            allowed = tuple(a for a in (typing.get_args(hint) if union else (hint,)) if isinstance(a, type))
            known, _ = out.get(pname, ((), None))
            out[pname] = (tuple(dict.fromkeys(known + allowed)), par.default)
    return out


def parse_settings(kind: str, items: list[str]) -> dict[str, Any]:
    """``synth --set name=value`` items -> generator keyword arguments, typed like config
    values: YAML (alias-free), then checked against the generator's annotation (an integer
    for ``frames: int``; a bool is not a number; NaN and infinities are refused), so a bad
    value is one line naming the setting, never a comparison error from inside a generator."""
    from placeloc.core.config import safe_yaml
    from placeloc.core.errors import ConfigError

    if kind not in SYNTH_KINDS:
        raise ConfigError(f"unknown synthetic data set {kind!r}; choose one of {', '.join(SYNTH_KINDS)}")
    known = _setting_types(kind)
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected name=value, e.g. --set frames=200")
        name, raw = (part.strip() for part in item.split("=", 1))
        if name not in known:
            raise ConfigError(f"synth {kind}: unknown setting {name!r}; known: {', '.join(known)}")
        try:
            value = safe_yaml(raw) if raw else None
        except Exception as exc:  # yaml.YAMLError: the text is not a value
            raise ConfigError(f"--set {item!r}: the value is not valid YAML ({' '.join(str(exc).split())[:120]})") from exc
        allowed, default = known[name]
        if not _fits(value, allowed, default):
            kinds = " or ".join(_WORDS.get(t, t.__name__) for t in allowed) or "a value"
            raise ConfigError(f"synth {kind}: {name} must be {kinds}, got {value!r} ({type(value).__name__}); "
                              f"e.g. --set {name}={default if default is not None else '...'}")
        # An integer setting is a count or a size: one whose default is positive needs at
        # least 1 (0 frames, a width of -5), one whose default is 0 (dwell) at least 0.
        least = 1 if isinstance(default, int) and default > 0 else 0
        if isinstance(value, int) and not isinstance(value, bool) and int in allowed and isinstance(default, int) \
                and not isinstance(default, bool) and value < least:
            raise ConfigError(f"synth {kind}: {name} must be >= {least}, got {value}; e.g. --set {name}={default}")
        out[name] = float(value) if float in allowed and int not in allowed and isinstance(value, int) else value
    return out


def _fits(value: Any, allowed: tuple[type, ...], default: Any) -> bool:
    if value is None:
        return type(None) in allowed or default is None
    if isinstance(value, float) and not math.isfinite(value):
        return False
    for t in allowed:
        if t in (int, float) and isinstance(value, bool):
            continue
        if t is float and isinstance(value, (int, float)) or isinstance(value, t):
            return True
    return False
