"""Divergence detection: notice a filter that has lost the vehicle.

A measurement gate that rejects measurements for seconds, or innovations far
outside their χ² bound for as long, mean the filter — not the sensors — is
wrong: a manoeuvre the model cannot follow (reversing, a lifted wheel), a
sensor glitch that pulled the state away, or a data gap with motion.  The
monitor declares the filter *lost* when any of these holds:

1. **Innovations**: one measurement channel (the wheel speeds, or the
   ground speed) was gated on every update that carried it for
   ``lost_after_s`` — a filter that keeps refusing a sensor while accepting
   the others has parted from that sensor — or every update for as long had
   a NIS above the χ²(dof) quantile of probability ``1 − nis_alpha`` (far
   above the 95 % band the filter is tuned to: with the default α = 1e-6 and
   a 100 Hz update, a consistent filter would need ~10⁶ years to show one
   such run by chance).
2. **Physical envelope**: the estimated ground speed has the opposite sign
   to the wheel-based speed while both move faster than ``min_speed_mps`` —
   wheels and vehicle cannot travel in opposite directions in traction.
3. **Parameter bound**: ρ_s has stayed within 10 % of its upper bound for
   ``lost_after_s`` while moving (real soils stay far below it; ρ_s is
   unobservable only at standstill).

:meth:`DivergenceMonitor.update` returns the time the bad run began (the
start of the *lost period*: nothing from it should be mapped) on the step
the filter is declared lost, else None.
"""

from __future__ import annotations

import math

from scipy.stats import chi2

MAX_DOF = 8
"""Largest number of output components an update can have."""


class DivergenceMonitor:
    """Watch innovations, the speed envelope and ρ_s for a lost filter (module doc).

    Parameters
    ----------
    lost_after_s : length of a bad run that declares the filter lost [s]; 0 disables.
    nis_alpha : tail probability of the NIS bound [-].
    rho_max : upper bound of ρ_s [-] (the estimator's clamp).
    min_speed_mps : speeds below this are "not moving" for the envelope and ρ_s checks [m/s].
    """

    def __init__(self, lost_after_s: float, nis_alpha: float, rho_max: float, min_speed_mps: float) -> None:
        self.lost_after_s = float(lost_after_s)
        self.rho_max = float(rho_max)
        self.min_speed = float(min_speed_mps)
        self._bound = [math.inf] + [float(chi2.isf(nis_alpha, k)) for k in range(1, MAX_DOF + 1)]
        self.reset()

    def reset(self) -> None:
        """Forget the runs (after the filter was re-initialised)."""
        self._nis_since: float | None = None
        self._wheel_since: float | None = None
        self._ground_since: float | None = None
        self._rho_since: float | None = None

    def update(self, t: float, wheel_out: bool | None, ground_out: bool | None, nis: float, dof: int,
               v_hat: float, v_wheel: float | None, rho: float) -> float | None:
        """One step at ``t`` [s].

        ``wheel_out`` / ``ground_out``: whether this step's update found the
        wheel speeds / the ground speed outside the gate (None: the update did
        not carry that channel); ``nis`` and ``dof`` are the update's (dof 0:
        no update); ``v_hat`` the estimated speed, ``v_wheel`` the wheel-based
        speed r·ω [m/s] (None: no wheel speeds this step), ``rho`` the
        estimated ρ_s.

        Returns the start of the lost period [s] when the filter is declared lost, else None.
        """
        if self.lost_after_s <= 0.0:
            return None
        # 1. innovations: a channel outside the gate on every update that carried it, or NIS far out
        if wheel_out is not None:
            if not wheel_out:
                self._wheel_since = None
            elif self._wheel_since is None:
                self._wheel_since = t
        if ground_out is not None:
            if not ground_out:
                self._ground_since = None
            elif self._ground_since is None:
                self._ground_since = t
        if dof > 0:
            if nis <= self._bound[dof if dof <= MAX_DOF else MAX_DOF]:     # False for NaN
                self._nis_since = None
            elif self._nis_since is None:
                self._nis_since = t
        first = t
        for since in (self._wheel_since, self._ground_since, self._nis_since):
            if since is not None and since < first:
                first = since
        if t - first >= self.lost_after_s:
            return self._lost(first)
        # 2. physical envelope: vehicle and wheels travel the same way
        if v_wheel is None:
            return None
        moving = v_wheel >= self.min_speed or v_wheel <= -self.min_speed
        if moving and (v_hat >= self.min_speed and v_wheel < 0.0 or v_hat <= -self.min_speed and v_wheel > 0.0):
            return self._lost(t)
        # 3. ρ_s held near its bound while moving
        if moving and rho >= 0.9 * self.rho_max:
            if self._rho_since is None:
                self._rho_since = t
            elif t - self._rho_since >= self.lost_after_s:
                return self._lost(self._rho_since)
        else:
            self._rho_since = None
        return None

    def _lost(self, since: float) -> float:
        self.reset()
        return since
