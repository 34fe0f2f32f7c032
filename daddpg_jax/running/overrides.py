"""Command-line helpers shared by the experiment scripts: KEY=VALUE overrides of config
dataclasses and their attribute docstrings (for --help)."""

from __future__ import annotations

import ast
import inspect


def field_docs(cls) -> dict:
    """Attribute docstrings of a dataclass (the string literal after each field)."""
    try:
        tree = ast.parse(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    body = tree.body[0].body
    docs = {}
    for a, b in zip(body, body[1:]):
        if isinstance(a, ast.AnnAssign) and isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant):
            docs[a.target.id] = " ".join(str(b.value.value).split())
    return docs


def parse_value(text: str, default):
    if isinstance(default, bool):
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"expected a boolean, got {text!r}")
    if isinstance(default, tuple):
        parts = [p for p in text.replace("(", "").replace(")", "").split(",") if p.strip()]
        if default and isinstance(default[0], tuple):
            return ast.literal_eval(text)
        kind = type(default[0]) if default else float
        return tuple(kind(p) for p in parts)
    if isinstance(default, int):
        return int(float(text)) if "e" in text.lower() else int(text)
    if isinstance(default, float):
        return float(text)
    return text


def parse_overrides(items, defaults: dict, what: str) -> dict:
    out = {}
    for item in items or []:
        if "=" not in item:
            raise SystemExit(f"error: {what} expects KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        k = k.strip().replace("-", "_")
        if k not in defaults:
            raise SystemExit(f"error: unknown {what} field {k!r}; valid: {', '.join(sorted(defaults))}")
        try:
            out[k] = parse_value(v.strip(), defaults[k])
        except ValueError as e:
            raise SystemExit(f"error: {what} {k}: {e}")
    return out
