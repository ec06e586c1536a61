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
        self._gated_since: dict[str, float | None] = {"wheel": None, "ground": None}
        self._rho_since: float | None = None

    def update(self, t: float, gated: dict[str, bool], nis: float, dof: int, v_hat: float, v_wheel: float | None,
               rho: float) -> float | None:
        """One step at ``t`` [s].

        ``gated`` says, for each channel this step's update carried
        (``"wheel"``, ``"ground"``), whether the gate refused it; ``nis`` and
        ``dof`` are the update's (dof 0: no update); ``v_hat`` the estimated
        speed, ``v_wheel`` the wheel-based speed r·ω [m/s] (None: no wheel
        speeds this step), ``rho`` the estimated ρ_s.

        Returns the start of the lost period [s] when the filter is declared lost, else None.
        """
        if self.lost_after_s <= 0.0:
            return None
        # 1. innovations: a channel refused on every update that carried it, or NIS far out on every update
        for ch, refused in gated.items():
            if not refused:
                self._gated_since[ch] = None
            elif self._gated_since[ch] is None:
                self._gated_since[ch] = t
        if dof > 0:
            if math.isfinite(nis) and nis <= self._bound[min(dof, MAX_DOF)]:
                self._nis_since = None
            elif self._nis_since is None:
                self._nis_since = t
        starts = [s for s in (*self._gated_since.values(), self._nis_since) if s is not None]
        if starts and t - min(starts) >= self.lost_after_s:
            return self._lost(min(starts))
        # 2. physical envelope: vehicle and wheels travel the same way
        moving = v_wheel is not None and abs(v_wheel) >= self.min_speed
        if moving and abs(v_hat) >= self.min_speed and (v_hat > 0.0) != (v_wheel > 0.0):  # type: ignore[operator]
            return self._lost(t)
        # 3. ρ_s held near its bound while moving
        if moving and rho >= 0.9 * self.rho_max:
            if self._rho_since is None:
                self._rho_since = t
            elif t - self._rho_since >= self.lost_after_s:
                return self._lost(self._rho_since)
        elif v_wheel is not None:
            self._rho_since = None
        return None

    def _lost(self, since: float) -> float:
        self.reset()
        return since
