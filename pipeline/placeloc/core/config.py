"""YAML run configuration: load, override with ``--set``, validate, resolve paths, hash.

A config is a plain nested dict. Its schema is the union of the shared sections
(:class:`placeloc.core.common_params.CommonParams`) and the chosen method's parameter
dataclass (see :mod:`placeloc.core.params`): every key has exactly one default there, the type
of that default is the type a user value must have, and a declared range or list of choices is checked. Values whose default is ``None`` must have
the type their dataclass field declares (``float | None`` takes a number or null). Relative
paths resolve against the folder of the config file, so a config can be moved together
with its data.

YAML is read with a safe loader that also refuses aliases (``*name``): an alias can expand
a few hundred bytes into gigabytes (the "billion laughs" attack), and a config never needs
one.
"""

from __future__ import annotations

import contextlib
import copy
import glob
import hashlib
import json
import math
from pathlib import Path
from typing import Any, Callable

import yaml

from placeloc.core import params as P
from placeloc.core.common_params import CommonParams
from placeloc.core.errors import ConfigError  # noqa: F401 - re-exported: placeloc.core.config.ConfigError
from placeloc.core.safe_io import MAX_YAML_DEPTH, DuplicateKeyError, load_yaml  # noqa: F401 - re-exported: the one YAML parser
from placeloc.core.shared_data import SHARED_PREFIX, resolve_shared

# A config larger than this is not a hand-written preset; refuse it before parsing.
MAX_CONFIG_BYTES = 1 << 20


def safe_yaml(text: str) -> Any:
    """Parse YAML text with :func:`placeloc.core.safe_io.load_yaml` (the older name)."""
    return load_yaml(text, max_bytes=MAX_CONFIG_BYTES)


def read_yaml_file(path: Path, what: str = "config file") -> Any:
    """Read and parse a YAML file; every failure becomes a ConfigError naming the file and the fix."""
    if path.is_dir():
        raise ConfigError(f"{what} {path} is a folder, not a YAML file: give the path of a .yaml file, e.g. configs/demo.yaml")
    if not path.exists():
        raise ConfigError(f"{what} {path} does not exist: give the path to a YAML preset, e.g. configs/demo.yaml")
    from placeloc.core.safe_io import UnsafeInputError, read_input_bytes

    try:
        raw = read_input_bytes(path, what, MAX_CONFIG_BYTES)
    except UnsafeInputError as exc:
        raise ConfigError(f"{exc} (a config holds settings, not data: put data in files and name them)") from None
    except PermissionError as exc:
        raise ConfigError(f"{what} {path}: permission denied; make it readable (chmod u+r) or copy it") from exc
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{what} {path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); "
                          "save it as UTF-8") from exc
    try:
        return load_yaml(text, f"{what} {path}")
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {' '.join(str(exc).split())}") from exc
# Sections a user may leave out entirely (their absence means something). A run's own
# config.yaml writes an absent one as null, so null reads as absent (a method that needs the
# section says so by name).
OPTIONAL_SECTIONS = ("query", "reference")


