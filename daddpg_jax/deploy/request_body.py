"""The body of a policy-service request, checked before the policy sees it: strict JSON with
a nesting limit checked in C and NumPy (`decode_body`, `json_depth_exceeds`), the /act fields
(`check_fields`) and their matrices of finite float32 numbers (`parse_matrix`). Every refusal
is a `RequestError` carrying the HTTP status; ``daddpg_jax.deploy.server`` answers it.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

REQUEST_FIELDS = ("observation", "desired_goal", "id")


class RequestError(Exception):
    def __init__(self, status: int, message: str, close: bool = False, extra=()):
        super().__init__(message)
        self.status = status
        self.message = message
        self.close = close
        self.extra = tuple(extra)  # more answer headers: (name, value) pairs


_DROP = bytes(c for c in range(256) if c not in b'"[]{}')
_TO_STEP = bytes.maketrans(b"[{]}", b"\x01\x01\xff\xff")  # +1 / -1 as int8


def json_depth_exceeds(body: bytes, max_depth: int) -> bool:
    """True when arrays/objects nest deeper than ``max_depth`` (brackets inside strings do not
    count). In C and NumPy, no per-byte Python: escapes go first (escaped backslashes, then
    escaped quotes, left to right as JSON reads them), then every byte but quotes and brackets
    (``bytes.translate``); the parts between quotes are strings and are dropped, and the depth
    is a cumulative sum of +1/-1 (its cost: docs/RELIABILITY.md, "Policy service")."""
    if body.count(b"[") + body.count(b"{") <= max_depth:
        return False
    if b"\\" in body:
        body = body.replace(b"\\\\", b"").replace(b'\\"', b"")
    s = body.translate(None, _DROP)
    if b'"' in s:
        s = b"".join(s.split(b'"')[::2])
    if len(s) <= max_depth:
        return False
    steps = np.frombuffer(s.translate(_TO_STEP), np.int8)
    return bool(np.cumsum(steps, dtype=np.int32).max() > max_depth)


def decode_body(body: bytes, max_depth: int) -> Any:
    """A request body as strict JSON: UTF-8 without a byte-order mark, no NaN/Infinity, nesting
    at most ``max_depth``; RequestError 400 otherwise."""
    if body[:3] == b"\xef\xbb\xbf":
        raise RequestError(400, "invalid JSON: a byte-order mark is not allowed")
    try:
        text = body.decode("utf-8")
    except UnicodeDecodeError as e:
        raise RequestError(400, f"body is not UTF-8: {e}") from None
    if json_depth_exceeds(body, max_depth):
        raise RequestError(400, f"JSON nested deeper than {max_depth} levels")
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except RecursionError:
        raise RequestError(400, "JSON nested too deeply") from None
    except ValueError as e:
        raise RequestError(400, f"invalid JSON: {e}") from None


def _reject_constant(name):
    raise ValueError(f"{name} is not valid JSON (non-finite numbers are refused)")


def parse_matrix(name: str, value: Any, rows: int, cols: int) -> np.ndarray:
    """A JSON value that must be ``rows`` lists of ``cols`` finite numbers -> float32 array."""
    if not isinstance(value, list) or len(value) != rows:
        got = f"a list of {len(value)}" if isinstance(value, list) else type(value).__name__
        raise RequestError(400, f"'{name}' must be a list of {rows} rows of {cols} numbers; "
                                f"got {got}")
    out = np.empty((rows, cols), np.float64)
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != cols:
            got = f"a list of {len(row)}" if isinstance(row, list) else type(row).__name__
            raise RequestError(400, f"'{name}'[{i}] must be a list of {cols} numbers; got {got}")
        for j, x in enumerate(row):
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise RequestError(400, f"'{name}'[{i}][{j}] must be a number, got "
                                        f"{type(x).__name__}")
            if isinstance(x, float) and not math.isfinite(x):
                raise RequestError(400, f"'{name}'[{i}][{j}] is not finite")
            if isinstance(x, int) and abs(x) > 1e300:
                raise RequestError(400, f"'{name}'[{i}][{j}] is out of range")
            out[i, j] = x
    out32 = out.astype(np.float32)
    if not np.all(np.isfinite(out32)):
        raise RequestError(400, f"'{name}' holds a number beyond the float32 range")
    return out32


def check_fields(req: dict) -> None:
    """400 naming the missing and the unknown fields of a /act request, if any.

    Unknown fields are refused rather than ignored: a client that sends a field this service
    does not implement (a misspelt name, an option of another version) learns it at once
    instead of having the robot act on an answer computed without it.
    """
    missing = [k for k in ("observation", "desired_goal") if k not in req]
    unknown = [k for k in req if k not in REQUEST_FIELDS]
    if not missing and not unknown:
        return
    parts = []
    if missing:
        parts.append(f"missing field(s) {missing}")
    if unknown:
        names = ", ".join(repr(k if len(k) <= 40 else k[:40] + "...") for k in unknown[:5])
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        parts.append(f"unknown field(s) {names}{more}")
    raise RequestError(400, "; ".join(parts) + "; a request has 'observation', "
                            "'desired_goal' and optionally 'id'")
