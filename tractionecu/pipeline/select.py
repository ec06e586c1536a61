"""Which estimator runs a machine, on which signal table: the hub estimator or the machine-level one.

The vehicle's ``[drivetrain] kind`` decides the estimator
(:func:`~.signals.estimator_profile`); the signals a recording carries decide
what it may claim: without a draft signal the machine-level estimator runs
with ρ_s and the draft as one sum (status ``rho_s_and_draft_not_separated``),
without a front-axle load signal it takes the loads from the mass and the
draft.  Replay and the daemon both build their estimator here (the daemon
from its configuration alone: :func:`tractionecu.service.loop.default_estimator_factory`).
"""

from __future__ import annotations

from typing import Any

from ..config import SensorSpec, VehicleParams
from ..estimation.config import EstimatorConfig
from .signals import DRAFT, FRONT_AXLE_LOAD, HUB_GROUPS, MACHINE_GROUPS, SignalGroups, estimator_profile, signal_state

__all__ = ["estimator_for", "groups_for"]


def groups_for(vehicle: VehicleParams | None) -> SignalGroups:
    """The signal table of the estimator ``vehicle`` runs (the hub's for None)."""
    return MACHINE_GROUPS if estimator_profile(vehicle) == "mechanical" else HUB_GROUPS


def estimator_for(rec: Any, vehicle: VehicleParams, cfg: EstimatorConfig, sensors: SensorSpec
                  ) -> tuple[Any, SignalGroups]:
    """``(estimator, its signal table)`` for replaying ``rec`` on ``vehicle`` (module doc)."""
    if estimator_profile(vehicle) == "mechanical":
        from ..estimation.machine import MachineEstimator

        dt = vehicle.drivetrain
        draft = dt.draft_sensing and signal_state(rec, DRAFT) == "found"
        front = dt.load_sensing == "front-axle" and signal_state(rec, FRONT_AXLE_LOAD) == "found"
        return MachineEstimator(vehicle, cfg, sensors, draft=draft, front_load=front), MACHINE_GROUPS
    from ..estimation.estimator import Estimator

    return Estimator(vehicle, cfg, sensors), HUB_GROUPS
