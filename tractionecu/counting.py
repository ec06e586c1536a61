"""Counted, logged skips: the one reject counter and the one warn-once of the package.

Every reader of outside input (candump lines, NMEA sentences, CSV rows, CAN
frames on a live bus) follows the same bad-input policy: skip the bad item,
count it by reason, keep the first line numbers and text as examples, and
log the first occurrence of each kind at WARNING (later ones at DEBUG).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

MAX_EXAMPLES = 5
"""Line numbers kept per reject reason."""

MAX_TEXT = 80
"""Characters kept of the first offending line of each reason."""


@dataclass
class RejectCounter:
    """Lines read and lines rejected by reason, with examples.

    ``examples[reason]`` holds the first :data:`MAX_EXAMPLES` line numbers
    (1-based) of each reason; ``texts[reason]`` the first offending line,
    shortened to :data:`MAX_TEXT` characters.  ``source`` names the file in
    :meth:`describe`.
    """

    source: str = ""
    lines: int = 0
    rejected: Counter = field(default_factory=Counter)
    examples: dict[str, list[int]] = field(default_factory=dict)
    texts: dict[str, str] = field(default_factory=dict)

    def reject(self, reason: str, lineno: int, text: str = "") -> None:
        """Count one rejected line."""
        self.rejected[reason] += 1
        ex = self.examples.setdefault(reason, [])
        if len(ex) < MAX_EXAMPLES and (not ex or ex[-1] != lineno):   # a line with two bad cells: named once
            ex.append(lineno)
        if text and reason not in self.texts:
            t = text.rstrip("\r\n")
            self.texts[reason] = t if len(t) <= MAX_TEXT else t[: MAX_TEXT - 3] + "..."

    @property
    def total_rejected(self) -> int:
        """Number of lines rejected for any reason."""
        return sum(self.rejected.values())

    def describe(self) -> list[str]:
        """One line per reject reason: ``reason: count (file line a, b, ...)`` (without line numbers where the
        reader gave none: 0)."""
        out = []
        src = f"{self.source} " if self.source else ""
        for reason in sorted(self.rejected):
            ex = [k for k in self.examples.get(reason, []) if k > 0]     # 0: a reader that gives no line number
            if not ex:
                out.append(f"{reason}: {self.rejected[reason]}" + (f" ({self.source})" if self.source else ""))
                continue
            more = "" if self.rejected[reason] <= len(ex) else ", ..."
            out.append(f"{reason}: {self.rejected[reason]} ({src}line {', '.join(map(str, ex))}{more})")
        return out

    def notes(self) -> list[str]:
        """Lines read, but not as they were written (a reader's repairs), one line each; none here."""
        return []


class WarnOnce:
    """Log the first message of each kind at WARNING (or ``level``), later ones of the same kind at DEBUG.

    ``forget(kind)`` re-arms a kind (e.g. after a device came back, so the
    next failure is reported again).
    """

    __slots__ = ("log", "_seen")

    def __init__(self, log: logging.Logger) -> None:
        self.log = log
        self._seen: set[str] = set()

    def __call__(self, kind: str, msg: str, *args: Any, level: int = logging.WARNING) -> None:
        if kind in self._seen:
            self.log.debug(msg, *args)
        else:
            self._seen.add(kind)
            self.log.log(level, msg, *args)

    def forget(self, kind: str) -> None:
        """Warn again the next time ``kind`` happens."""
        self._seen.discard(kind)

    def __contains__(self, kind: object) -> bool:
        return kind in self._seen
