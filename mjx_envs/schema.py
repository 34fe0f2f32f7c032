"""One field schema for every configuration field (task settings and training settings).

A field is declared once, with its default, its docstring and what values it accepts::

    @dataclasses.dataclass(frozen=True)
    class Example:
        n_substeps: int = spec(4, "physics steps per control step", low=1)

`validate(obj)` checks every field of a schema dataclass (type, range, choices, emptiness) and
raises `ConfigError` with a one-line message naming the field; `parse(cls, name, text)` turns
the text of a ``KEY=VALUE`` command-line override into a value of the field's type (strictly:
unknown boolean words are an error); `docs(cls)` and `describe(cls, name, value)` give the text
of ``--help``. The training config (`daddpg_jax.algo.config.TrainConfig`) and the task settings
(`mjx_envs.settings`) both use it, so validation, ``--help`` and config files read one
definition. Standard library only: the robot side imports it without JAX or NumPy.
"""

from __future__ import annotations

import ast
import dataclasses
import math
import typing

_NO = object()


class ConfigError(ValueError):
    """A configuration value is outside what its field accepts (one-line message)."""


def spec(default, doc: str, *, low=None, high=None, low_open: bool = False,
         high_open: bool = False, choices=None, nonempty: bool = False, length=None):
    """A dataclass field with its schema.

    low/high: inclusive bounds (exclusive with low_open/high_open) of a number, or of every
    number inside a tuple; choices: the allowed values; nonempty: a tuple or string must not
    be empty; length: the required length of a tuple (of each inner tuple for nested ones:
    (outer, inner)).
    """
    meta = dict(doc=" ".join(doc.split()), low=low, high=high, low_open=low_open,
                high_open=high_open, choices=tuple(choices) if choices is not None else None,
                nonempty=nonempty, length=length)
    return dataclasses.field(default=default, metadata={"schema": meta})


def _meta(f: dataclasses.Field) -> dict:
    return f.metadata.get("schema", {})


def fields(cls_or_obj) -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(cls_or_obj)}


def docs(cls) -> dict[str, str]:
    """Field name -> docstring."""
    return {n: _meta(f).get("doc", "") for n, f in fields(cls).items()}


def _kind(cls, name: str):
    """The field's declared type: bool, int, float, str or tuple."""
    hints = typing.get_type_hints(cls)
    t = hints[name]
    origin = typing.get_origin(t)
    if t is tuple or origin is tuple:
        return tuple
    if t in (bool, int, float, str):
        return t
    return object


def _numbers(v):
    if isinstance(v, (tuple, list)):
        for x in v:
            yield from _numbers(x)
    else:
        yield v


def check(cls, name: str, value) -> None:
    """Raises ConfigError when `value` is not acceptable for field `name` of `cls`."""
    f = fields(cls)[name]
    m, kind = _meta(f), _kind(cls, name)
    where = f"{name}"
    if kind is bool and not isinstance(value, bool):
        raise ConfigError(f"{where} must be true or false, got {value!r}")
    if kind is int and (isinstance(value, bool) or not isinstance(value, int)):
        raise ConfigError(f"{where} must be an integer, got {value!r}")
    if kind is float and (isinstance(value, bool) or not isinstance(value, (int, float))):
        raise ConfigError(f"{where} must be a number, got {value!r}")
    if kind is str and not isinstance(value, str):
        raise ConfigError(f"{where} must be a string, got {value!r}")
    if kind is tuple and not isinstance(value, tuple):
        raise ConfigError(f"{where} must be a tuple, got {value!r}")
    if m.get("choices") is not None and value not in m["choices"]:
        raise ConfigError(f"{where} must be one of {', '.join(map(repr, m['choices']))}, "
                          f"got {value!r}")
    if m.get("nonempty") and len(value) == 0:
        raise ConfigError(f"{where} must not be empty")
    length = m.get("length")
    if length is not None:
        outer, inner = length if isinstance(length, tuple) else (length, None)
        if len(value) != outer or (inner is not None and any(
                not isinstance(x, tuple) or len(x) != inner for x in value)):
            shape = f"{outer}" if inner is None else f"{outer} x {inner}"
            raise ConfigError(f"{where} must have {shape} entries, got {value!r}")
    lo, hi = m.get("low"), m.get("high")
    if lo is None and hi is None:
        return
    for x in _numbers(value):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or math.isnan(x):
            raise ConfigError(f"{where} must hold numbers, got {value!r}")
        if lo is not None and (x < lo or (m["low_open"] and x == lo)):
            raise ConfigError(f"{where} must be {'>' if m['low_open'] else '>='} {lo}, "
                              f"got {value!r}")
        if hi is not None and (x > hi or (m["high_open"] and x == hi)):
            raise ConfigError(f"{where} must be {'<' if m['high_open'] else '<='} {hi}, "
                              f"got {value!r}")


