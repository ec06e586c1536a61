"""Driving plans: a path with a target speed and implement state along it.

The path is sampled densely (0.05 m) into arrays of distance travelled,
position, heading, target speed, implement-in-work flag and direction of
travel; the simulator interpolates.  Turns change only the heading: the
vehicle model is longitudinal (paper section 2), so curvature does not alter
the wheel speeds.

A segment driven in reverse has ``direction`` −1: its positions move
backwards along the body heading, which stays the heading of the machine
(where its bonnet points), not the direction of motion.  The distance ``s``
counts metres travelled, forwards or backwards, so it only grows.  Where the
direction changes (a cusp) the simulator stops the machine before it
shuttles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

DS = 0.05
"""Path sampling step [m]."""
DURATION_CAP = 10.0
"""A scenario's ``duration_s`` is cut to this many times the time its plan is estimated to take [-]: the run
ends where the plan ends, and a longer duration only allocated noise for steps never driven (745 GiB for 1e9 s)."""


@dataclass
class Plan:
    """Densely sampled path: arrays over path distance s [m]."""

    s: NDArray[np.float64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    heading: NDArray[np.float64]
    """Heading [rad], 0 = east, counter-clockwise positive."""
    v_target: NDArray[np.float64]
    """Target speed [m/s]."""
    work: NDArray[np.bool_]
    """Implement in work."""
    direction: NDArray[np.int8] | None = None
    """Direction of travel: +1 forwards, −1 in reverse; None = forwards everywhere."""

    def __post_init__(self) -> None:
        if self.direction is None:
            self.direction = np.ones(len(self.s), dtype=np.int8)
        else:
            self.direction = np.asarray(self.direction, dtype=np.int8)
        if self.direction.shape != self.s.shape or not np.all(np.abs(self.direction) == 1):
            raise ValueError("Plan.direction: +1 or -1 for every path sample")

    @property
    def cusps(self) -> NDArray[np.float64]:
        """Path distances [m] where the direction of travel changes (the machine stops there)."""
        i = np.flatnonzero(self.direction[1:] != self.direction[:-1]) + 1
        return self.s[i].astype(float)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def at(self, d: float) -> tuple[float, float, float, float, bool]:
        """(x, y, heading, v_target, work) at path distance d [m]."""
        i = min(max(int(d / DS), 0), len(self.s) - 1)
        return float(self.x[i]), float(self.y[i]), float(self.heading[i]), float(self.v_target[i]), bool(self.work[i])


def _line(x0: float, y0: float, heading: float, length: float) -> tuple[NDArray, NDArray, NDArray]:
    n = max(int(round(length / DS)), 1)
    d = np.arange(n) * DS
    return x0 + d * np.cos(heading), y0 + d * np.sin(heading), np.full(n, heading)


def _arc(x0: float, y0: float, heading: float, radius: float, turn: float) -> tuple[NDArray, NDArray, NDArray]:
    """Arc of |turn| rad, left if turn > 0."""
    length = abs(turn) * radius
    n = max(int(round(length / DS)), 1)
    d = np.arange(n) * DS
    side = np.sign(turn)
    cx = x0 - side * radius * np.sin(heading)
    cy = y0 + side * radius * np.cos(heading)
    h = heading + side * d / radius
    return cx + side * radius * np.sin(h), cy - side * radius * np.cos(h), h


def _arc_end(x0: float, y0: float, heading: float, radius: float, turn: float) -> tuple[float, float, float]:
    """End point and heading of :func:`_arc` (the arc's samples stop one step short of it)."""
    side = np.sign(turn)
    cx = x0 - side * radius * np.sin(heading)
    cy = y0 + side * radius * np.cos(heading)
    h = heading + turn
    return float(cx + side * radius * np.sin(h)), float(cy - side * radius * np.cos(h)), float(h)


def _three_point_turn(x: float, y: float, heading: float, spacing: float, turn_sign: float, reverse: float,
                      v_turn: float, v_reverse: float) -> tuple[list, tuple[float, float]]:
    """Headland K-turn from the end of a pass to the start of the next, ``spacing`` [m] to the side.

    Forwards through a quarter circle into the headland, stop, reverse
    ``reverse`` [m] straight back, stop, forwards through a second quarter
    circle onto the next pass.  Both arcs have the radius R = (spacing +
    reverse)/2 [m], which puts the next pass at the same end of the field as
    the semicircular turn does (R = 9 m for 6 m spacing and 12 m reverse).
    Returns the segments (x, y, heading, v_target, work, direction) and the
    start point of the next pass.
    """
    radius = (spacing + reverse) / 2.0
    quarter = turn_sign * np.pi / 2.0
    segs = []
    ax, ay, ah = _arc(x, y, heading, radius, quarter)
    segs.append((ax, ay, ah, np.full(len(ax), v_turn), np.zeros(len(ax), bool), np.ones(len(ax), np.int8)))
    x, y, h = _arc_end(x, y, heading, radius, quarter)
    rx, ry, _ = _line(x, y, h + np.pi, reverse)
    segs.append((rx, ry, np.full(len(rx), h), np.full(len(rx), v_reverse), np.zeros(len(rx), bool),
                 np.full(len(rx), -1, np.int8)))
    x, y = x - reverse * np.cos(h), y - reverse * np.sin(h)
    bx, by, bh = _arc(x, y, h, radius, quarter)
    segs.append((bx, by, bh, np.full(len(bx), v_turn), np.zeros(len(bx), bool), np.ones(len(bx), np.int8)))
    x, y, _ = _arc_end(x, y, h, radius, quarter)
    return segs, (x, y)


def back_and_forth(x0: float, y0: float, pass_length: float, n_passes: int, spacing: float,
                   v_work: float, v_turn: float, lead_in: float = 8.0, reverse_at_headland: float = 0.0,
                   v_reverse: float = 1.0) -> Plan:
    """Passes along ±x, spaced ``spacing`` [m] in +y, joined by headland turns.

    The implement is in work on each pass after ``lead_in`` metres and up
    during turns; speed targets ``v_work`` on passes, ``v_turn`` in turns.
    With ``reverse_at_headland`` = 0 the turns are semicircles of radius
    ``spacing``/2; with ``reverse_at_headland`` > 0 [m] every turn is a
    three-point turn (:func:`_three_point_turn`) whose middle leg reverses
    that far straight back at ``v_reverse`` [m/s].
    """
    if reverse_at_headland < 0.0 or v_reverse <= 0.0:
        raise ValueError("back_and_forth: reverse_at_headland >= 0 m and v_reverse > 0 m/s")
    if reverse_at_headland > 0.0:
        return _back_and_forth_reversing(x0, y0, pass_length, n_passes, spacing, v_work, v_turn, lead_in,
                                         reverse_at_headland, v_reverse)
    xs, ys, hs, vs, ws = [], [], [], [], []
    x, y = x0, y0
    for k in range(n_passes):
        heading = 0.0 if k % 2 == 0 else np.pi
        px, py, ph = _line(x, y, heading, pass_length)
        xs.append(px); ys.append(py); hs.append(ph)
        dist = np.arange(len(px)) * DS
        vs.append(np.where(dist > pass_length - 6.0, v_turn, v_work))
        ws.append((dist > lead_in) & (dist < pass_length - 3.0))
        x, y = px[-1] + DS * np.cos(heading), py[-1] + DS * np.sin(heading)
        if k < n_passes - 1:
            turn = np.pi if k % 2 == 0 else -np.pi
            ax, ay, ah = _arc(x, y, heading, spacing / 2.0, turn)
            xs.append(ax); ys.append(ay); hs.append(ah)
            vs.append(np.full(len(ax), v_turn)); ws.append(np.zeros(len(ax), bool))
            x, y = x, y + spacing
    X = np.concatenate(xs); Y = np.concatenate(ys); H = np.concatenate(hs)
    return Plan(np.arange(len(X)) * DS, X, Y, H, np.concatenate(vs), np.concatenate(ws))


def _back_and_forth_reversing(x0: float, y0: float, pass_length: float, n_passes: int, spacing: float,
                              v_work: float, v_turn: float, lead_in: float, reverse: float, v_reverse: float) -> Plan:
    """:func:`back_and_forth` with a three-point turn at every headland."""
    segs = []
    x, y = x0, y0
    for k in range(n_passes):
        heading = 0.0 if k % 2 == 0 else np.pi
        px, py, ph = _line(x, y, heading, pass_length)
        dist = np.arange(len(px)) * DS
        segs.append((px, py, ph, np.where(dist > pass_length - 6.0, v_turn, v_work),
                     (dist > lead_in) & (dist < pass_length - 3.0), np.ones(len(px), np.int8)))
        x, y = px[-1] + DS * np.cos(heading), py[-1] + DS * np.sin(heading)
        if k < n_passes - 1:
            turn, (x, y) = _three_point_turn(x, y, heading, spacing, 1.0 if k % 2 == 0 else -1.0, reverse,
                                             v_turn, v_reverse)
            segs += turn
    X, Y, H, V, W, D = (np.concatenate(c) for c in zip(*segs))
    return Plan(np.arange(len(X)) * DS, X, Y, H, V, W, D)


def straight(x0: float, y0: float, heading: float, length: float, v_work: float, lead_in: float = 8.0) -> Plan:
    """One straight run: accelerate to ``v_work`` and cruise (the paper's case study)."""
    px, py, ph = _line(x0, y0, heading, length)
    dist = np.arange(len(px)) * DS
    return Plan(dist, px, py, ph, np.full(len(px), v_work), (dist > lead_in) & (dist < length - 3.0))


def s_curves(x0: float, y0: float, pass_length: float, n_passes: int, spacing: float, radius: float,
             v_work: float, v_turn: float, wave_angle: float = 0.4, lead_in: float = 8.0) -> Plan:
    """Work passes that are S-shaped: arcs of ``radius`` [m] turning alternately right and left by
    ``wave_angle`` [rad] about the pass direction (±x), spaced ``spacing`` [m] in +y, joined by
    semicircular headland turns of radius ``spacing``/2.  Each pass starts and ends on its mean direction
    (half arcs at both ends); the implement is in work after ``lead_in`` metres, up in the turns."""
    xs, ys, hs, vs, ws = [], [], [], [], []
    x, y = x0, y0
    for k in range(n_passes):
        heading = 0.0 if k % 2 == 0 else np.pi
        sign = 1.0 if k % 2 == 0 else -1.0
        arcs = [wave_angle / 2.0]
        adv = radius * np.sin(wave_angle / 2.0)
        side = -1.0
        while adv + 2.0 * radius * np.sin(wave_angle / 2.0) * 1.0 < pass_length:
            arcs.append(side * wave_angle)
            adv += 2.0 * radius * np.sin(wave_angle / 2.0)
            side = -side
        arcs.append(side * wave_angle / 2.0 if len(arcs) % 2 == 0 else -side * wave_angle / 2.0)
        # Heading must return to the pass direction: fix the last half arc by the running sum.
        arcs[-1] = -sum(arcs[:-1])
        h = heading
        seg_x, seg_y, seg_h = [], [], []
        for turn in arcs:
            ax, ay, ah = _arc(x, y, h, radius, turn)
            seg_x.append(ax); seg_y.append(ay); seg_h.append(ah)
            x, y, h = _arc_end(x, y, h, radius, turn)
        px, py, ph = np.concatenate(seg_x), np.concatenate(seg_y), np.concatenate(seg_h)
        dist = np.arange(len(px)) * DS
        total = len(px) * DS
        xs.append(px); ys.append(py); hs.append(ph)
        vs.append(np.where(dist > total - 6.0, v_turn, v_work))
        ws.append((dist > lead_in) & (dist < total - 3.0))
        if k < n_passes - 1:
            turn = np.pi if k % 2 == 0 else -np.pi
            ax, ay, ah = _arc(x, y, heading, spacing / 2.0, turn)
            xs.append(ax); ys.append(ay); hs.append(ah)
            vs.append(np.full(len(ax), v_turn)); ws.append(np.zeros(len(ax), bool))
            x, y, _ = _arc_end(x, y, heading, spacing / 2.0, turn)
        del sign
    X = np.concatenate(xs); Y = np.concatenate(ys); H = np.concatenate(hs)
    return Plan(np.arange(len(X)) * DS, X, Y, H, np.concatenate(vs), np.concatenate(ws))


def circles(x0: float, y0: float, radius: float, n_circles: int, v_work: float, straight_m: float = 20.0,
            lead_in: float = 8.0) -> Plan:
    """Circular work passes: ``straight_m`` [m] along +x, then a full circle of ``radius`` [m], left first,
    then alternately right, each circle preceded by the straight; implement in work after ``lead_in``
    metres until 3 m before the end."""
    xs, ys, hs = [], [], []
    x, y, h = x0, y0, 0.0
    for k in range(n_circles):
        lx, ly, lh = _line(x, y, h, straight_m)
        xs.append(lx); ys.append(ly); hs.append(lh)
        x, y = x + straight_m * np.cos(h), y + straight_m * np.sin(h)
        turn = 2.0 * np.pi if k % 2 == 0 else -2.0 * np.pi
        ax, ay, ah = _arc(x, y, h, radius, turn)
        xs.append(ax); ys.append(ay); hs.append(ah)
        x, y, h = _arc_end(x, y, h, radius, turn)
    lx, ly, lh = _line(x, y, h, straight_m)
    xs.append(lx); ys.append(ly); hs.append(lh)
    X = np.concatenate(xs); Y = np.concatenate(ys); H = np.concatenate(hs)
    dist = np.arange(len(X)) * DS
    return Plan(dist, X, Y, H, np.full(len(X), v_work), (dist > lead_in) & (dist < dist[-1] - 3.0))