def load_config(
    path: str | Path | None = None,
    overrides: list[str] | None = None,
    data: dict | None = None,
    base_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Read a YAML config (or take ``data``), apply ``key.path=value`` overrides, validate.

    Returns the full config with every default filled in and paths made absolute.
    Raises :class:`ConfigError` naming the offending key and the fix.
    """
    if path is not None:
        path = Path(path)
        data = read_yaml_file(path) or {}
        base_dir = path.resolve().parent
    if not isinstance(data, dict):
        raise ConfigError(f"{path or 'config'}: the top level must be a mapping of keys to values")
    data = copy.deepcopy(data)
    for item in overrides or []:
        apply_override(data, item)
    return validate(data, Path(base_dir or Path.cwd()))


def apply_override(data: dict, item: str) -> None:
    """Apply one ``--set a.b.c=value`` (value parsed as YAML) to a raw config dict."""
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected key.path=value, e.g. --set seqslam.ds=20")
    key, raw = item.split("=", 1)
    _check_finite(f"--set {key.strip()}", raw, None)  # text that is not UTF-8, named before YAML's own words for it
    try:
        value = safe_yaml(raw) if raw.strip() else None
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        shown = item if len(item) <= 80 else f"{item[:60]}... ({len(item):,} characters)"
        if isinstance(exc, DuplicateKeyError):
            raise ConfigError(f"--set {shown!r}: {exc}") from None
        raise ConfigError(f"--set {shown!r}: the value is not valid YAML ({problem}); close brackets and quotes, "
                          f"e.g. --set {key.strip()}=[1, 2] or --set {key.strip()}='text'") from exc
    node = data
    parts = key.strip().split(".")
    if not all(parts):
        raise ConfigError(f"--set {item!r}: empty key part; expected key.path=value, e.g. --set seqslam.ds=20")
    for part in parts[:-1]:
        if not isinstance(node.get(part), dict):
            node[part] = {}
        node = node[part]
    node[parts[-1]] = value


def validate(data: dict, base_dir: Path) -> dict[str, Any]:
    """Check ``data`` against the schema of its method and return the completed config."""
    from placeloc.core.methods import METHOD_NAMES, get_method

    method_name = data.get("method")
    if method_name is None:
        raise ConfigError(f"key 'method' is missing: set it to one of {', '.join(METHOD_NAMES)}")
    if method_name not in METHOD_NAMES:
        raise ConfigError(f"method: {method_name!r} is not known; choose one of {', '.join(METHOD_NAMES)}")
    method = get_method(method_name)
    schema = P.defaults(CommonParams)
    schema[method.name] = copy.deepcopy(method.defaults)
    choices = {**P.choices(CommonParams), **{f"{method.name}.{k}": v for k, v in method.choices.items()}}
    types = {**P.declared_types(CommonParams),
             **{f"{method.name}.{k}": v for k, v in P.declared_types(method.params).items()}}
    nullable = set(P.nullable_keys(CommonParams)) | {f"{method.name}.{k}" for k in P.nullable_keys(method.params)}
    item_types = {**P.declared_item_types(CommonParams),
                  **{f"{method.name}.{k}": v for k, v in P.declared_item_types(method.params).items()}}

    path_keys = P.path_keys(CommonParams) + tuple(f"{method.name}.{k}" for k in method.path_keys)

    query_given = isinstance(data.get("query"), dict) and data["query"].get("images") is not None
    reference_given = isinstance(data.get("reference"), dict) and data["reference"].get("images") is not None
    config = _merge(schema, data, prefix="", choices=choices, types=types, nullable=nullable, item_types=item_types)
    config["method"] = method_name
    problems = P.check_bounds(method.params, config[method.name], f"{method.name}.")
    problems += P.check_bounds(CommonParams, config, "")
    problems += _check_min_max_pairs(config[method.name], f"{method.name}.")
    if problems:
        raise ConfigError(problems[0])
    for key in path_keys:
        _resolve_path(config, key, base_dir)
    if not query_given:
        config["query"] = None
    if not reference_given:
        config["reference"] = None
    for role in method.required_images:
        if config[role] is None or config[role]["images"] is None:
            raise ConfigError(f"{role}.images is missing: give the folder (or glob) of the {role} images")
    for role in ("reference", "query"):
        if config[role] is not None and config[role]["images"] is not None:
            _check_image_source(config[role]["images"], f"{role}.images", base_dir)
    gt = config["ground_truth"]
    if gt["kind"] in ("csv", "hdf5", "poses", "matrix") and gt["path"] is None:
        raise ConfigError(f"ground_truth.path is missing: kind {gt['kind']!r} reads a file; set ground_truth.path")
    if gt["path"] is not None and gt["kind"] != "none" and not Path(gt["path"]).exists():
        raise ConfigError(f"ground_truth.path: {gt['path']} does not exist; fix the path (relative paths start at the "
                          f"config's folder, {base_dir}){_from_here(gt['path'], base_dir, lambda q: Path(q).exists())}")
    method.check(config)
    from placeloc.core.limits import config_problems

    problems = config_problems(config)
    if problems:
        raise ConfigError(problems[0])
    from placeloc.evaluation.contracts import check_ground_truth

    check_ground_truth(config, method)  # the method's result contract checks its ground truth before any stage runs
    return config


def _check_min_max_pairs(section: dict, prefix: str) -> list[str]:
    """Generic cross-key rule: keys that differ only by ``min`` <-> ``max`` in their name
    (``v_min``/``v_max``, ``n_pmin``/``n_pmax``) must satisfy min <= max."""
    problems = []
    for key, lo in section.items():
        if isinstance(lo, dict):
            problems += _check_min_max_pairs(lo, f"{prefix}{key}.")
            continue
        if "min" not in key or isinstance(lo, bool) or not isinstance(lo, (int, float)):
            continue
        other = key.replace("min", "max")
        hi = section.get(other)
        if isinstance(hi, (int, float)) and not isinstance(hi, bool) and lo > hi:
            problems.append(f"{prefix}{key} ({lo!r}) is larger than {prefix}{other} ({hi!r}); "
                            f"it must be <= {prefix}{other}")
    return problems


def _merge(schema: dict, data: dict, prefix: str, choices: dict, types: dict | None = None,
           nullable: set[str] | None = None, item_types: dict | None = None) -> dict:
    out = {}
    for key in data:
        if key not in schema:
            where = prefix.rstrip(".") or "the top level"
            known = ", ".join(sorted(schema))
            import difflib  # here: only a wrong key needs it

            near = difflib.get_close_matches(str(key), [str(k) for k in schema], n=1)
            guess = f"did you mean '{prefix}{near[0]}'? " if near else ""
            raise ConfigError(f"unknown key '{prefix}{key}' in {where}; {guess}known keys: {known} "
                              "(placeloc params [METHOD] lists each with its default and meaning)")
    for key, default in schema.items():
        dotted = f"{prefix}{key}"
        if key not in data:
            out[key] = copy.deepcopy(default)
            continue
        value = data[key]
        if isinstance(default, dict):
            if value is None and key in OPTIONAL_SECTIONS:
                out[key] = copy.deepcopy(default)
                continue
            if not isinstance(value, dict):
                raise ConfigError(f"{dotted} must be a mapping (indented keys), not {value!r}")
            out[key] = _merge(default, value, f"{dotted}.", choices, types, nullable, item_types)
            continue
        if value is None and nullable and dotted in nullable:
            out[key] = None  # declared ``X | None``: null is one of its values
            continue
        # The one guard every value passes first: NaN and infinities compare false with every
        # bound (a range check lets them through) and poison whatever they reach.
        _check_finite(dotted, value, default)
        if default is None and types and dotted in types:
            out[key] = _check_declared(dotted, value, types[dotted])
        else:
            out[key] = _check_type(dotted, value, default)
        if item_types and dotted in item_types and isinstance(out[key], list):
            out[key] = [_check_type(f"{dotted}[{i}]", v, item_types[dotted](0)) for i, v in enumerate(out[key])]
        if dotted in choices and out[key] not in choices[dotted]:
            raise ConfigError(f"{dotted}: {out[key]!r} is not allowed; choose one of {', '.join(map(str, choices[dotted]))}")
    return out


# Integers past what a 64-bit array index holds reach numpy as an OverflowError.
_INT_LIMIT = 2**63 - 1


def _first_leaf(value: Any, bad: Any) -> Any:
    """The first leaf of a value (a scalar, or lists and mappings of them) for which
    ``bad(leaf)`` holds, else None."""
    if not isinstance(value, (dict, list, tuple)):
        return value if bad(value) else None
    for item in value.values() if isinstance(value, dict) else value:
        found = _first_leaf(item, bad)
        if found is not None:
            return found
    return None


def _non_finite(value: Any) -> float | int | None:
    """The first NaN, infinity or integer beyond 64 bits in a value (a number, or a list or
    mapping of them), else None."""
    return _first_leaf(value, lambda v: (isinstance(v, float) and not math.isfinite(v)) or (
        isinstance(v, int) and not isinstance(v, bool) and abs(v) > _INT_LIMIT))


def _not_utf8(value: Any) -> str | None:
    """The first string in a value that is not valid UTF-8 (a ``--set`` argument or a path
    with bytes the locale could not decode reaches Python as lone surrogates), else None."""

    def bad(v: Any) -> bool:
        try:
            v.encode("utf-8")
        except UnicodeEncodeError:
            return True
        return False

    return _first_leaf(value, lambda v: isinstance(v, str) and bad(v))


def _check_finite(key: str, value: Any, default: Any) -> None:
    """Refuse NaN and infinities (``.nan``, ``.inf``, ``-.inf`` in YAML), integers no array
    index holds, and text that is not valid UTF-8, in any value."""
    text = _not_utf8(value)
    if text is not None:
        shown = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        raise ConfigError(f"{key}: '{shown}' is not valid UTF-8 text; rename the file or folder in UTF-8 "
                          "(e.g. convmv -f latin1 -t utf8 --notest NAME) and give the new name")
    bad = _non_finite(value)
    if bad is None:
        return
    what = "is not a finite number" if bad is value else f"holds {bad!r}, not a finite number"
    if isinstance(bad, int):
        what = "is too large a number" if bad is value else "holds a number too large (beyond 64 bits)"
    example = f"; e.g. {key}: {default!r}" if default is not None else ""
    raise ConfigError(f"{key}: {value!r} {what}; every number in a config must be finite and fit 64 bits{example}")


_TYPE_WORDS = {str: "a string", int: "an integer", float: "a number", bool: "true or false", list: "a list",
               tuple: "a list", dict: "a mapping"}


def _check_declared(key: str, value: Any, allowed: tuple[type, ...]) -> Any:
    """Check a value whose default is None against the field's declared types."""
    if value is None:
        return None
    for t in allowed:
        if t is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if t is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if t in (list, tuple) and isinstance(value, list):
            return value
        if t not in (int, float) and isinstance(value, t):
            return value
    kinds = " or ".join(_TYPE_WORDS.get(t, t.__name__) for t in allowed)
    raise ConfigError(f"{key} must be {kinds} or null, got {value!r} ({type(value).__name__})")


def _check_type(key: str, value: Any, default: Any) -> Any:
    def fail(kind: str) -> ConfigError:
        hint = P.text_number_hint(value) if kind in ("an integer", "a number") else ""
        return ConfigError(f"{key} must be {kind}, got {value!r} ({type(value).__name__}){hint}; e.g. {key}: {default!r}")

    if default is None or value is None and not isinstance(default, (bool, int, float, list)):
        return value
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise fail("true or false")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail("an integer")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail("a number")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise fail("a string")
        return value
    if isinstance(default, list):
        if not isinstance(value, list):
            raise fail("a list")
        if default and len(default) in (2, 3) and len(value) != len(default):
            raise fail(f"a list of {len(default)} items")
        if default:
            return [_check_type(f"{key}[{i}]", v, default[0]) for i, v in enumerate(value)]
        return value
    return value


def _get(config: dict, dotted: str) -> tuple[dict | None, str]:
    node: Any = config
    parts = dotted.split(".")
    for part in parts[:-1]:
        node = node.get(part) if isinstance(node, dict) else None
    return (node if isinstance(node, dict) else None), parts[-1]


def _resolve_path(config: dict, dotted: str, base_dir: Path) -> None:
    node, leaf = _get(config, dotted)
    if node is None or node.get(leaf) is None:
        return
    value = str(node[leaf])
    if value.startswith(SHARED_PREFIX):
        node[leaf] = str(resolve_shared(value, dotted))
        return
    p = Path(value).expanduser()
    node[leaf] = str(p if p.is_absolute() else (base_dir / p).resolve())


def _check_image_source(spec: str, key: str, base_dir: Path | None = None) -> None:
    def found(path: str) -> bool:
        return Path(path).is_dir() or (any(ch in path for ch in "*?[") and bool(glob.glob(path)))

    if found(spec):
        return
    raise ConfigError(f"{key}: {spec} is neither a folder nor a glob that matches files; fix the path (relative paths "
                      f"start at the config's folder{f', {base_dir}' if base_dir is not None else ''})"
                      f"{_from_here(spec, base_dir, found)}")


def _from_here(spec: str, base_dir: Path | None, found: Callable[[str], bool]) -> str:
    """A relative path typed in the shell (``--set query.images=my/query``) is read from the
    config's folder, as every relative path of a config is; where that finds nothing but
    the working directory has it, the words that say so (else "")."""
    if base_dir is None:
        return ""
    base, here = Path(base_dir).resolve(), Path.cwd().resolve()
    with contextlib.suppress(ValueError):
        there = here / Path(spec).relative_to(base)
        if here != base and found(str(there)):
            return f"; from the working directory it would be {there}: give that (an absolute path)"
    return ""


def config_hash(obj: Any) -> str:
    """Stable SHA-256 of a JSON-able object (dict key order does not matter)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def to_yaml(config: dict) -> str:
    return yaml.safe_dump(config, sort_keys=False)
