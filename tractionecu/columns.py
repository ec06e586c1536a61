"""Blocks of estimates as columns: a dict of equal-length columns, each a numpy array or a list.

Replay's and batch replay's sinks and the fixed-lag smoother's blocks all hold estimates this way.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["concat"]


def concat(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The blocks ``parts`` (at least one, with the keys of the first) one after the other: arrays concatenated
    (numpy), lists joined."""
    return {name: (np.concatenate([p[name] for p in parts]) if isinstance(parts[0][name], np.ndarray)
                   else [x for p in parts for x in p[name]]) for name in parts[0]}
