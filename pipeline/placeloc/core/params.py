"""Parameter objects: the one home of every method parameter's default, type, range and help.

Each method declares its parameters once, as a frozen dataclass in ``<method>/params.py``::

    @dataclass(frozen=True)
    class SeqSLAMParams:
        ds: int = param(10, min=1, help="sequence length (the window has ds + 1 query frames)")
        search: str = param("causal", choices=("causal", "centred"))

From that class the config layer derives the YAML defaults, the allowed choices, the
numeric ranges and the keys that name files (:func:`defaults`, :func:`choices`,
:func:`bounds`, :func:`path_keys`); the runner builds one instance per run from the
validated config section (:func:`from_section`) and hands it to the stages as
``ctx.params``. Numerical code never sees the config: stages pass it explicit keyword
arguments taken from this object. A nested section (e.g. ``umap.ca``) is a field whose
type is another such dataclass, declared with :func:`section`.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, TypeVar

T = TypeVar("T")


class Params:
    """Base of every parameter dataclass: frozen, built once per run, read by attribute
    (``p.ds``). Stages pass the values on as explicit keyword arguments."""


def param(default: Any, *, help: str = "", min: float | None = None, max: float | None = None,
          choices: tuple | None = None, path: bool = False, min_exclusive: bool = False, min_len: int | None = None,
          affects_result: bool = True) -> Any:
    """A parameter with its default and the facts the config validator checks.

    ``min``/``max`` bound a number (or every item of a list of numbers); ``min_exclusive``
    makes ``min`` a strict bound; ``choices`` lists the allowed strings; ``path`` marks a
    file or folder (resolved against the config's folder and fingerprinted by the runner);
    ``min_len`` is the fewest items a list parameter may have (checked with the config, so
    an empty list fails there, not stages later).
    ``affects_result=False`` marks a setting that changes only how the work is cut (block
    and task sizes), never a result: a stage may read it without declaring it, so changing
    it re-runs nothing (tests/test_stage_keys.py holds stages to this).
    """
    meta = {"help": help, "min": min, "max": max, "choices": choices, "path": path, "min_exclusive": min_exclusive,
            "min_len": min_len, "affects_result": affects_result}
    if isinstance(default, dict):
        raise TypeError("a mapping of parameters is a section(): declare it as a dataclass of its own")
    # Lists are stored as tuples so parameter objects stay immutable; YAML shows them as lists.
    if isinstance(default, list):
        default = tuple(default)
    return dataclasses.field(default=default, metadata=meta)


def section(cls: type) -> Any:
    """A nested parameter section (a dataclass of its own, e.g. ``umap.ca``)."""
    return dataclasses.field(default_factory=cls, metadata={"section": True})


def _fields(cls: type) -> tuple[dataclasses.Field, ...]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a parameter dataclass")
    return dataclasses.fields(cls)


def _is_section(f: dataclasses.Field) -> bool:
    return bool(f.metadata.get("section"))


def _section_type(cls: type, f: dataclasses.Field) -> type:
    return type(f.default_factory())  # type: ignore[misc]


def defaults(cls: type) -> dict[str, Any]:
    """The YAML defaults of a parameter class, as a nested dict."""
    out: dict[str, Any] = {}
    for f in _fields(cls):
        if _is_section(f):
            out[f.name] = defaults(_section_type(cls, f))
        else:
            out[f.name] = list(f.default) if isinstance(f.default, tuple) else f.default
    return out


def _walk(cls: type, prefix: str = "") -> list[tuple[str, dataclasses.Field]]:
    rows: list[tuple[str, dataclasses.Field]] = []
    for f in _fields(cls):
        if _is_section(f):
            rows += _walk(_section_type(cls, f), f"{prefix}{f.name}.")
        else:
            rows.append((f"{prefix}{f.name}", f))
    return rows


def choices(cls: type) -> dict[str, tuple]:
    """Dotted key -> allowed values, for the keys that declare ``choices``."""
    return {k: f.metadata["choices"] for k, f in _walk(cls) if f.metadata.get("choices")}


def bounds(cls: type) -> dict[str, tuple[float | None, float | None, bool]]:
    """Dotted key -> (min, max, min_exclusive), for the keys that declare a range."""
    return {k: (f.metadata.get("min"), f.metadata.get("max"), bool(f.metadata.get("min_exclusive")))
            for k, f in _walk(cls) if f.metadata.get("min") is not None or f.metadata.get("max") is not None}


def declared_types(cls: type, prefix: str = "") -> dict[str, tuple[type, ...]]:
    """Dotted key -> the types a value may have, from the field annotations (``str | None``
    -> ``(str,)``; ``None`` is always allowed for such keys). Only keys whose default is
    ``None`` are listed: the others are checked against their default's type."""
    hints = typing.get_type_hints(cls)
    out: dict[str, tuple[type, ...]] = {}
    for f in _fields(cls):
        if _is_section(f):
            out.update(declared_types(_section_type(cls, f), f"{prefix}{f.name}."))
            continue
        if f.default is not None:
            continue
        hint = hints.get(f.name, Any)
        args = typing.get_args(hint) if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union else (hint,)
        allowed = tuple(typing.get_origin(a) or a for a in args if a is not type(None) and a is not Any)
        if allowed and all(isinstance(a, type) for a in allowed):
            out[f"{prefix}{f.name}"] = allowed
    return out


def declared_item_types(cls: type, prefix: str = "") -> dict[str, type]:
    """Dotted key -> the type every item must have, for keys whose annotation is a list or
    tuple of one number type (``tuple[float, float, float] | None`` -> ``float``,
    ``tuple[int, ...]`` -> ``int``): a string or a bool among the items is refused like a
    bad scalar, also where the default (null, an empty list) shows no item to compare with."""
    hints = typing.get_type_hints(cls)
    out: dict[str, type] = {}
    for f in _fields(cls):
        if _is_section(f):
            out.update(declared_item_types(_section_type(cls, f), f"{prefix}{f.name}."))
            continue
        hint = hints.get(f.name, Any)
        args = typing.get_args(hint) if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union else (hint,)
        for a in args:
            if typing.get_origin(a) in (list, tuple):
                items = {t for t in typing.get_args(a) if t is not Ellipsis}
                if len(items) == 1 and next(iter(items)) in (int, float):
                    out[f"{prefix}{f.name}"] = next(iter(items))
    return out


def nullable_keys(cls: type, prefix: str = "") -> tuple[str, ...]:
    """Dotted keys whose annotation admits ``None`` (``float | None``): null is a value
    they take (e.g. "not set: use the default rule") even when their default is a number."""
    hints = typing.get_type_hints(cls)
    out: list[str] = []
    for f in _fields(cls):
        if _is_section(f):
            out += nullable_keys(_section_type(cls, f), f"{prefix}{f.name}.")
            continue
        hint = hints.get(f.name, Any)
        if (isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union) and type(None) in typing.get_args(hint):
            out.append(f"{prefix}{f.name}")
    return tuple(out)


def path_keys(cls: type) -> tuple[str, ...]:
    """Dotted keys that name files or folders."""
    return tuple(k for k, f in _walk(cls) if f.metadata.get("path"))


def describe(cls: type, prefix: str = "") -> list[tuple[str, Any, str, str]]:
    """(dotted key, default, allowed values or range, help) for every parameter of ``cls``:
    what ``placeloc params`` prints."""
    rows = []
    for key, f in _walk(cls):
        m = f.metadata
        default = list(f.default) if isinstance(f.default, tuple) else f.default
        allowed = ""
        if m.get("choices"):
            allowed = " | ".join(map(str, m["choices"]))
        elif m.get("min") is not None or m.get("max") is not None:
            lo, hi = m.get("min"), m.get("max")
            low = f"{'>' if m.get('min_exclusive') else '>='} {lo}" if lo is not None else ""
            allowed = ", ".join(x for x in (low, f"<= {hi}" if hi is not None else "") if x)
        if m.get("path"):
            allowed = "path" + (f"; {allowed}" if allowed else "")
        rows.append((f"{prefix}{key}", default, allowed, m.get("help", "")))
    return rows


def work_layout_keys(cls: type) -> tuple[str, ...]:
    """Dotted keys declared ``affects_result=False`` (they cut the work, not the result)."""
    return tuple(k for k, f in _walk(cls) if f.metadata.get("affects_result") is False)


def from_section(cls: type[T], section_values: dict[str, Any]) -> T:
    """Build the parameter object from a validated config section (a nested dict)."""
    kwargs: dict[str, Any] = {}
    for f in _fields(cls):
        if f.name not in section_values:
            continue
        value = section_values[f.name]
        if _is_section(f):
            value = from_section(_section_type(cls, f), value or {})
        elif isinstance(value, list):
            value = tuple(value)
        kwargs[f.name] = value
    return cls(**kwargs)


def check_bounds(cls: type, section_values: dict[str, Any], prefix: str) -> list[str]:
    """Messages for every value outside its declared range, and every list shorter than
    its declared ``min_len`` (empty when all are inside)."""
    problems = []
    for key, f in _walk(cls):
        need = f.metadata.get("min_len")
        if need is None:
            continue
        node = section_values
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, (list, tuple)) and len(node) < need:
            example = f", e.g. {prefix}{key}={list(f.default)[:max(need, 3)]!r}" if isinstance(f.default, (list, tuple)) else ""
            problems.append(f"{prefix}{key}: {list(node)!r} has {len(node)} item(s); it needs at least {need}{example}")
    for key, (lo, hi, strict) in bounds(cls).items():
        node: Any = section_values
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        values = node if isinstance(node, (list, tuple)) else [node]
        for v in values:
            if v is None or isinstance(v, bool) or not isinstance(v, (int, float)):
                continue
            if lo is not None and (v <= lo if strict else v < lo) or hi is not None and v > hi:
                rng = f"{'>' if strict else '>='} {lo}" if hi is None else (
                    f"<= {hi}" if lo is None else f"in {'(' if strict else '['}{lo}, {hi}]")
                problems.append(f"{prefix}{key}: {node!r} is out of range; it must be {rng}")
                break
    return problems


def text_number_hint(value: Any) -> str:
    """For text where a number belongs that reads as one: why it is text. YAML 1.1 (PyYAML)
    reads ``1e12`` and ``1.0e12`` as strings (a float needs a dot and a signed exponent,
    ``1.0e+12``), and a quoted ``'10'`` is a string."""
    if not isinstance(value, str):
        return ""
    try:
        float(value)
    except ValueError:
        return ""
    signed = ", and exponents with a dot and a sign: 1.0e+12" if "e" in value.lower() else ""
    return f" (YAML read it as text: write the number without quotes{signed})"
