"""JSON that strict parsers read: NaN and ±inf as ``null`` (Python's ``json`` writes bare ``NaN``)."""

from __future__ import annotations

import math
from typing import Any


def json_safe(x: Any) -> Any:
    """JSON-safe copy: NaN and ±inf become None (``null``), numpy scalars and arrays plain Python."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if hasattr(x, "tolist"):
        return json_safe(x.tolist())
    return x


__all__ = ["json_safe"]
