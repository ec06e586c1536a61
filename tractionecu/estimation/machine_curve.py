"""The μ(s) prior of the machine-level estimator (:mod:`.machine`): which one-parameter shape a·g(s) it fits.

Why a prior, and why it decides the curve
-----------------------------------------
The machine-level estimator gives one (μ, s) pair per instant: μ = ΣF_h/ΣF_z of the whole machine and
the effective slip s_e of its two axles (g(s_e) = Σ w_a g(s_a), :meth:`.machine.MachineEstimator.
_effective_slip`).  In steady work the pairs of one soil sit at one working point: on
``mechanical-three-soils`` seed 0 the rear slip spans 0.031-0.057 / 0.038-0.065 / 0.070-0.102 (5-95 %,
firm / mid / soft) and the estimated μ and slip are not correlated beyond their noise (correlation of
the valid pairs 0.00 / 0.23 / 0.49; of the truth's own pairs 0.78 / 0.75 / 0.80, yet a free shape fit
even on those gives R² 0.85 / -0.42 / 0.92, load transfer moving the pairs across curves of different
load): the data fix the level a·g(s_work) and nothing of the shape.
Whatever the curve is away from the working point comes from the shape the estimator assumes, so the
R² of μ(s) over 0-0.4 scores that assumption.  Choosing among several classes on these data does not
help: with slip noise and no μ-s correlation the class likelihood of :mod:`.curve` prefers the class
steepest in g'/g at the working slip (its predicted slip varies least), whatever the soil.

Priors
------
* the configured ``soil_classes`` (default): the paper's class path (eq. 14 with ``stubble``'s p, α1, α2);
* ``"d497"`` (:data:`D497`): the shape of the ASABE D497.7 / Brixius (1987) gross traction ratio,
  GT(s) = 0.88 (1 − e^{−0.1 B_n}) (1 − e^{−7.5 s}) + 0.04, the field's standard traction equation for
  tractor tyres on agricultural soil.  Its slip dependence 1 − e^{−7.5 s} does not depend on the soil
  (the mobility number B_n scales it only), so it is a one-parameter family a·g(s) in the paper's sense:
  eq. 14 with p = 1, α1 = α2 = −7.5.  **The project's physical truth (``tractionecu.sim.tyre``) uses
  Brixius' equations**, so R² figures with this prior on the simulated tractors measure the estimator
  against its truth's own family; a real tyre on a real soil departs from D497 by its own amount.
  On soils of an independent tyre–soil model (Bekker sinkage, Janosi–Hanamoto shear over the contact
  patch, :mod:`tractionecu.sim.terramech`; scenarios ``mechanical-bekker-soils`` / ``-no-gbsd``) it does
  not hold: R² −14.2 to 0.32 over s 0–0.4, seeds 0 and 1 (``benchmarks/machine.py``), because the Janosi
  curve with Wong's shear moduli K of farm soils (1–2.5 cm) rises much faster than 1 − e^{−7.5 s}: even
  the best level a gives R² 0.26 / 0.66 / 0.92 there (D497's shape matches Janosi's only for K ≥ 4 cm).
  The default stays the configured classes; no prior meets R² ≥ 0.95 on every soil of both truths, and the
  machine's pairs, at one working point per soil, do not choose between shapes (docs/results/mechanical.md, issue 14).

The prior is chosen per estimator (:class:`~.machine.MachineEstimator` ``curve_prior``); a prior outside
the registry of surface classes (:data:`~tractionecu.model.mucurve.SOIL_CLASSES`, which the simulator's
truth files are written against) is one of the curve shapes of
:data:`~tractionecu.model.mucurve.CURVE_SHAPES`: consumers look an estimate's ``soil_class`` up by name with
:func:`~tractionecu.model.mucurve.curve_class`, which knows both registries, and the reported curve
(:class:`MachineCurveState`) carries its shape too.  The estimate's ``soil_class_index`` (the bus's
``SoilClassIndex``) is the prior's index in the configured ``soil_classes`` when it is one of them, else its
fixed code 200 + k (:data:`~tractionecu.model.mucurve.CLASS_CODES`; d497: 204).
"""

from __future__ import annotations

import dataclasses
import math
from functools import cached_property
from typing import Any

