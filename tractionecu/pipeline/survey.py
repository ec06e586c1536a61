"""Which signals a survey of a long recording keeps whole.

``tractionecu replay`` and ``tractionecu inspect`` read a recording block by
block (:mod:`tractionecu.recording.chunks`); they keep whole only the few
signals their reports and the CAN-to-GNSS clock offset use, and of every other
signal a stub that tells whether it is present and sent as numbers
(``keep`` of :func:`tractionecu.recording.reader.read_recording`).
"""

from __future__ import annotations

from ..recording.clock import SPEED_SIGNALS as CLOCK_SPEEDS
from ..recording.clock import WHEEL_SIGNALS as CLOCK_WHEELS
from .signals import (ENGINE_IDLE_SPEED, ENGINE_SPEED, HUB_GROUPS, MACHINE_GROUPS, PARKING_BRAKE, SELECTED_GEAR,
                      SPEED_SIGNALS)

SURVEY_FULL = frozenset({*CLOCK_SPEEDS, *SPEED_SIGNALS, ENGINE_IDLE_SPEED, SELECTED_GEAR, PARKING_BRAKE})
"""Signals a survey keeps whole: ground- and wheel-based speeds (10 Hz messages; the clock offset and the
motion report use them) and the engine's idle speed, selected gear and parking brake (motion report).  The
wheel speeds are kept too while no ground- or wheel-based speed has been seen: the clock offset falls back
to them."""

INSPECT_FULL = SURVEY_FULL | {ENGINE_SPEED}
"""What ``inspect`` keeps whole: the survey's signals and the engine speed (its range and median in the
motion report)."""


REPLAY_SIGNALS = frozenset(nm for g in (HUB_GROUPS, MACHINE_GROUPS) for names in g.groups.values() for nm in names)
"""Every bus signal either estimator's replay steps on (:data:`~.signals.HUB_GROUPS`,
:data:`~.signals.MACHINE_GROUPS`): what batch replay's survey holds decoded for its one pass
(:class:`~tractionecu.recording.reader.HeldBlocks`)."""


def survey_keep(name: str, seen: set[str]) -> bool:
    """``keep`` for replay's survey (module doc)."""
    if name in SURVEY_FULL:
        return True
    return name in CLOCK_WHEELS and not any(s in seen for s in CLOCK_SPEEDS)


def inspect_keep(name: str, seen: set[str]) -> bool:
    """``keep`` for ``tractionecu inspect`` (module doc)."""
    return name in INSPECT_FULL or survey_keep(name, seen)
