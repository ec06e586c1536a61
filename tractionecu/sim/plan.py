"""Driving plans: a path with a target speed and implement state along it.

The path is sampled densely (0.05 m) into arrays of distance, position,
heading, target speed and implement-in-work flag; the simulator interpolates.
Turns change only the heading: the vehicle model is longitudinal (paper
section 2), so curvature does not alter the wheel speeds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

DS = 0.05
"""Path sampling step [m]."""


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


def back_and_forth(x0: float, y0: float, pass_length: float, n_passes: int, spacing: float,
                   v_work: float, v_turn: float, lead_in: float = 8.0) -> Plan:
    """Passes along ±x, spaced ``spacing`` [m] in +y, joined by semicircular headland turns.

    The implement is in work on each pass after ``lead_in`` metres and up
    during turns; speed targets ``v_work`` on passes, ``v_turn`` in turns.
    """
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


def straight(x0: float, y0: float, heading: float, length: float, v_work: float, lead_in: float = 8.0) -> Plan:
    """One straight run: accelerate to ``v_work`` and cruise (the paper's case study)."""
    px, py, ph = _line(x0, y0, heading, length)
    dist = np.arange(len(px)) * DS
    return Plan(dist, px, py, ph, np.full(len(px), v_work), (dist > lead_in) & (dist < length - 3.0))
