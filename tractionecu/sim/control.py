"""The driver's speed control, shared by both truth models (:mod:`.simulator`, :mod:`.physical`).

:class:`ControllerSpec` holds the speed controller's settings; :class:`Shuttle`
is the direction of travel along a plan.  The plan's direction changes only at
standstill: the speed reference brakes to a stop at each cusp
(``ControllerSpec.stop_decel``), holds still for ``shuttle_dwell_s``, then
accelerates the other way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .plan import DS, Plan

V_STANDSTILL = 0.01
"""|v| [m/s] below which the machine counts as standing still (shuttling allowed)."""


@dataclass(frozen=True)
class ControllerSpec:
    """Speed controller of the driver / cruise control."""

    accel_max: float = 0.35
    """Acceleration limit of the speed reference [m/s²]."""
    kp: float = 1.2
    """Proportional gain [1/s]."""
    ki: float = 0.4
    """Integral gain [1/s²]."""
    torque_tau_s: float = 0.05
    """Inverter torque response time constant [s]."""
    rho_guess: float = 0.07
    """Rolling resistance used in the feed-forward [-]."""
    stop_decel: float = 0.25
    """Deceleration of the speed target approaching a change of direction [m/s²] (below accel_max)."""
    shuttle_dwell_s: float = 1.0
    """Time at standstill before the direction of travel changes (power-shuttle reversal) [s]."""
    hold_tau_s: float = 0.25
    """At a change of direction, once the speed reference is zero, the integral term (the drive force
    that kept the machine rolling) decays with this time constant [s]: the machine comes to rest."""


class Shuttle:
    """Direction of travel along a plan and its change at each cusp (module doc), for both truth models.

    The speed target brakes to stand still at the next cusp (``ControllerSpec.stop_decel``); at the cusp,
    once the machine has stood still (|v| < V_STANDSTILL) for ``shuttle_dwell_s``, the direction changes
    to the plan's direction past the cusp.  ``direction`` (+1 / −1) and ``next_cusp`` (path distance [m],
    inf when none is ahead) are read by the integrator; ``hold_decay`` is the per-step decay of the speed
    controller's integral term at a cusp (``hold_tau_s``).
    """

    def __init__(self, plan: Plan, ctl: ControllerSpec, dt: float) -> None:
        self._plan, self._ctl, self._dt = plan, ctl, dt
        self._cusps = plan.cusps
        self._n_path = len(plan.s)
        self._i = 0
        self._still_s = 0.0
        self.direction = int(plan.direction[0])
        self.next_cusp = float(self._cusps[0]) if len(self._cusps) else math.inf
        self.hold_decay = math.exp(-dt / ctl.hold_tau_s)

    def at_cusp(self, d: float, v_ref: float) -> bool:
        """True at the cusp [path distance d, m] once the plan's speed reference there is zero."""
        return self.next_cusp - d <= DS and v_ref == 0.0

    def advance(self, at_cusp: bool, d: float, v: float) -> float:
        """Count the standstill at the cusp; after the dwell, change direction and move past the cusp.
        Returns the path distance [m] (the cusp's once passed)."""
        if at_cusp and abs(v) < V_STANDSTILL:
            self._still_s += self._dt
            if self._still_s >= self._ctl.shuttle_dwell_s - 1e-9:
                d = self.next_cusp
                self._i += 1
                self.direction = int(self._plan.direction[min(int(round(d / DS)), self._n_path - 1)])
                self.next_cusp = float(self._cusps[self._i]) if self._i < len(self._cusps) else math.inf
                self._still_s = 0.0
        else:
            self._still_s = 0.0
        return d

    def brake(self, v_tgt: float, d: float) -> float:
        """The speed target [m/s, magnitude] limited so as to stand still at the next cusp."""
        if self.next_cusp < math.inf:
            return min(v_tgt, math.sqrt(2.0 * self._ctl.stop_decel * max(self.next_cusp - d, 0.0)))
        return v_tgt