from ..model.mucurve import CURVE_SHAPES, SOIL_CLASSES, MuCurve, SoilClass, class_index, curve_class
from .curve import CurveEstimator, CurveState

__all__ = ["D497", "MACHINE_PRIORS", "MachineCurveState", "machine_curve_estimator", "resolve_prior"]

D497 = CURVE_SHAPES["d497"]
"""The D497 shape as an eq. 14 class (module doc; defined in :data:`~tractionecu.model.mucurve.CURVE_SHAPES`)."""

MACHINE_PRIORS: dict[str, SoilClass] = CURVE_SHAPES
"""Priors of the machine-level curve beyond the surface classes, by name (the registry of curve shapes that
are not surface classes, :data:`~tractionecu.model.mucurve.CURVE_SHAPES`)."""


def resolve_prior(prior: str | SoilClass | None) -> SoilClass | None:
    """The :class:`SoilClass` a ``curve_prior`` names (None: the configured classes)."""
    if prior is None or isinstance(prior, SoilClass):
        return prior
    cls = curve_class(prior)
    if cls is None:
        raise ValueError(f"unknown machine curve prior {prior!r} "
                         f"(known: {', '.join([*CURVE_SHAPES, *SOIL_CLASSES])})")
    return cls


class _WithClasses:
    """An estimator configuration with its ``soil_classes`` replaced (everything else read through)."""

    def __init__(self, cfg: Any, classes: tuple[SoilClass, ...]) -> None:
        self._cfg = cfg
        self.soil_classes = classes

    def __getattr__(self, name: str) -> Any:
        return getattr(self._cfg, name)


class _PriorCurveEstimator(CurveEstimator):
    """The curve identification of one prior, whose states carry the prior's ``class_index`` as the bus
    reads it (:func:`~tractionecu.model.mucurve.class_index`): its index in the configured ``soil_classes``
    when it is one of them, else its fixed code (200 + k).  The index in the estimator's own one-class list
    (0) would make a receiver read the first configured class (``stubble``).  A :class:`SoilClass` given
    directly that is in neither registry has no code: its index is −1, which the bus sends as not available."""

    bus_index: int = 0

    def state(self) -> CurveState:
        cs = super().state()
        return cs if cs.class_index == self.bus_index else dataclasses.replace(cs, class_index=self.bus_index)


def machine_curve_estimator(cfg: Any, prior: SoilClass | None) -> CurveEstimator:
    """The machine's curve identification: the configuration's (:meth:`CurveEstimator.from_config`), with
    the one class ``prior`` instead of the configured ``soil_classes`` when given (its states' ``class_index``
    is then the prior's bus index, :class:`_PriorCurveEstimator`)."""
    if prior is None:
        return CurveEstimator.from_config(cfg)
    est = _PriorCurveEstimator.from_config(_WithClasses(cfg, (prior,)))
    idx = class_index(prior.name, tuple(getattr(cfg, "soil_classes", ())))
    est.bus_index = -1 if idx is None else idx        # -1: a class of its own (no code), sent as not available
    return est


@dataclasses.dataclass(frozen=True)
class MachineCurveState(CurveState):
    """A :class:`~.curve.CurveState` whose class-path curve is a·g(s) of ``prior``, also for a prior that
    is not one of :data:`~tractionecu.model.mucurve.SOIL_CLASSES`.  Its ``class_index`` is the prior's index
    as the bus's ``SoilClassIndex`` reads it (:func:`~tractionecu.model.mucurve.class_index`)."""

    prior: SoilClass | None = None

    @classmethod
    def of(cls, cs: CurveState, prior: SoilClass) -> "MachineCurveState":
        """``cs`` with its prior attached."""
        return cls(**{f.name: getattr(cs, f.name) for f in dataclasses.fields(CurveState)}, prior=prior)

    @cached_property
    def curve(self) -> MuCurve | None:
        if self.shape_curve is not None:
            return self.shape_curve
        if not self.a == self.a or self.prior is None or self.class_name != self.prior.name:
            return CurveState.curve.func(self)          # type: ignore[attr-defined]
        c = MuCurve.from_class(self.prior, self.a, self.var_a if math.isfinite(self.var_a) else math.nan)
        return c if self.s_range is None else dataclasses.replace(c, s_range=self.s_range)