def validate(obj) -> None:
    """Checks every schema field of a dataclass instance (see `check`)."""
    cls = type(obj)
    for name, f in fields(cls).items():
        if "schema" in f.metadata:
            check(cls, name, getattr(obj, name))


def normalize(cls, name: str, value):
    """JSON/list values -> the field's type (lists -> tuples, ints -> floats for float fields)."""
    kind = _kind(cls, name)
    if kind is tuple and isinstance(value, (list, tuple)):
        out = tuple(tuple(x) if isinstance(x, list) else x for x in value)
        return value if out == value and isinstance(value, tuple) else out
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def parse(cls, name: str, text: str):
    """The value of field `name` written as command-line text (``KEY=VALUE``).

    bool: true/false/yes/no/on/off/1/0 (anything else is an error); int: 100, 1e6;
    float; str; tuple: comma-separated numbers ('64,64'; an empty text is the empty tuple),
    or a Python literal for nested tuples ('((0.1,0.2,0.3),(0.1,0.2,0.3))').
    """
    kind = _kind(cls, name)
    text = text.strip()
    if kind is bool:
        low = text.lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ConfigError(f"{name} expects true or false, got {text!r}")
    try:
        if kind is int:
            v = float(text) if ("e" in text.lower() or "." in text) else int(text)
            if isinstance(v, float):
                if not v.is_integer():
                    raise ValueError
                v = int(v)
            return v
        if kind is float:
            return float(text)
        if kind is tuple:
            if "(" in text or "[" in text:
                v = ast.literal_eval(text)
                return normalize(cls, name, list(v) if isinstance(v, (tuple, list)) else v)
            parts = [p.strip() for p in text.split(",") if p.strip()]
            default = fields(cls)[name].default
            elem = type(default[0]) if default and not isinstance(default[0], tuple) else float
            return tuple(elem(float(p)) if elem is int else elem(p) for p in parts)
    except (ValueError, SyntaxError):
        raise ConfigError(f"{name} expects {kind.__name__}, got {text!r}") from None
    return text


def parse_overrides(cls, items, what: str) -> dict:
    """``KEY=VALUE`` items -> {field: value} for the fields of `cls` (dashes read as
    underscores). Unknown fields, malformed items and values that `parse` or `check`
    rejects raise ConfigError naming `what` (e.g. '--set')."""
    names = fields(cls)
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"{what} expects KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        k = k.strip().replace("-", "_")
        if k not in names:
            raise ConfigError(f"unknown {what} field {k!r}; valid: {', '.join(sorted(names))}")
        try:
            out[k] = parse(cls, k, v)
            check(cls, k, out[k])
        except ConfigError as e:
            raise ConfigError(f"{what} {e}") from None
    return out


def from_dict(cls, d: dict, **kw):
    """An instance from a JSON dict (unknown keys ignored, lists -> tuples); `kw` overrides."""
    names = fields(cls)
    vals = {k: normalize(cls, k, v) for k, v in d.items() if k in names}
    vals.update(kw)
    return cls(**vals)


def replace_config(obj, **overrides):
    """``dataclasses.replace`` of a schema dataclass with a clear error for unknown fields;
    values are validated."""
    names = fields(obj)
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ConfigError(f"unknown config field(s) {unknown} for {type(obj).__name__}; "
                          f"valid: {sorted(names)}")
    return dataclasses.replace(obj, **overrides)


def _plain(v):
    return [_plain(x) for x in v] if isinstance(v, tuple) else v


def to_dict_values(d: dict) -> dict:
    """A {field: value} dict made JSON-ready (tuples -> lists)."""
    return {k: _plain(v) for k, v in d.items()}


def to_dict(obj) -> dict:
    """JSON-ready dict of a schema dataclass (tuples -> lists)."""
    return to_dict_values(dataclasses.asdict(obj))


def describe_value(v) -> str:
    """A value as written on the command line (what `parse` reads back)."""
    if isinstance(v, tuple):
        if any(isinstance(x, tuple) for x in v):
            return ",".join(f"({describe_value(x)})" for x in v)
        return ",".join(describe_value(x) for x in v)
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def finalize(obj) -> None:
    """For a frozen dataclass's ``__post_init__``: JSON-style values (lists, ints for floats)
    converted to each field's type, then `validate`."""
    cls = type(obj)
    for name in fields(cls):
        v = getattr(obj, name)
        nv = normalize(cls, name, v)
        if nv is not v:
            object.__setattr__(obj, name, nv)
    validate(obj)
