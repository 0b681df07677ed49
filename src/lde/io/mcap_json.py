"""JSON channels of lde's MCAP files: one flat object of numbers per message.

Writing: :func:`plain` (one record) and :func:`json_rows` (columns -> one compact object per row;
floats with ``repr`` precision, NaN/inf as ``null``). Schemas: :func:`object_schema`. Reading:
:func:`json_columns` turns the payloads of one channel into column arrays (``int64`` where every
value is an integer: exact step times; else ``float64`` with NaN for ``null`` or a missing field).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from lde.errors import LogFormatError

__all__ = ["plain", "json_rows", "object_schema", "json_columns"]


def object_schema(
    topic: str, props: Mapping[str, Mapping[str, Any]] | Iterable[str], title: str | None = None
) -> tuple[tuple[str, ...], bytes]:
    """(field names, JSON schema) of a channel of flat objects; a plain list of names makes them
    all numbers."""
    if not isinstance(props, Mapping):
        props = {k: {"type": "number"} for k in props}
    schema = {"type": "object", "title": title or topic, "properties": {k: dict(v) for k, v in props.items()}}
    return tuple(props), json.dumps(schema).encode()


def plain(record: Mapping[str, Any]) -> dict[str, Any]:
    """A record with Python numbers only (numpy scalars converted; non-finite floats as None)."""
    out: dict[str, Any] = {}
    for k, v in record.items():
        if isinstance(v, (bool, np.bool_)):
            out[k] = bool(v)
        elif isinstance(v, (int, np.integer)):
            out[k] = int(v)
        else:
            f = float(v)
            out[k] = f if math.isfinite(f) else None
    return out


def json_rows(columns: Mapping[str, np.ndarray], n: int) -> list[str]:
    """One compact JSON object per row (floats with repr precision; NaN/inf -> null)."""
    cols: list[list[str]] = []
    for name, col in columns.items():
        a = np.asarray(col)
        if a.shape != (n,):
            raise ValueError(f"JSON column {name!r} has shape {a.shape}, expected ({n},)")
        key = json.dumps(name)
        if a.dtype == np.bool_:
            vals = ["true" if x else "false" for x in a.tolist()]
        elif np.issubdtype(a.dtype, np.integer):
            vals = [str(x) for x in a.tolist()]
        else:
            vals = [repr(x) if math.isfinite(x) else "null" for x in a.astype(np.float64).tolist()]
        cols.append([f"{key}:{v}" for v in vals])
    return ["{" + ",".join(row) + "}" for row in zip(*cols, strict=True)] if cols else ["{}"] * n


def json_columns(
    topic: str, log_time: np.ndarray, payloads: list[bytes | memoryview]
) -> dict[str, np.ndarray]:
    """Columns of a JSON channel from its messages (in time order): every field of any message,
    plus ``log_time`` and, unless a field has that name, ``t_ns`` (both the log times).

    Raises:
        LogFormatError: a message that is not a JSON object.
    """
    text = b"[" + b",".join(payloads) + b"]"
    try:
        rows = json.loads(text)
    except ValueError as exc:
        raise LogFormatError(f"topic {topic!r}: a message is not valid JSON ({exc})") from exc
    keys: dict[str, None] = {}
    for r in rows:
        if not isinstance(r, dict):
            raise LogFormatError(f"topic {topic!r}: a message is not a JSON object")
        for k in r:
            keys.setdefault(k, None)
    cols: dict[str, np.ndarray] = {}
    for k in keys:
        vals = [r.get(k) for r in rows]
        if all(type(v) is int for v in vals):
            cols[k] = np.array(vals, dtype=np.int64)  # exact (step times in ns)
        else:
            cols[k] = np.array([math.nan if v is None else v for v in vals], dtype=np.float64)
    t = np.asarray(log_time, np.int64).copy()
    cols.setdefault("t_ns", t)
    cols["log_time"] = t
    return cols
